"""Solids for the object library, with their exact convex parts.

Lathe profiles, swept handles and tubes, built with manifold3d booleans. Because each
primitive is known, its convex parts come exactly from the 2-D profile (bands of the profile
whose convex hull stays within ``HULL_TOL_M`` of it, split into angular sectors where the band
is a ring) instead of from a voxel decomposition, which fills thin walls.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

HULL_TOL_M = 0.00075  # how far a convex part may stray from the true surface
CIRCLE_SEGMENTS = 64  # facets around a lathe body (visual mesh)


@dataclass
class Shape:
    """A watertight solid plus convex point clouds whose hulls cover it."""

    solid: object  # manifold3d.Manifold
    hulls: list[np.ndarray]  # each (n, 3): the part is the convex hull of these points

    def __add__(self, other: Shape) -> Shape:
        return Shape(self.solid + other.solid, self.hulls + other.hulls)


def manifold3d_module():
    # deferred: manifold3d only for boolean solids
    import manifold3d

    return manifold3d


def profile(ctrl: list[tuple[float, float]], step: float = 0.002) -> np.ndarray:
    """Sample a smooth lathe profile r(z) through control points (r, z), z increasing.

    Monotone cubic (PCHIP) interpolation: no overshoot, so steps (lids, caps) stay crisp.
    Returns (n, 2) points (r, z) from the bottom to the top.
    """
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.interpolate import PchipInterpolator

    c = np.asarray(ctrl, dtype=np.float64)
    if np.any(np.diff(c[:, 1]) <= 0):
        raise ValueError("profile z must increase")
    f = PchipInterpolator(c[:, 1], c[:, 0])
    zs = [c[:1, 1]]
    for (r0, z0), (r1, z1) in itertools.pairwise(c):
        n = max(1, math.ceil(math.hypot(r1 - r0, z1 - z0) / step))
        zs.append(np.linspace(z0, z1, n + 1)[1:])
    z = np.concatenate(zs)
    return np.stack([np.maximum(f(z), 0.0), z], axis=1)


def half_section(pr: np.ndarray, top_to_axis: bool = True):
    """The region between the axis and a profile, as a CrossSection in (r, z)."""
    m = manifold3d_module()
    pts = [(0.0, pr[0, 1]), *map(tuple, pr)]
    if top_to_axis and pr[-1, 0] > 0:
        pts.append((0.0, pr[-1, 1]))
    return m.CrossSection([np.asarray(pts)])


def mirrored(cs):
    return cs + cs.mirror((1.0, 0.0))


def rect(x0: float, z0: float, x1: float, z1: float):
    return manifold3d_module().CrossSection.square((x1 - x0, z1 - z0)).translate((x0, z0))


def vessel_section(pr: np.ndarray, wall: float, floor: float):
    """Half cross-section of an open vessel: outer profile `pr`, walls `wall` thick (normal
    offset), the cavity floor at height `floor`, open at the top."""
    m = manifold3d_module()
    outer = half_section(pr)
    # Continue the profile upwards so the offset cavity breaks through the rim.
    ext = np.vstack([pr, [pr[-1, 0], pr[-1, 1] + 1.0]])
    cav = mirrored(half_section(ext)).offset(-wall, m.JoinType.Round, 2.0, 48)
    cav = cav ^ rect(0.0, floor, 1.0, pr[-1, 1] + 2.0)
    return outer - cav, cav


def revolve(cs) -> object:
    m = manifold3d_module()
    # Booleans leave near-duplicate vertices (nm apart) that would merge when written.
    return m.Manifold.revolve(cs.simplify(1e-6), CIRCLE_SEGMENTS)


def _polygons(cs) -> list[np.ndarray]:
    return [np.asarray(p, dtype=np.float64) for p in cs.to_polygons()]


def _concavity(points: np.ndarray, probes: np.ndarray) -> float:
    """Largest distance from `probes` (inside) to the boundary of the hull of `points` (2-D)."""
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
    except QhullError:
        return 0.0
    d = -(probes @ hull.equations[:, :2].T + hull.equations[:, 2])
    return float(d.min(axis=1).max()) if len(probes) else 0.0


def _band_ok(band, tol: float) -> bool:
    polys = _polygons(band)
    if len(polys) != 1:
        return False
    p = polys[0]
    if p[:, 0].min() < 1e-7:
        # Touches the axis: revolved, it is convex iff the mirrored section is.
        off_axis = p[p[:, 0] > 1e-7]
        both = np.vstack([p, p * [-1.0, 1.0]])
        return _concavity(both, np.vstack([off_axis, off_axis * [-1.0, 1.0]])) <= tol
    return _concavity(p, p) <= tol


def _ring_points(p: np.ndarray, angles: np.ndarray) -> np.ndarray:
    r, z = p[:, 0:1], p[:, 1:2]
    c, s = np.cos(angles)[None, :], np.sin(angles)[None, :]
    pts = np.stack([r * c, r * s, np.broadcast_to(z, (len(p), len(angles)))], axis=-1)
    return pts.reshape(-1, 3)


def lathe_hulls(cs, tol: float = HULL_TOL_M) -> list[np.ndarray]:
    """Convex parts of the solid of revolution of the half-section `cs` (exact to ~`tol`).

    The section is cut into horizontal bands, each as tall as its 2-D convex hull allows
    (concavity <= tol). A band touching the axis revolves to one convex part; a ring band is
    split into sectors narrow enough that the chord of its inner arc stays within `tol`.
    """
    polys = _polygons(cs)
    levels = np.unique(np.round(np.concatenate([p[:, 1] for p in polys]), 7))
    out: list[np.ndarray] = []
    i = 0
    while i < len(levels) - 1:
        best = i + 1
        j = i + 2
        while j < len(levels) and _band_ok(cs ^ rect(0.0, levels[i], 1.0, levels[j]), tol):
            best = j
            j += 1
        band = cs ^ rect(0.0, levels[i], 1.0, levels[best])
        for p in _polygons(band):
            out.extend(_band_hulls(p, tol))
        i = best
    return out


def _band_hulls(p: np.ndarray, tol: float) -> list[np.ndarray]:
    if p[:, 0].max() < 1e-7:
        return []
    if p[:, 0].min() < 1e-7:
        ang = np.linspace(0.0, 2 * np.pi, CIRCLE_SEGMENTS, endpoint=False)
        return [_ring_points(p[p[:, 0] >= 1e-7], ang)]
    r_in = float(p[:, 0].min())
    half = math.acos(max(-1.0, 1.0 - tol / r_in))
    n_sec = int(min(48, max(6, math.ceil(math.pi / half))))
    edges = np.linspace(0.0, 2 * np.pi, n_sec + 1)
    sub = max(2, math.ceil((2 * np.pi / n_sec) / math.radians(6.0)))
    return [_ring_points(p, np.linspace(a, b, sub + 1)) for a, b in itertools.pairwise(edges)]


def lathe(cs, tol: float = HULL_TOL_M) -> Shape:
    return Shape(revolve(cs), lathe_hulls(cs, tol))


def solid_of_revolution(ctrl: list[tuple[float, float]], step: float = 0.002) -> Shape:
    """A solid of revolution through the control points (r, z)."""
    return lathe(half_section(profile(ctrl, step=step)))


def mesh_manifold(verts: np.ndarray, faces: np.ndarray):
    m = manifold3d_module()
    man = m.Manifold(
        m.Mesh64(
            vert_properties=np.ascontiguousarray(verts, dtype=np.float64),
            tri_verts=np.ascontiguousarray(faces, dtype=np.uint32),
        )
    )
    if man.is_empty():
        raise ValueError(f"not a manifold: {man.status()}")
    return man


def handle(
    centre: tuple[float, float],
    ring: float,
    stretch: float,
    thick: float,
    wide: float,
    x_cut: float,
    n_ring: int = 48,
    n_tube: int = 16,
) -> Shape:
    """A closed loop handle in the xz plane on the +x side: its centreline is the ellipse
    (x, z) = centre + (ring cos t, ring*stretch sin t); its tube an ellipse `thick` (in the
    plane) by `wide` (along y) semi-axes. The part of the loop inside the body is hidden by
    the body; convex parts are kept only where x >= x_cut (so none reaches a cavity)."""
    m = manifold3d_module()
    t = np.linspace(0.0, 2 * np.pi, n_ring, endpoint=False)
    psi = np.linspace(0.0, 2 * np.pi, n_tube, endpoint=False)
    a, b = ring, ring * stretch
    c = np.stack([centre[0] + a * np.cos(t), np.zeros_like(t), centre[1] + b * np.sin(t)], 1)
    nrm = np.stack([b * np.cos(t), np.zeros_like(t), a * np.sin(t)], 1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    yax = np.array([0.0, 1.0, 0.0])
    pts = (
        c[:, None, :]
        + thick * np.cos(psi)[None, :, None] * nrm[:, None, :]
        + wide * np.sin(psi)[None, :, None] * yax[None, None, :]
    )  # (n_ring, n_tube, 3)
    idx = np.arange(n_ring * n_tube).reshape(n_ring, n_tube)
    i0, j0 = idx, np.roll(idx, -1, axis=1)
    i1, j1 = np.roll(idx, -1, axis=0), np.roll(np.roll(idx, -1, axis=0), -1, axis=1)
    faces = np.concatenate(
        [np.stack([i0, i1, j1], -1).reshape(-1, 3), np.stack([i0, j1, j0], -1).reshape(-1, 3)]
    )
    verts = pts.reshape(-1, 3)
    if _signed_volume(verts, faces) < 0:
        faces = faces[:, ::-1]
    solid = mesh_manifold(verts, faces)
    hulls = []
    for k in range(n_ring):
        seg = np.vstack([pts[k], pts[(k + 1) % n_ring]])
        if seg[:, 0].max() <= x_cut:
            continue
        piece = m.Manifold.hull_points(seg)
        if seg[:, 0].min() < x_cut:
            piece = piece.trim_by_plane((1.0, 0.0, 0.0), x_cut)
        if not piece.is_empty() and piece.volume() > 1e-10:
            hulls.append(np.asarray(piece.to_mesh64().vert_properties)[:, :3])
    return Shape(solid, hulls)


def tube(points: np.ndarray, radii: np.ndarray, segments: int = 24) -> Shape:
    """A tapering tube: the union of hulls of consecutive balls along a polyline (a spout)."""
    m = manifold3d_module()
    balls = [
        m.Manifold.sphere(float(r), segments).translate(tuple(p))
        for p, r in zip(points, radii, strict=True)
    ]
    pieces = [m.Manifold.batch_hull([a, b]) for a, b in itertools.pairwise(balls)]
    solid = m.Manifold.batch_boolean(pieces, m.OpType.Add)
    hulls = [np.asarray(p.to_mesh64().vert_properties)[:, :3] for p in pieces]
    return Shape(solid, hulls)


def _signed_volume(verts: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def half_turn_z(shape: Shape) -> Shape:
    """Turn a shape half a revolution about z (a handle built on +x moves to -x)."""
    return Shape(
        shape.solid.rotate((0.0, 0.0, 180.0)), [h * [-1.0, -1.0, 1.0] for h in shape.hulls]
    )


def radius_at(pr: np.ndarray, z: float) -> float:
    return float(np.interp(z, pr[:, 1], pr[:, 0]))


def cut_cavity(shape: Shape, cavity_cs) -> Shape:
    return Shape(shape.solid - revolve(cavity_cs), shape.hulls)


def inner_radius_max(cavity_cs, z0: float, z1: float) -> float:
    band = cavity_cs ^ rect(0.0, z0, 1.0, z1)
    polys = _polygons(band)
    return max((float(p[:, 0].max()) for p in polys), default=0.0)
