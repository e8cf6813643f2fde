"""Vectorised quaternion and look-at maths on plain arrays, quaternions (x, y, z, w) as in
`activetouch.interfaces`.

scipy's `Rotation` is the tool for one pose at a time; these are for the planner's arrays of
millions of relative poses, where building `Rotation` objects costs more than the maths, and
where the planner's results must not move by a bit: every function here is the exact
arithmetic its callers did by hand before, so swapping them in changed no output.

Bottom floor of the import contract (pyproject.toml): numpy only.
"""

from __future__ import annotations

import numpy as np

__all__ = ["look_at_axes", "quat_conj", "quat_mul", "quat_rotate"]

_CONJ = np.array([-1.0, -1.0, -1.0, 1.0])


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugates of quaternions (..., 4): the inverse rotations of unit ones."""
    return np.asarray(q, dtype=np.float64) * _CONJ


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton products p * q of broadcastable (..., 4) quaternions (q applied first)."""
    x1, y1, z1, w1 = np.moveaxis(np.asarray(p), -1, 0)
    x2, y2, z2, w2 = np.moveaxis(np.asarray(q), -1, 0)
    return np.stack(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ],
        axis=-1,
    )


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors v (..., 3) rotated by unit quaternions q (..., 4), broadcasting."""
    q = np.asarray(q)
    u, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def look_at_axes(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit axes x, y, z (each shaped like `direction`, (..., 3)) of frames whose +z is
    `direction`, before any roll about it: x lies in the vertical plane containing z, pointing
    up where possible (any horizontal x when looking straight up or down), y = z cross x."""
    d = np.asarray(direction, dtype=np.float64)
    z = d.reshape(-1, 3)
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    x = up[None, :] - z * (z @ up)[:, None]
    flat = np.linalg.norm(x, axis=1) < 1e-6
    x[flat] = np.array([1.0, 0.0, 0.0]) - z[flat] * z[flat, :1]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return x.reshape(d.shape), y.reshape(d.shape), z.reshape(d.shape)
