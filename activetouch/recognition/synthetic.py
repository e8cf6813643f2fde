"""Synthetic contact data for tests and benchmarks: points on the surfaces of simple shapes.

A synthetic grasp is a handful of points sampled uniformly (by area) on a shape's surface,
optionally restricted to the patch a hand could enclose (within ``reach_m`` of a random surface
point), optionally with Gaussian noise, and expressed in a random rigid frame (the descriptor must
not depend on it). This is not a physics simulation; it gives shape-dependent triangle statistics
quickly and deterministically from a numpy Generator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from activetouch.errors import ConfigError

Sampler = Callable[[np.random.Generator, int], np.ndarray]


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _sphere(r: float) -> Sampler:
    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        return r * _unit_vectors(rng, n)

    return sample


def _ellipsoid(a: float, b: float, c: float) -> Sampler:
    axes = np.array([a, b, c])

    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        # Rejection on the area element of the stretched sphere makes the density uniform.
        out: list[np.ndarray] = []
        got = 0
        bound = max(a * b, b * c, a * c)
        while got < n:
            u = _unit_vectors(rng, 2 * n + 8)
            w = np.sqrt(((u / axes) ** 2).sum(axis=1)) * a * b * c
            ok = rng.uniform(0.0, bound, size=len(u)) < w
            pts = u[ok] * axes
            out.append(pts)
            got += len(pts)
        return np.concatenate(out)[:n]

    return sample


def _cylinder(r: float, h: float) -> Sampler:
    side, cap = 2 * np.pi * r * h, np.pi * r * r

    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        part = rng.choice(3, size=n, p=np.array([side, cap, cap]) / (side + 2 * cap))
        th = rng.uniform(0, 2 * np.pi, n)
        rad = np.where(part == 0, r, r * np.sqrt(rng.uniform(0, 1, n)))
        z = np.where(part == 0, rng.uniform(-h / 2, h / 2, n), np.where(part == 1, h / 2, -h / 2))
        return np.stack([rad * np.cos(th), rad * np.sin(th), z], axis=1)

    return sample


def _box(x: float, y: float, z: float) -> Sampler:
    size = np.array([x, y, z])
    areas = np.array([y * z, x * z, x * y])

    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        axis = rng.choice(3, size=n, p=areas / areas.sum())
        pts = rng.uniform(-0.5, 0.5, size=(n, 3)) * size
        sign = rng.choice([-0.5, 0.5], size=n)
        pts[np.arange(n), axis] = sign * size[axis]
        return pts

    return sample


def _cone(r: float, h: float) -> Sampler:
    slant = np.hypot(r, h)
    lateral, base = np.pi * r * slant, np.pi * r * r

    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        on_side = rng.uniform(0, lateral + base, n) < lateral
        th = rng.uniform(0, 2 * np.pi, n)
        # Lateral area grows linearly with distance from the apex: sqrt of a uniform.
        s = np.sqrt(rng.uniform(0, 1, n))
        rad = np.where(on_side, r * s, r * np.sqrt(rng.uniform(0, 1, n)))
        z = np.where(on_side, h / 2 - h * s, -h / 2)
        return np.stack([rad * np.cos(th), rad * np.sin(th), z], axis=1)

    return sample


def _torus(big_r: float, small_r: float) -> Sampler:
    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        out: list[np.ndarray] = []
        got = 0
        while got < n:
            m = 2 * n + 8
            u = rng.uniform(0, 2 * np.pi, m)  # around the tube
            v = rng.uniform(0, 2 * np.pi, m)  # around the axis
            # Area element is proportional to (R + r cos u).
            ok = rng.uniform(0, big_r + small_r, m) < big_r + small_r * np.cos(u)
            u, v = u[ok], v[ok]
            ring = big_r + small_r * np.cos(u)
            out.append(np.stack([ring * np.cos(v), ring * np.sin(v), small_r * np.sin(u)], axis=1))
            got += len(u)
        return np.concatenate(out)[:n]

    return sample


def _capsule(r: float, h: float) -> Sampler:
    side, caps = 2 * np.pi * r * h, 4 * np.pi * r * r

    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        on_side = rng.uniform(0, side + caps, n) < side
        th = rng.uniform(0, 2 * np.pi, n)
        cyl = np.stack([r * np.cos(th), r * np.sin(th), rng.uniform(-h / 2, h / 2, n)], axis=1)
        sph = r * _unit_vectors(rng, n)
        sph[:, 2] += np.sign(sph[:, 2]) * h / 2
        return np.where(on_side[:, None], cyl, sph)

    return sample


def _hemisphere_shell(r: float) -> Sampler:
    """An open bowl: the lower half of a sphere (both sides of a thin wall are the same points)."""

    def sample(rng: np.random.Generator, n: int) -> np.ndarray:
        u = _unit_vectors(rng, n)
        u[:, 2] = -np.abs(u[:, 2])
        return r * u

    return sample


@dataclass(frozen=True)
class SyntheticShape:
    name: str
    description: str
    sampler: Sampler


def _shapes() -> dict[str, SyntheticShape]:
    items = [
        ("sphere_small", "sphere r=3 cm", _sphere(0.03)),
        ("sphere_large", "sphere r=7 cm", _sphere(0.07)),
        ("ellipsoid", "ellipsoid 8 x 5 x 3.5 cm semi-axes", _ellipsoid(0.08, 0.05, 0.035)),
        ("cylinder_thin", "cylinder r=2 cm h=20 cm", _cylinder(0.02, 0.20)),
        ("cylinder_wide", "cylinder r=6 cm h=10 cm", _cylinder(0.06, 0.10)),
        ("cylinder_disc", "cylinder r=8 cm h=2 cm", _cylinder(0.08, 0.02)),
        ("box_cube", "cube 8 cm", _box(0.08, 0.08, 0.08)),
        ("box_flat", "box 15 x 10 x 3 cm", _box(0.15, 0.10, 0.03)),
        ("box_long", "box 25 x 5 x 5 cm", _box(0.25, 0.05, 0.05)),
        ("cone", "cone r=5 cm h=15 cm", _cone(0.05, 0.15)),
        ("torus", "torus R=6 cm r=2 cm", _torus(0.06, 0.02)),
        ("capsule", "capsule r=3 cm h=15 cm", _capsule(0.03, 0.15)),
        ("bowl", "hemispherical shell r=8 cm", _hemisphere_shell(0.08)),
    ]
    return {name: SyntheticShape(name, desc, fn) for name, desc, fn in items}


SHAPES: dict[str, SyntheticShape] = _shapes()
SYNTHETIC_SHAPES: tuple[str, ...] = tuple(SHAPES)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random 3x3 rotation matrix (QR of a Gaussian matrix, sign-fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def surface_points(shape: str, rng: np.random.Generator, n: int) -> np.ndarray:
    """n points uniformly (by area) on the surface of a synthetic shape, in its own frame."""
    if shape not in SHAPES:
        raise ConfigError(
            f"unknown synthetic shape {shape!r}; choose from {', '.join(SYNTHETIC_SHAPES)}"
        )
    return SHAPES[shape].sampler(rng, int(n))


def synthetic_grasp(
    shape: str,
    rng: np.random.Generator,
    n_contacts: tuple[int, int] | int = (3, 7),
    reach_m: float | None = 0.12,
    noise_m: float = 0.0,
) -> np.ndarray:
    """Contact points (n, 3) of one synthetic grasp of ``shape`` in a random rigid frame.

    n is drawn uniformly from the inclusive range n_contacts (or fixed if an int). With
    ``reach_m`` the contacts lie within that distance of a random surface point (a hand encloses
    a patch, not the whole object); None samples the whole surface.
    """
    if isinstance(n_contacts, int):
        n = n_contacts
    else:
        lo, hi = n_contacts
        if lo < 0 or hi < lo:
            raise ConfigError(f"n_contacts range {n_contacts!r} is invalid")
        n = int(rng.integers(lo, hi + 1))
    pool = surface_points(shape, rng, max(64, 16 * n))
    if reach_m is not None:
        centre = pool[rng.integers(len(pool))]
        near = pool[np.linalg.norm(pool - centre, axis=1) <= reach_m]
        if len(near) >= n:
            pool = near
    pts = pool[rng.choice(len(pool), size=n, replace=False)]
    if noise_m > 0:
        pts = pts + rng.normal(scale=noise_m, size=pts.shape)
    rot = random_rotation(rng)
    shift = rng.uniform(-0.5, 0.5, size=3)
    return pts @ rot.T + shift
