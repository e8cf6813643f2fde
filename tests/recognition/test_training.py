"""Partial-histogram training samples and the synthetic contact generator."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from activetouch.errors import ConfigError, DataError
from activetouch.recognition.histogram import HistogramSpec
from activetouch.recognition.synthetic import (
    SYNTHETIC_SHAPES,
    random_rotation,
    surface_points,
    synthetic_grasp,
)
from activetouch.recognition.training import grasp_counts, grasp_triangles, partial_histograms
from activetouch.recognition.triangles import triangle_params

SPEC = HistogramSpec(lo=np.array([0.0, 0.0, 1.0]), hi=np.array([0.3, 0.3, 3.1416]), bins=6)


def _objects(rng: np.random.Generator, n_grasps: tuple[int, ...]) -> list[list[np.ndarray]]:
    shapes = ("cone", "torus", "box_flat", "capsule")
    return [
        grasp_triangles([synthetic_grasp(shapes[i], rng, (3, 6)) for _ in range(g)])
        for i, g in enumerate(n_grasps)
    ]


def test_grasp_triangles_and_counts() -> None:
    rng = np.random.default_rng(0)
    contacts = [synthetic_grasp("sphere_large", rng, n) for n in (2, 3, 5)]
    tris = grasp_triangles(contacts)
    assert [len(t) for t in tris] == [0, 1, 10]
    np.testing.assert_array_equal(tris[2], triangle_params(contacts[2]))
    C = grasp_counts(tris, SPEC)
    assert C.shape == (3, SPEC.n_bins)
    np.testing.assert_array_equal(C.sum(axis=1), [0, 1, 10])


def test_shapes_labels_and_full_histogram() -> None:
    rng = np.random.default_rng(1)
    objs = _objects(rng, (5, 8, 3))
    H, y = partial_histograms(objs, SPEC, n_samples=20, min_grasps=1, max_grasps=4, rng=rng)
    assert H.shape == (63, SPEC.n_bins) and y.dtype == np.int64
    np.testing.assert_array_equal(np.bincount(y), [21, 21, 21])
    np.testing.assert_allclose(H.sum(axis=1), 1.0)
    assert (np.diff(y) >= 0).all()  # objects in order
    for k, obj in enumerate(objs):
        full = SPEC.counts(np.vstack(obj))
        np.testing.assert_allclose(H[y == k][-1], full / full.sum())  # last row: all grasps


def test_partial_rows_are_subsets_of_the_right_size() -> None:
    rng = np.random.default_rng(2)
    objs = _objects(rng, (6,))
    C = grasp_counts(objs[0], SPEC)
    assert (C.sum(axis=1) > 0).all()
    subsets = {}
    for k in range(1, 7):
        for sub in itertools.combinations(range(6), k):
            s = C[list(sub)].sum(axis=0)
            subsets[sub] = s / s.sum()
    H, _ = partial_histograms(objs, SPEC, n_samples=60, min_grasps=2, max_grasps=3, rng=rng)
    sizes = []
    for h in H[:-1]:
        match = [sub for sub, ref in subsets.items() if np.allclose(h, ref, atol=1e-12)]
        assert match, "a partial histogram is not the histogram of any subset of grasps"
        sizes.append(min(len(m) for m in match))
    assert set(sizes) <= {2, 3} and {2, 3} <= set(sizes)


def test_max_grasps_capped_by_available_and_deterministic() -> None:
    objs = _objects(np.random.default_rng(3), (2, 4))
    a = partial_histograms(objs, SPEC, 10, 1, 30, np.random.default_rng(7))
    b = partial_histograms(objs, SPEC, 10, 1, 30, np.random.default_rng(7))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    c = partial_histograms(objs, SPEC, 10, 5, 30, np.random.default_rng(7))
    # min_grasps above the available 2 grasps: every sample of object 0 uses both.
    rows = c[0][c[1] == 0]
    np.testing.assert_allclose(rows, np.repeat(rows[-1:], len(rows), axis=0))


def test_empty_samples_left_out() -> None:
    rng = np.random.default_rng(4)
    empty = [np.zeros((0, 3))] * 3
    full = grasp_triangles([synthetic_grasp("box_cube", rng, 5)])
    H, y = partial_histograms([empty + full, full], SPEC, 50, 1, 1, rng)
    # Single-grasp samples of object 0 are empty 3 times in 4: those rows are dropped.
    n0 = int((y == 0).sum())
    assert 1 <= n0 < 51 and (y == 1).sum() == 51
    assert (H.sum(axis=1) > 0).all()


@pytest.mark.parametrize(("lo", "hi", "n"), [(0, 3, 5), (4, 3, 5), (1, 3, -1)])
def test_config_errors(lo: int, hi: int, n: int) -> None:
    objs = _objects(np.random.default_rng(5), (3,))
    with pytest.raises(ConfigError):
        partial_histograms(objs, SPEC, n, lo, hi, np.random.default_rng(0))


def test_data_errors() -> None:
    with pytest.raises(DataError, match="no training grasps"):
        partial_histograms([[]], SPEC, 5, 1, 2, np.random.default_rng(0))
    with pytest.raises(DataError, match="no objects"):
        partial_histograms([], SPEC, 5, 1, 2, np.random.default_rng(0))


# --- synthetic contact generator ----------------------------------------------------------


def test_enough_distinct_shapes() -> None:
    assert len(SYNTHETIC_SHAPES) >= 12 and len(set(SYNTHETIC_SHAPES)) == len(SYNTHETIC_SHAPES)


@pytest.mark.parametrize("shape", SYNTHETIC_SHAPES)
def test_surface_points_are_finite_and_sized(shape: str) -> None:
    pts = surface_points(shape, np.random.default_rng(0), 200)
    assert pts.shape == (200, 3) and np.isfinite(pts).all()
    assert 0.01 < np.ptp(pts, axis=0).max() < 0.3


def test_points_lie_on_known_surfaces() -> None:
    rng = np.random.default_rng(1)
    np.testing.assert_allclose(
        np.linalg.norm(surface_points("sphere_small", rng, 50), axis=1), 0.03
    )
    box = surface_points("box_cube", rng, 100)
    assert np.allclose(np.abs(box).max(axis=1), 0.04)
    tor = surface_points("torus", rng, 100)
    ring = np.hypot(tor[:, 0], tor[:, 1])
    np.testing.assert_allclose(np.hypot(ring - 0.06, tor[:, 2]), 0.02, atol=1e-12)
    cyl = surface_points("cylinder_thin", rng, 100)
    on_side = np.isclose(np.hypot(cyl[:, 0], cyl[:, 1]), 0.02)
    on_cap = np.isclose(np.abs(cyl[:, 2]), 0.10)
    assert (on_side | on_cap).all()


def test_synthetic_grasp_rigid_frame_and_counts() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        g = synthetic_grasp("sphere_large", rng, (3, 7))
        assert 3 <= len(g) <= 7
        # A random rigid frame keeps the points on a sphere of radius 7 cm (centre unknown):
        # all pairwise distances are at most the diameter.
        d = np.linalg.norm(g[:, None] - g[None], axis=2)
        assert d.max() <= 0.14 + 1e-12
    assert synthetic_grasp("cone", rng, 27, reach_m=None).shape == (27, 3)
    g = synthetic_grasp("box_long", rng, 6, reach_m=0.05)
    assert np.linalg.norm(g[:, None] - g[None], axis=2).max() <= 0.1 + 1e-12
    noisy = synthetic_grasp("box_cube", rng, 5, noise_m=0.001)
    assert noisy.shape == (5, 3)
    R = random_rotation(rng)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_synthetic_errors() -> None:
    with pytest.raises(ConfigError, match="unknown synthetic shape"):
        synthetic_grasp("dodecahedron", np.random.default_rng(0))
    with pytest.raises(ConfigError, match="n_contacts"):
        synthetic_grasp("cone", np.random.default_rng(0), (5, 3))
