"""Triangle parameters: values, ordering, invariance, degenerate cases and errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from activetouch.errors import ConfigError, DataError
from activetouch.recognition.triangles import (
    FEATURE_NAMES,
    PARAMETERISATIONS,
    parse_parameterisation,
    subset_table,
    triangle_features,
    triangle_params,
)


def reference_features(xyz: np.ndarray, min_side: float, min_angle_deg: float) -> np.ndarray:
    """Plain-loop version: sides by distance, angles from vectors at the vertices."""
    rows = []
    for i, j, k in itertools.combinations(range(len(xyz)), 3):
        p = xyz[[i, j, k]]
        pairs = []  # (side length opposite vertex v, angle at vertex v)
        for v in range(3):
            a, b = p[(v + 1) % 3] - p[v], p[(v + 2) % 3] - p[v]
            side = float(np.linalg.norm(p[(v + 1) % 3] - p[(v + 2) % 3]))
            na, nb = np.linalg.norm(a), np.linalg.norm(b)
            ang = math.acos(max(-1.0, min(1.0, float(a @ b) / (na * nb)))) if na * nb else 0.0
            pairs.append((side, ang))
        sides = sorted((s for s, _ in pairs), reverse=True)
        angles = sorted((a for _, a in pairs), reverse=True)
        if sides[2] < min_side or angles[2] < math.radians(min_angle_deg):
            continue
        rows.append(sides + angles)
    return np.array(rows, dtype=np.float64).reshape(-1, 6)


def same_rows(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    """True if a and b hold the same rows up to order and tol (optimal matching)."""
    if a.shape != b.shape:
        return False
    if len(a) == 0:
        return True
    cost = np.abs(a[:, None, :] - b[None, :, :]).max(axis=2)
    r, c = linear_sum_assignment(cost)
    return bool(cost[r, c].max() <= tol)


def margins_ok(xyz: np.ndarray, min_side: float = 1e-4, min_angle_deg: float = 1.0) -> bool:
    """No triangle sits so close to a degeneracy threshold that rounding could flip it."""
    f = reference_features(xyz, 0.0, 0.0)
    if len(f) == 0:
        return True
    near_side = np.abs(f[:, 2] - min_side) < 1e-7
    near_angle = np.abs(f[:, 5] - math.radians(min_angle_deg)) < 1e-6
    return not (near_side.any() or near_angle.any())


grid_points = st.lists(st.tuples(*[st.integers(-8, 8)] * 3), min_size=0, max_size=8).map(
    lambda pts: np.array(pts, dtype=np.float64).reshape(-1, 3) * 0.01
)
rotations = st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(x * x for x in q) > 0.1)
translations = st.tuples(*[st.floats(-2, 2)] * 3)


def test_right_triangle_values() -> None:
    xyz = np.array([[0, 0, 0], [0.03, 0, 0], [0, 0.04, 0]], dtype=float)
    f = triangle_features(xyz)
    assert f.shape == (1, 6)
    np.testing.assert_allclose(f[0, :3], [0.05, 0.04, 0.03], atol=1e-15)
    np.testing.assert_allclose(
        f[0, 3:], [math.pi / 2, math.atan2(0.04, 0.03), math.atan2(0.03, 0.04)], atol=1e-12
    )
    np.testing.assert_allclose(triangle_params(xyz), [[0.05, 0.04, math.pi / 2]], atol=1e-12)
    np.testing.assert_allclose(triangle_params(xyz, "l0,l1,l2"), [[0.05, 0.04, 0.03]], atol=1e-15)
    np.testing.assert_allclose(
        triangle_params(xyz, "a0,a1,l0"),
        [[math.pi / 2, math.atan2(0.04, 0.03), 0.05]],
        atol=1e-12,
    )


def test_equilateral_and_isosceles_keep_order() -> None:
    eq = np.array([[0, 0, 0], [0.05, 0, 0], [0.025, 0.05 * math.sqrt(3) / 2, 0]])
    f = triangle_features(eq)
    np.testing.assert_allclose(f[0, 3:], [math.pi / 3] * 3, atol=1e-9)
    assert f[0, 3] >= f[0, 4] >= f[0, 5]
    iso = np.array([[0, 0, 0], [0.1, 0.01, 0], [0.1, -0.01, 0]])
    f = triangle_features(iso)
    assert f[0, 0] >= f[0, 1] >= f[0, 2] and f[0, 3] >= f[0, 4] >= f[0, 5]
    assert f[0, 0] == f[0, 1]


def test_subset_table() -> None:
    assert subset_table(2).shape == (0, 3)
    t = subset_table(38)
    assert t.shape == (math.comb(38, 3), 3)
    assert (t[:, 0] < t[:, 1]).all() and (t[:, 1] < t[:, 2]).all()
    assert subset_table(38) is t  # cached


@pytest.mark.parametrize("n", [0, 1, 2])
def test_fewer_than_three_contacts(n: int) -> None:
    out = triangle_params(np.zeros((n, 3)) + np.arange(n)[:, None])
    assert out.shape == (0, 3) and out.dtype == np.float64
    assert triangle_params(np.zeros((0,))).shape == (0, 3)


def test_degenerate_dropped() -> None:
    collinear = np.array([[0, 0, 0], [0.02, 0, 0], [0.05, 0, 0]], dtype=float)
    assert triangle_params(collinear).shape == (0, 3)
    assert triangle_params(np.zeros((5, 3))).shape == (0, 3)
    # Two of four contacts coincide: the 2 triangles holding both are dropped.
    dup = np.array([[0, 0, 0], [0, 0, 0], [0.05, 0, 0], [0, 0.05, 0]], dtype=float)
    assert triangle_params(dup).shape == (2, 3)
    dup3 = np.array([[0, 0, 0], [0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0, 0, 0.05]])
    assert triangle_params(dup3).shape == (math.comb(5, 3) - 3, 3)
    # Thresholds are explicit: a 0.5 degree sliver is kept when the limit is lowered.
    sliver = np.array([[0, 0, 0], [0.1, 0, 0], [0.05, 0.05 * math.tan(math.radians(0.5)), 0]])
    assert triangle_params(sliver).shape == (0, 3)
    assert triangle_params(sliver, min_angle_deg=0.1).shape == (1, 3)
    near = np.array([[0, 0, 0], [5e-5, 0, 0], [0, 0.05, 0]])
    assert triangle_params(near).shape == (0, 3)
    assert triangle_params(near, min_side_m=1e-5, min_angle_deg=0.0).shape == (1, 3)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_raises(bad: float) -> None:
    xyz = np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.05, bad]])
    with pytest.raises(DataError, match="NaN or infinite"):
        triangle_params(xyz)


def test_wrong_shape_raises() -> None:
    with pytest.raises(DataError, match=r"\(n, 3\)"):
        triangle_params(np.zeros((4, 2)))


@pytest.mark.parametrize("name", ["l0,l1", "l0,l0,a0", "l0,l1,x", "", "l0,l1,a0,a1"])
def test_bad_parameterisation(name: str) -> None:
    with pytest.raises(ConfigError, match="parameterisation"):
        triangle_params(np.eye(3), name)


def test_every_parameterisation_selects_its_columns() -> None:
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-0.1, 0.1, size=(7, 3))
    full = triangle_features(xyz)
    names = [*PARAMETERISATIONS, "a2,l2,a1", " l1 , a2 , l0 "]
    for name in names:
        cols = [FEATURE_NAMES.index(s.strip()) for s in name.split(",")]
        assert parse_parameterisation(name) == tuple(cols)
        np.testing.assert_array_equal(triangle_params(xyz, name), full[:, cols])


@settings(max_examples=60, deadline=None)
@given(xyz=grid_points)
def test_matches_reference_and_geometry(xyz: np.ndarray) -> None:
    assume(margins_ok(xyz))
    f = triangle_features(xyz)
    assert same_rows(f, reference_features(xyz, 1e-4, 1.0), tol=1e-7)
    if len(f):
        assert (np.diff(f[:, :3], axis=1) <= 0).all() and (np.diff(f[:, 3:], axis=1) <= 0).all()
        np.testing.assert_allclose(f[:, 3:].sum(axis=1), math.pi, atol=1e-9)
        # Law of sines: a_i is opposite l_i.
        ratio = f[:, :3] / np.sin(f[:, 3:])
        np.testing.assert_allclose(ratio, ratio[:, :1].repeat(3, axis=1), rtol=1e-6)


@settings(max_examples=60, deadline=None)
@given(xyz=grid_points, q=rotations, t=translations, data=st.data())
def test_invariant_to_rigid_motion_and_order(
    xyz: np.ndarray, q: tuple[float, ...], t: tuple[float, ...], data: st.DataObject
) -> None:
    assume(margins_ok(xyz))
    perm = data.draw(st.permutations(range(len(xyz))))
    moved = Rotation.from_quat(q).apply(xyz) + np.array(t) if len(xyz) else xyz
    moved = moved[list(perm)]
    for name in ("l0,l1,a0", "l0,l1,l2", "a0,a1,l0"):
        a, b = triangle_params(xyz, name), triangle_params(moved, name)
        assert same_rows(a, b, tol=1e-9)
