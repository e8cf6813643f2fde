"""HistogramSpec: binning, clipping, fitting, serialisation, invariance of the descriptor."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from activetouch.errors import DataError
from activetouch.recognition.histogram import HistogramSpec, l1_normalise, l1_normalise_rows
from activetouch.recognition.triangles import triangle_features, triangle_params

SPEC = HistogramSpec(lo=np.array([0.0079, 0.0056, 1.091]), hi=np.array([0.1477, 0.1388, 3.1416]))


def test_layout_and_edges() -> None:
    assert SPEC.n_bins == 1000 and SPEC.bins == 10
    for d in range(3):
        np.testing.assert_array_equal(SPEC.edges[d], np.linspace(SPEC.lo[d], SPEC.hi[d], 11))
    np.testing.assert_allclose(SPEC.centres[:, 0], SPEC.lo + (SPEC.hi - SPEC.lo) / 20)


def test_flat_index_and_counts_match_numpy() -> None:
    rng = np.random.default_rng(0)
    t = rng.uniform(SPEC.lo, SPEC.hi, size=(500, 3))
    t[:3] = SPEC.hi  # upper range ends belong to the last bin
    t[3] = SPEC.edges[:, 4]  # a value on an edge opens the next bin
    idx = SPEC.bin_index(t)
    assert idx.dtype == np.int64 and idx.shape == (500,)
    ref, _ = np.histogramdd(t, bins=list(SPEC.edges))
    np.testing.assert_array_equal(SPEC.counts(t), ref.ravel())
    i0, i1, i2 = np.unravel_index(idx, (10, 10, 10))
    np.testing.assert_array_equal(idx, (i0 * 10 + i1) * 10 + i2)
    assert idx[0] == 999 and idx[3] == (4 * 10 + 4) * 10 + 4


def test_out_of_range_clipped_into_edge_bins_and_reported() -> None:
    t = np.array(
        [
            [0.0, 0.05, 2.0],  # l0 below range
            [0.5, 0.05, 2.0],  # l0 above range
            [0.05, 0.05, 9.0],  # a0 above range
            [0.05, 0.05, 2.0],  # inside
        ]
    )
    idx, clipped = SPEC.bin_index(t, return_clipped=True)
    assert clipped == 3
    inside = SPEC.bin_index(t[3:])[0]
    assert idx[0] == inside - (inside // 100) * 100  # i0 = 0
    assert idx[1] // 100 == 9
    assert idx[2] % 10 == 9
    counts, n = SPEC.counts_with_clipped(t)
    assert n == 3 and counts.sum() == 4


def test_histogram_normalised_and_empty() -> None:
    t = np.random.default_rng(1).uniform(SPEC.lo, SPEC.hi, size=(37, 3))
    h = SPEC.histogram(t)
    assert h.shape == (1000,) and abs(h.sum() - 1) < 1e-12
    np.testing.assert_allclose(h, SPEC.counts(t) / 37)
    empty = np.zeros((0, 3))
    assert SPEC.counts(empty).sum() == 0 and SPEC.histogram(empty).sum() == 0
    assert SPEC.bin_index(empty, return_clipped=True)[1] == 0
    assert l1_normalise(np.zeros(4)).sum() == 0
    np.testing.assert_array_equal(
        l1_normalise_rows(np.array([[0, 0], [1, 3]])), [[0, 0], [0.25, 0.75]]
    )


def test_non_finite_or_bad_shape_raises() -> None:
    with pytest.raises(DataError, match="NaN"):
        SPEC.counts(np.array([[0.05, np.nan, 2.0]]))
    with pytest.raises(DataError, match=r"\(m, 3\)"):
        SPEC.counts(np.zeros((4, 2)))


def test_fit_ranges() -> None:
    rng = np.random.default_rng(2)
    t = rng.uniform([0.01, 0.005, 1.0], [0.15, 0.14, 3.1], size=(300, 3))
    spec = HistogramSpec.fit(t, bins=8)
    np.testing.assert_array_equal(spec.lo, t.min(axis=0))
    np.testing.assert_array_equal(spec.hi, t.max(axis=0))
    assert spec.n_bins == 512
    _, clipped = spec.bin_index(t, return_clipped=True)
    assert clipped == 0
    assert spec.counts(t).sum() == 300


def test_fit_degenerate_range_is_widened() -> None:
    t = np.array([[0.05, 0.04, 1.5], [0.06, 0.04, 1.5]])
    spec = HistogramSpec.fit(t)
    assert (spec.hi > spec.lo).all()
    assert spec.lo[1] < 0.04 < spec.hi[1] and spec.hi[1] - spec.lo[1] < 1e-6
    assert spec.bin_index(t, return_clipped=True)[1] == 0
    one = HistogramSpec.fit(np.zeros((1, 3)))
    assert (one.hi > one.lo).all()
    with pytest.raises(DataError, match="no training triangles"):
        HistogramSpec.fit(np.zeros((0, 3)))


@pytest.mark.parametrize(
    ("lo", "hi", "bins"),
    [
        ([0, 0, 0], [1, 1, 0], 10),
        ([0, 0], [1, 1], 10),
        ([0, 0, 0], [1, 1, 1], 0),
        ([0, 0, 0], [1, 1, np.inf], 10),
        ([0, 0, 0], [1, 1, 1], 2.5),
    ],
)
def test_invalid_spec(lo: list[float], hi: list[float], bins: float) -> None:
    with pytest.raises(DataError):
        HistogramSpec(lo=np.array(lo, dtype=float), hi=np.array(hi, dtype=float), bins=bins)


def test_dict_round_trip_through_json() -> None:
    d = json.loads(json.dumps(SPEC.to_dict()))
    back = HistogramSpec.from_dict(d)
    assert back == SPEC and hash(back) == hash(SPEC)
    assert back != HistogramSpec(lo=SPEC.lo, hi=SPEC.hi, bins=9)
    t = np.random.default_rng(3).uniform(0, 3, size=(50, 3))
    np.testing.assert_array_equal(back.bin_index(t), SPEC.bin_index(t))
    with pytest.raises(DataError, match="lacks"):
        HistogramSpec.from_dict({"lo": [0, 0, 0], "bins": 10})
    with pytest.raises(DataError, match="format"):
        HistogramSpec.from_dict({**d, "format": "something/9"})
    with pytest.raises(DataError, match="not numbers"):
        HistogramSpec.from_dict({**d, "lo": ["a", "b", "c"]})


grid_points = st.lists(st.tuples(*[st.integers(-6, 6)] * 3), min_size=3, max_size=9).map(
    lambda pts: np.array(pts, dtype=np.float64) * 0.012
)


@settings(max_examples=50, deadline=None)
@given(
    xyz=grid_points,
    q=st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(x * x for x in q) > 0.1),
    t=st.tuples(*[st.floats(-1, 1)] * 3),
    data=st.data(),
)
def test_histogram_invariant_to_rigid_motion_and_order(
    xyz: np.ndarray, q: tuple[float, ...], t: tuple[float, ...], data: st.DataObject
) -> None:
    tri = triangle_params(xyz)
    f = triangle_features(xyz, 0.0, 0.0)
    # Triangles within rounding of a degeneracy threshold could be dropped on one side only.
    assume(not (np.abs(f[:, 5] - np.deg2rad(1.0)) < 1e-6).any())
    # A value within rounding of a bin edge could legitimately switch bins; such draws say
    # nothing about invariance.
    if len(tri):
        gap = np.abs(tri.T[:, :, None] - SPEC.edges[:, None, :]).min()
        assume(gap > 1e-9)
    perm = data.draw(st.permutations(range(len(xyz))))
    moved = (Rotation.from_quat(q).apply(xyz) + np.array(t))[list(perm)]
    np.testing.assert_array_equal(SPEC.counts(triangle_params(moved)), SPEC.counts(tri))
    np.testing.assert_array_equal(SPEC.histogram(triangle_params(moved)), SPEC.histogram(tri))
