"""Histogram distances: known values, zero histograms, one-to-many and pairwise versions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from activetouch.recognition.distances import (
    inner_product_distance,
    inner_product_distance_many,
    intersection_distance,
    intersection_distance_many,
    l2_distance,
    l2_distance_many,
    pairwise_distances,
)

PAIRS = [
    (inner_product_distance, inner_product_distance_many),
    (intersection_distance, intersection_distance_many),
    (l2_distance, l2_distance_many),
]


def test_known_values() -> None:
    a = np.array([1.0, 0.0, 0.0, 0.0])
    b = np.array([0.0, 1.0, 0.0, 0.0])
    c = np.array([1.0, 1.0, 0.0, 0.0])
    assert inner_product_distance(a, b) == 1.0
    assert inner_product_distance(a, a) == 0.0
    assert inner_product_distance(a, c) == pytest.approx(1 - 1 / np.sqrt(2))
    assert intersection_distance(a, b) == 1.0
    assert intersection_distance(a, c) == pytest.approx(0.5)
    assert l2_distance(a, b) == pytest.approx(np.sqrt(2))
    assert l2_distance(a, c) == pytest.approx(np.sqrt(0.5))


def test_scale_invariance() -> None:
    rng = np.random.default_rng(0)
    h1, h2 = rng.random(50), rng.random(50)
    for fn, _ in PAIRS:
        assert fn(h1, h2) == pytest.approx(fn(7 * h1, 0.1 * h2), abs=1e-12)


def test_zero_histograms() -> None:
    z = np.zeros(5)
    h = np.array([1.0, 2, 0, 0, 1])
    assert inner_product_distance(z, h) == 1.0 and inner_product_distance(z, z) == 1.0
    assert intersection_distance(z, h) == 1.0 and intersection_distance(z, z) == 1.0
    assert l2_distance(z, z) == 0.0
    np.testing.assert_array_equal(inner_product_distance_many(z, np.vstack([h, z])), [1.0, 1.0])
    np.testing.assert_array_equal(intersection_distance_many(h, np.vstack([h, z]))[1:], [1.0])


def test_shape_errors() -> None:
    with pytest.raises(ValueError, match="length"):
        inner_product_distance(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        intersection_distance_many(np.ones(3), np.ones((2, 4)))
    with pytest.raises(ValueError, match="metric"):
        pairwise_distances(np.ones((2, 3)), np.ones((2, 3)), metric="cosine")


hists = arrays(
    np.float64, (6, 12), elements=st.one_of(st.just(0.0), st.floats(0, 100, allow_subnormal=False))
)


@settings(max_examples=50, deadline=None)
@given(H=hists)
def test_properties_and_vectorised_agree(H: np.ndarray) -> None:
    h = H[0]
    for fn, many in PAIRS:
        d = many(h, H)
        assert d.shape == (6,)
        np.testing.assert_allclose(d, [fn(h, row) for row in H], atol=1e-12)
        np.testing.assert_allclose(d, [fn(row, h) for row in H], atol=1e-12)  # symmetric
    for _, many in PAIRS[:2]:
        d = many(h, H)
        assert ((d >= 0) & (d <= 1)).all()
    for metric, (fn, _) in zip(("inner", "intersection", "l2"), PAIRS, strict=True):
        P = pairwise_distances(H[:2], H, metric)
        Q = pairwise_distances(H, H[:2], metric)
        assert P.shape == (2, 6) and Q.shape == (6, 2)
        np.testing.assert_allclose(P, Q.T, atol=1e-12)
        assert P[1, 4] == pytest.approx(fn(H[1], H[4]), abs=1e-12)
    if h.sum() > 0:
        assert inner_product_distance(h, 3 * h) == pytest.approx(0.0, abs=1e-12)
        assert intersection_distance(h, 3 * h) == pytest.approx(0.0, abs=1e-12)
