"""activetouch.poses and Pose.compose / inverse agree with scipy's Rotation (x, y, z, w)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from activetouch.interfaces import Pose
from activetouch.planning.grid import look_at_quaternion
from activetouch.poses import look_at_axes, quat_conj, quat_mul, quat_rotate


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quaternion_maths_matches_rotation() -> None:
    rng = np.random.default_rng(0)
    p, q, v = _unit(rng, 200), _unit(rng, 200), rng.normal(size=(200, 3))
    want = (Rotation.from_quat(p) * Rotation.from_quat(q)).as_quat()
    got = quat_mul(p, q)
    # q and -q are one rotation: compare up to sign.
    np.testing.assert_allclose(np.abs(np.sum(got * want, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat_rotate(p, v), Rotation.from_quat(p).apply(v), atol=1e-12)
    np.testing.assert_allclose(
        quat_rotate(quat_conj(p), v), Rotation.from_quat(p).inv().apply(v), atol=1e-12
    )
    np.testing.assert_allclose(quat_mul(p[0], q), quat_mul(np.tile(p[0], (200, 1)), q))


def test_quat_mul_order() -> None:
    # A quarter turn about z after one about x: not the same as the other way round.
    rx, rz = Rotation.from_euler("x", 90, degrees=True), Rotation.from_euler("z", 90, degrees=True)
    got = quat_mul(rz.as_quat(), rx.as_quat())
    np.testing.assert_allclose(got, (rz * rx).as_quat(), atol=1e-15)
    assert not np.allclose(got, (rx * rz).as_quat(), atol=1e-3)


@pytest.mark.parametrize(
    "d", [[1.0, 0.0, 0.0], [0.3, -0.4, 0.5], [0.0, 0.0, 1.0], [0.0, 0.0, -2.0], [1e-9, 0, -1]]
)
def test_look_at_axes(d) -> None:
    x, y, z = look_at_axes(np.array(d))
    R = np.column_stack([x, y, z])
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(z, np.array(d) / np.linalg.norm(d))
    assert abs(x @ np.cross([0.0, 0.0, 1.0], z)) < 1e-9 or abs(z[2]) > 1 - 1e-9  # vertical plane
    # Batched rows give the same axes as one at a time.
    xs, _, _ = look_at_axes(np.array([d, [0.0, 1.0, 0.0]]))
    np.testing.assert_array_equal(xs[0], x)


def test_look_at_quaternion_rolls_about_the_view_axis() -> None:
    d = np.array([0.2, 0.5, -0.7])
    r0 = Rotation.from_quat(look_at_quaternion(d, 0.0))
    r1 = Rotation.from_quat(look_at_quaternion(d, 0.9))
    np.testing.assert_allclose(r1.apply([0, 0, 1.0]), d / np.linalg.norm(d), atol=1e-12)
    assert (r0.inv() * r1).magnitude() == pytest.approx(0.9)


def _matrix(p: Pose) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(p.quat).as_matrix()
    T[:3, 3] = p.xyz
    return T


def test_pose_compose_and_inverse_are_matrix_products() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = Pose(rng.normal(size=3), rng.normal(size=4))
        b = Pose(rng.normal(size=3), rng.normal(size=4))
        np.testing.assert_allclose(_matrix(a.compose(b)), _matrix(a) @ _matrix(b), atol=1e-12)
        np.testing.assert_allclose(_matrix(a.inverse()), np.linalg.inv(_matrix(a)), atol=1e-12)
        ident = a.compose(a.inverse())
        np.testing.assert_allclose(ident.xyz, 0.0, atol=1e-12)
        assert abs(ident.quat[3]) == pytest.approx(1.0)
