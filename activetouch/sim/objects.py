"""The object library: procedurally generated household objects and meshes a user imports.

Layout of a library directory (``<data>/objects``)::

    <name>/visual.obj          the watertight (or imported) surface, in the object frame
    <name>/collision_NNN.obj   convex parts whose union covers the object
    <name>/compound.obj        the same parts as one OBJ with one ``o`` group each
                               (PyBullet makes one convex hull per group: a compound shape)
    <name>/object.json         name, source, set, scale, extents, sha256, ...

The object frame has its origin at the bounding-box centre, axes parallel to the world; the
object stands upright on the table (z = 0) at (0, 0, extents[2] / 2).

Builtins are the 7 simulated objects and the 5 real ones of Zhang et al. (IROS 2017),
rebuilt as lathe profiles, swept handles and spouts with manifold3d booleans. Because the
generator knows each primitive, their convex parts are computed exactly from the 2-D
profiles (bands of the profile whose convex hull stays within ``HULL_TOL_M`` of it, split into
angular sectors where the band is a ring) instead of by a voxel decomposition, which fills
thin walls. Imported meshes are decomposed with CoACD (or PyBullet's V-HACD).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import itertools
import json
import math
import os
import re
import shutil
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from activetouch.errors import ActiveTouchError, DataError

PAPER_SIM_OBJECTS: tuple[str, ...] = (
    "cup",
    "teapot",
    "bowl",
    "bottle",
    "mug",
    "toilet_paper",
    "sphere",
)
PAPER_REAL_OBJECTS: tuple[str, ...] = (
    "mug_real",
    "bottle_real",
    "jar_real",
    "bowl_real",
    "glass_real",
)
BUILTIN_OBJECTS: tuple[str, ...] = PAPER_SIM_OBJECTS + PAPER_REAL_OBJECTS
GENERATED_SETS: tuple[str, ...] = ("hard",)  # generated on request (sim/library/)


def generated_set(name: str) -> tuple[str, ...]:
    """The object names of a generated set (`GENERATED_SETS`)."""
    if name != "hard":
        raise DataError(f"no generated set {name!r}; sets: {', '.join(GENERATED_SETS)}")
    from activetouch.sim.library.hard import HARD_OBJECTS

    return HARD_OBJECTS


def _generated_objects() -> tuple[str, ...]:
    return tuple(n for s in GENERATED_SETS for n in generated_set(s))


# Bump when a builtin's geometry changes: libraries regenerate builtins of an older version.
GENERATOR_VERSION = 1
FORMAT_VERSION = 1
MESH_SUFFIXES = (".obj", ".stl", ".urdf")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")

HULL_TOL_M = 0.00075  # how far a convex part may stray from the true surface
CIRCLE_SEGMENTS = 64  # facets around a lathe body (visual mesh)
# Imports: sizes outside this range are probably in the wrong unit (mm, inches).
PLAUSIBLE_SIZE_M = (0.01, 1.0)


@dataclass
class ObjectSpec:
    """One object of the library; all meshes are in the object frame, in metres."""

    name: str
    source: str  # "builtin" | "imported"
    visual_mesh: Path
    collision_meshes: list[Path]
    scale: float
    extents: np.ndarray  # (3,) bounding-box size
    set: str  # "sim" | "real" (the paper's sets) | "user"
    rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)
    compound_mesh: Path | None = None  # all parts in one OBJ (what spawn_object loads)
    meta: dict = field(default_factory=dict)  # the rest of object.json

    @property
    def directory(self) -> Path:
        return self.visual_mesh.parent

    @property
    def height(self) -> float:
        return float(self.extents[2])

    @property
    def support_z(self) -> float:
        """The table plane in the object frame: the object stands on it, centred."""
        return -self.height / 2


# --------------------------------------------------------------------------------------------
# Geometry: lathe profiles, sweeps and their exact convex parts
# --------------------------------------------------------------------------------------------


@dataclass
class Shape:
    """A watertight solid plus convex point clouds whose hulls cover it."""

    solid: object  # manifold3d.Manifold
    hulls: list[np.ndarray]  # each (n, 3): the part is the convex hull of these points

    def __add__(self, other: Shape) -> Shape:
        return Shape(self.solid + other.solid, self.hulls + other.hulls)


def _m():
    import manifold3d

    return manifold3d


def profile(ctrl: list[tuple[float, float]], step: float = 0.002) -> np.ndarray:
    """Sample a smooth lathe profile r(z) through control points (r, z), z increasing.

    Monotone cubic (PCHIP) interpolation: no overshoot, so steps (lids, caps) stay crisp.
    Returns (n, 2) points (r, z) from the bottom to the top.
    """
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


def _half_section(pr: np.ndarray, top_to_axis: bool = True):
    """The region between the axis and a profile, as a CrossSection in (r, z)."""
    m = _m()
    pts = [(0.0, pr[0, 1]), *map(tuple, pr)]
    if top_to_axis and pr[-1, 0] > 0:
        pts.append((0.0, pr[-1, 1]))
    return m.CrossSection([np.asarray(pts)])


def _mirrored(cs):
    return cs + cs.mirror((1.0, 0.0))


def _rect(x0: float, z0: float, x1: float, z1: float):
    return _m().CrossSection.square((x1 - x0, z1 - z0)).translate((x0, z0))


def vessel_section(pr: np.ndarray, wall: float, floor: float):
    """Half cross-section of an open vessel: outer profile `pr`, walls `wall` thick (normal
    offset), the cavity floor at height `floor`, open at the top."""
    m = _m()
    outer = _half_section(pr)
    # Continue the profile upwards so the offset cavity breaks through the rim.
    ext = np.vstack([pr, [pr[-1, 0], pr[-1, 1] + 1.0]])
    cav = _mirrored(_half_section(ext)).offset(-wall, m.JoinType.Round, 2.0, 48)
    cav = cav ^ _rect(0.0, floor, 1.0, pr[-1, 1] + 2.0)
    return outer - cav, cav


def revolve(cs) -> object:
    m = _m()
    # Booleans leave near-duplicate vertices (nm apart) that would merge when written.
    return m.Manifold.revolve(cs.simplify(1e-6), CIRCLE_SEGMENTS)


def _polygons(cs) -> list[np.ndarray]:
    return [np.asarray(p, dtype=np.float64) for p in cs.to_polygons()]


def _concavity(points: np.ndarray, probes: np.ndarray) -> float:
    """Largest distance from `probes` (inside) to the boundary of the hull of `points` (2-D)."""
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
        while j < len(levels) and _band_ok(cs ^ _rect(0.0, levels[i], 1.0, levels[j]), tol):
            best = j
            j += 1
        band = cs ^ _rect(0.0, levels[i], 1.0, levels[best])
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


def _mesh_manifold(verts: np.ndarray, faces: np.ndarray):
    m = _m()
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
    m = _m()
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
    solid = _mesh_manifold(verts, faces)
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
    m = _m()
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


def _rz(shape: Shape) -> Shape:
    """Turn a shape half a revolution about z (a handle built on +x moves to -x)."""
    return Shape(
        shape.solid.rotate((0.0, 0.0, 180.0)), [h * [-1.0, -1.0, 1.0] for h in shape.hulls]
    )


def _r_at(pr: np.ndarray, z: float) -> float:
    return float(np.interp(z, pr[:, 1], pr[:, 0]))


def _cut_cavity(shape: Shape, cavity_cs) -> Shape:
    return Shape(shape.solid - revolve(cavity_cs), shape.hulls)


def _inner_radius_max(cavity_cs, z0: float, z1: float) -> float:
    band = cavity_cs ^ _rect(0.0, z0, 1.0, z1)
    polys = _polygons(band)
    return max((float(p[:, 0].max()) for p in polys), default=0.0)


# --- the builtins (sizes in metres; r = radius) ---------------------------------------------


def _cup_like(
    ctrl: list[tuple[float, float]],
    wall: float,
    floor: float,
    handle_z: float,
    ring: float,
    stretch: float,
    thick: float,
    wide: float,
    gap: float,
) -> Shape:
    pr = profile(ctrl)
    section, cavity = vessel_section(pr, wall, floor)
    body = lathe(section)
    r_out = _r_at(pr, handle_z)
    zspan = ring * stretch + thick
    x_cut = _inner_radius_max(cavity, handle_z - zspan, handle_z + zspan) + 0.0005
    h = handle((r_out + gap, handle_z), ring, stretch, thick, wide, x_cut)
    return _cut_cavity(body + h, _mirrored(cavity))


def make_cup() -> Shape:
    """A tea cup: tapered, thin-walled, a thin round C handle."""
    ctrl = [(0.027, 0.0), (0.028, 0.004), (0.031, 0.012), (0.036, 0.035), (0.041, 0.072)]
    return _cup_like(ctrl, 0.003, 0.006, 0.043, 0.016, 1.25, 0.0035, 0.0035, 0.009)


def make_mug() -> Shape:
    """A coffee mug: straight cylinder, thick walls, a thick D-shaped handle."""
    ctrl = [(0.038, 0.0), (0.0415, 0.004), (0.042, 0.012), (0.042, 0.098)]
    return _cup_like(ctrl, 0.0045, 0.008, 0.05, 0.021, 1.45, 0.0065, 0.0095, 0.011)


def make_mug_real() -> Shape:
    """A glass mug: slightly barrelled, thick glass base, a tall round handle."""
    ctrl = [(0.036, 0.0), (0.0385, 0.006), (0.0405, 0.04), (0.0405, 0.075), (0.039, 0.105)]
    return _cup_like(ctrl, 0.004, 0.014, 0.055, 0.02, 1.7, 0.0055, 0.0055, 0.012)


def _open_vessel(ctrl: list[tuple[float, float]], wall: float, floor: float) -> Shape:
    section, _ = vessel_section(profile(ctrl), wall, floor)
    return lathe(section)


def make_bowl() -> Shape:
    """A round soup bowl on a foot ring."""
    ctrl = [
        (0.033, 0.0),
        (0.034, 0.007),
        (0.045, 0.011),
        (0.06, 0.021),
        (0.072, 0.037),
        (0.0785, 0.055),
        (0.08, 0.066),
    ]
    return _open_vessel(ctrl, 0.004, 0.009)


def make_bowl_real() -> Shape:
    """A cereal bowl: deeper, straighter (conical) sides."""
    ctrl = [(0.03, 0.0), (0.031, 0.006), (0.04, 0.01), (0.055, 0.025), (0.066, 0.045), (0.07, 0.06)]
    return _open_vessel(ctrl, 0.0035, 0.008)


def make_glass_real() -> Shape:
    """A drinking glass (tumbler): tapered, thin wall, heavy base."""
    ctrl = [(0.029, 0.0), (0.0305, 0.003), (0.031, 0.01), (0.037, 0.12)]
    return _open_vessel(ctrl, 0.0025, 0.012)


def make_bottle() -> Shape:
    """A wine bottle: cylinder, rounded shoulder, long neck, lip."""
    ctrl = [
        (0.033, 0.0),
        (0.0365, 0.004),
        (0.037, 0.012),
        (0.037, 0.15),
        (0.031, 0.175),
        (0.018, 0.195),
        (0.014, 0.21),
        (0.0135, 0.232),
        (0.0158, 0.2335),
        (0.0158, 0.24),
        (0.0135, 0.2415),
        (0.0, 0.2416),
    ]
    return lathe(_half_section(profile(ctrl)))


def make_bottle_real() -> Shape:
    """A plastic water bottle: grip grooves, short shoulder, neck ring and screw cap."""
    ctrl = [
        (0.029, 0.0),
        (0.0325, 0.005),
        (0.0325, 0.05),
        (0.0295, 0.058),
        (0.0325, 0.066),
        (0.0325, 0.09),
        (0.0295, 0.098),
        (0.0325, 0.106),
        (0.0325, 0.14),
        (0.024, 0.162),
        (0.014, 0.172),
        (0.0135, 0.176),
        (0.0175, 0.1765),
        (0.0175, 0.179),
        (0.0135, 0.1795),
        (0.0135, 0.181),
        (0.0158, 0.1812),
        (0.0158, 0.199),
        (0.014, 0.2),
        (0.0, 0.2001),
    ]
    return lathe(_half_section(profile(ctrl)))


def make_jar_real() -> Shape:
    """A jar with a screw lid: rounded body, shoulder, neck, a wider lid on top."""
    ctrl = [
        (0.038, 0.0),
        (0.0425, 0.005),
        (0.043, 0.014),
        (0.043, 0.085),
        (0.04, 0.096),
        (0.036, 0.1),
        (0.0362, 0.101),
        (0.0405, 0.1015),
        (0.041, 0.119),
        (0.039, 0.122),
        (0.0, 0.1222),
    ]
    return lathe(_half_section(profile(ctrl)))


def make_toilet_paper() -> Shape:
    """A toilet-paper roll: a thick tube around a hollow cardboard core."""
    m = _m()
    r_in, r_out, h, rad = 0.021, 0.055, 0.1, 0.004
    # Rounded outer edges (a soft roll); the cardboard core's faces stay flat.
    corners = m.CrossSection.circle(rad, 32)
    section = (
        _rect(r_in, 0.0, r_out - rad, h)
        + _rect(r_in, rad, r_out, h - rad)
        + corners.translate((r_out - rad, rad))
        + corners.translate((r_out - rad, h - rad))
    )
    return lathe(section)


def make_sphere() -> Shape:
    """A ball 0.1 m across."""
    r = 0.05
    a = np.linspace(-np.pi / 2, np.pi / 2, 33)
    pr = np.stack([r * np.cos(a), r + r * np.sin(a)], 1)
    pr[0, 0] = pr[-1, 0] = 0.0
    return lathe(_half_section(pr[1:-1]))


def make_teapot() -> Shape:
    """A teapot: round body, lid with knob, curved spout (+x) and loop handle (-x)."""
    body_ctrl = [
        (0.045, 0.0),
        (0.05, 0.003),
        (0.062, 0.014),
        (0.07, 0.04),
        (0.066, 0.07),
        (0.052, 0.09),
        (0.042, 0.098),
        (0.0405, 0.1),
    ]
    body = lathe(_half_section(profile(body_ctrl)))
    lid_ctrl = [
        (0.043, 0.099),
        (0.0435, 0.1015),
        (0.038, 0.11),
        (0.026, 0.117),
        (0.006, 0.121),
        (0.005, 0.125),
        (0.011, 0.13),
        (0.0105, 0.136),
        (0.0, 0.139),
    ]
    lid = lathe(_half_section(profile(lid_ctrl, step=0.0015)))
    path = np.array(
        [
            [0.045, 0.0, 0.03],
            [0.075, 0.0, 0.04],
            [0.095, 0.0, 0.058],
            [0.108, 0.0, 0.08],
            [0.118, 0.0, 0.1],
        ]
    )
    spout = tube(path, np.array([0.016, 0.012, 0.009, 0.0075, 0.0065]))
    hdl = _rz(handle((0.068 + 0.012, 0.058), 0.026, 1.3, 0.006, 0.008, x_cut=0.05))
    return body + lid + spout + hdl


BUILDERS: dict[str, Callable[[], Shape]] = {
    "cup": make_cup,
    "teapot": make_teapot,
    "bowl": make_bowl,
    "bottle": make_bottle,
    "mug": make_mug,
    "toilet_paper": make_toilet_paper,
    "sphere": make_sphere,
    "mug_real": make_mug_real,
    "bottle_real": make_bottle_real,
    "jar_real": make_jar_real,
    "bowl_real": make_bowl_real,
    "glass_real": make_glass_real,
}

COLOURS: dict[str, tuple[float, float, float, float]] = {
    "cup": (0.93, 0.91, 0.86, 1.0),
    "teapot": (0.55, 0.32, 0.2, 1.0),
    "bowl": (0.85, 0.55, 0.3, 1.0),
    "bottle": (0.25, 0.55, 0.3, 1.0),
    "mug": (0.2, 0.35, 0.7, 1.0),
    "toilet_paper": (0.97, 0.97, 0.97, 1.0),
    "sphere": (0.85, 0.2, 0.2, 1.0),
    "mug_real": (0.75, 0.88, 0.92, 0.6),
    "bottle_real": (0.6, 0.8, 0.95, 0.6),
    "jar_real": (0.8, 0.7, 0.45, 1.0),
    "bowl_real": (0.9, 0.9, 0.85, 1.0),
    "glass_real": (0.8, 0.92, 0.95, 0.5),
}


# --------------------------------------------------------------------------------------------
# Mesh I/O (our own OBJ writer: fixed formatting, so generation is byte-for-byte repeatable)
# --------------------------------------------------------------------------------------------


def convex_hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward-oriented triangles of the convex hull of `points`."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(np.asarray(points, dtype=np.float64))
    faces = hull.simplices.copy()
    v = hull.points
    n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    flip = np.einsum("ij,ij->i", n, hull.equations[:, :3]) < 0
    faces[flip] = faces[flip][:, ::-1]
    used = np.unique(faces)
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[faces]


def _obj_text(groups: list[tuple[str, np.ndarray, np.ndarray]]) -> str:
    lines = ["# activetouch object mesh (metres, object frame)"]
    base = 1
    for name, verts, faces in groups:
        if name:
            lines.append(f"o {name}")
        lines.extend(f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(verts))
        lines.extend(f"f {a} {b} {c}" for a, b, c in (np.asarray(faces, dtype=np.int64) + base))
        base += len(verts)
    return "\n".join(lines) + "\n"


def write_obj(path: Path, verts: np.ndarray, faces: np.ndarray) -> None:
    path.write_text(_obj_text([("", verts, faces)]))


def read_obj_groups(path: Path) -> list[np.ndarray]:
    """Vertex arrays of each ``o``/``g`` group of an OBJ (what a decomposer writes)."""
    groups: list[list[list[float]]] = []
    cur: list[list[float]] | None = None
    with open(path) as f:
        for line in f:
            if line.startswith(("o ", "g ")):
                cur = []
                groups.append(cur)
            elif line.startswith("v "):
                if cur is None:
                    cur = []
                    groups.append(cur)
                cur.append([float(x) for x in line.split()[1:4]])
    return [np.asarray(g, dtype=np.float64) for g in groups if len(g) >= 4]


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# Writing an object directory
# --------------------------------------------------------------------------------------------


@dataclass
class _Built:
    verts: np.ndarray
    faces: np.ndarray
    parts: list[tuple[np.ndarray, np.ndarray]]  # convex (verts, faces)
    axis_xy: np.ndarray | None = None  # where a builtin's lathe axis is in the object frame


def shape_to_meshes(shape: Shape) -> _Built:
    """Visual mesh and convex parts of a generated shape, moved into the object frame."""
    mesh = shape.solid.simplify(1e-6).to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = (lo + hi) / 2.0
    parts = [convex_hull_mesh(h - centre) for h in shape.hulls]
    return _Built(verts - centre, faces, parts, axis_xy=-centre[:2])


def _write_object_dir(d: Path, built: _Built, meta: dict) -> None:
    write_obj(d / "visual.obj", built.verts, built.faces)
    for i, (v, f) in enumerate(built.parts):
        write_obj(d / f"collision_{i:03d}.obj", v, f)
    (d / "compound.obj").write_text(
        _obj_text([(f"part_{i:03d}", v, f) for i, (v, f) in enumerate(built.parts)])
    )
    ext = built.verts.max(axis=0) - built.verts.min(axis=0)
    meta = {
        "format": FORMAT_VERSION,
        **meta,
        "extents": [round(float(e), 6) for e in ext],
        "n_parts": len(built.parts),
        "n_triangles": len(built.faces),
    }
    (d / "object.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")


def _fsync_dir(d: Path) -> None:
    for p in sorted(d.iterdir()):
        with open(p, "rb") as f:
            os.fsync(f.fileno())


# --------------------------------------------------------------------------------------------
# Importing a user's mesh
# --------------------------------------------------------------------------------------------


def _urdf_mesh(path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """(mesh file, per-axis scale, 4x4 origin) of the first link's collision (else visual) mesh."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as e:
        raise DataError(f"{path}: not a readable URDF ({e})") from e
    if root.tag != "robot":
        raise DataError(f"{path}: not a URDF (root element <{root.tag}>, expected <robot>)")
    for link in root.findall("link"):
        for kind in ("collision", "visual"):
            for el in link.findall(kind):
                mesh = el.find("geometry/mesh")
                if mesh is None or not mesh.get("filename"):
                    continue
                scale = np.ones(3)
                if mesh.get("scale"):
                    try:
                        scale = np.array([float(s) for s in mesh.get("scale", "").split()])
                    except ValueError as e:
                        raise DataError(f"{path}: bad mesh scale {mesh.get('scale')!r}") from e
                    if scale.size == 1:
                        scale = np.repeat(scale, 3)
                    if scale.size != 3:
                        raise DataError(f"{path}: bad mesh scale {mesh.get('scale')!r}")
                origin = np.eye(4)
                o = el.find("origin")
                if o is not None:
                    origin = _urdf_origin(path, o)
                return _resolve_urdf_file(path, mesh.get("filename", "")), scale, origin
        raise DataError(f"{path}: link {link.get('name')!r} has no collision or visual mesh")
    raise DataError(f"{path}: URDF has no <link>")


def _urdf_origin(path: Path, o: ET.Element) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    try:
        xyz = [float(v) for v in o.get("xyz", "0 0 0").split()]
        rpy = [float(v) for v in o.get("rpy", "0 0 0").split()]
        if len(xyz) != 3 or len(rpy) != 3:
            raise ValueError("need 3 numbers")
    except ValueError as e:
        raise DataError(f"{path}: bad <origin> ({e})") from e
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF rpy: fixed axes x, y, z
    T[:3, 3] = xyz
    return T


def _resolve_urdf_file(urdf: Path, filename: str) -> Path:
    tried = []
    if filename.startswith("file://"):
        tried.append(Path(filename[len("file://") :]))
    elif filename.startswith("package://"):
        rest = filename[len("package://") :]
        _pkg, _, inner = rest.partition("/")
        # Without ROS we cannot look packages up: try the URDF's folder and its parents.
        for base in [urdf.parent, *list(urdf.parent.parents)[:3]]:
            tried += [base / rest, base / inner]
    else:
        p = Path(filename)
        tried.append(p if p.is_absolute() else urdf.parent / p)
    for p in tried:
        if p.is_file():
            return p
    raise DataError(
        f"{urdf}: mesh file {filename!r} not found (looked at {', '.join(map(str, tried))})"
    )


def load_mesh(path: Path, scale: float = 1.0):
    """Read an OBJ/STL/URDF as one trimesh.Trimesh in metres; errors -> DataError."""
    import trimesh

    path = Path(path)
    if not path.exists():
        raise DataError(f"mesh file not found: {path}")
    if not path.is_file():
        raise DataError(f"not a file: {path}")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise DataError(f"{path}: unsupported mesh format {suffix!r} (use .obj, .stl or .urdf)")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: empty file")
    if not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
        raise ActiveTouchError(f"scale must be a positive number, got {scale!r}")
    axis_scale, T = np.ones(3), np.eye(4)
    mesh_path = path
    if suffix == ".urdf":
        mesh_path, axis_scale, T = _urdf_mesh(path)
        if mesh_path.suffix.lower() not in (".obj", ".stl"):
            raise DataError(f"{path}: mesh {mesh_path.name} is not OBJ or STL")
        if mesh_path.stat().st_size == 0:
            raise DataError(f"{mesh_path}: empty file")
    # Before reading: a reader may choke on a cut file with an unrelated message, or keep
    # what it could parse of it and look whole.
    _check_not_truncated(mesh_path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = trimesh.load(str(mesh_path), force="mesh", process=True)
    except Exception as e:  # trimesh raises many types for malformed files
        raise DataError(f"{mesh_path}: cannot read mesh ({type(e).__name__}: {e})") from e
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or len(mesh.vertices) < 4:
        raise DataError(f"{mesh_path}: no triangles found (malformed or empty mesh)")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise DataError(f"{mesh_path}: vertices are not finite numbers")
    v = v * axis_scale
    v = v @ T[:3, :3].T + T[:3, 3]
    mesh = trimesh.Trimesh(v * float(scale), np.asarray(mesh.faces), process=True)
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise DataError(f"{mesh_path}: all triangles are degenerate")
    return mesh


def _check_not_truncated(path: Path) -> None:
    """DataError if the file was cut short (a copy that stopped, a download that broke): mesh
    readers keep what they could parse and say nothing, which would import half an object."""
    data = path.read_bytes()
    suffix = path.suffix.lower()
    cut = f"{path}: the file is truncated"
    if suffix == ".stl":
        if data[:5].lower() == b"solid" and b"facet" in data[:1000]:
            if b"endsolid" not in data[-1000:].lower():
                raise DataError(f"{cut} (ASCII STL without 'endsolid')")
        elif len(data) >= 84:
            n = int.from_bytes(data[80:84], "little")
            if len(data) < 84 + 50 * n:
                have = (len(data) - 84) // 50
                raise DataError(f"{cut} ({n} triangles announced, {have} present)")
        else:
            raise DataError(f"{cut} (shorter than a binary STL header)")
    elif suffix == ".obj":
        n_vertices, max_index = 0, 0
        for line in data.decode("utf-8", errors="replace").splitlines():
            if line.startswith("v "):
                n_vertices += 1
            elif line.startswith("f "):
                for token in line.split()[1:]:
                    head = token.split("/")[0]
                    if head.lstrip("-").isdigit():
                        max_index = max(max_index, int(head))
        if max_index > n_vertices:
            raise DataError(
                f"{path}: a face uses vertex {max_index} of {n_vertices} (the file is truncated "
                "or malformed)"
            )
        last = data.rstrip(b"\r\n").rsplit(b"\n", 1)[-1].split()
        if last[:1] in ([b"v"], [b"f"]) and len(last) < 4:
            raise DataError(f"{cut} (its last line is incomplete: {b' '.join(last).decode()!r})")


def decompose(verts: np.ndarray, faces: np.ndarray, method: str = "coacd") -> list[np.ndarray]:
    """Convex parts (as point sets) of a concave mesh, with CoACD or PyBullet's V-HACD."""
    if method == "coacd":
        return _decompose_coacd(verts, faces)
    if method == "vhacd":
        return _decompose_vhacd(verts, faces)
    raise ActiveTouchError(f"unknown decomposition {method!r} (use coacd or vhacd)")


def _decompose_coacd(verts: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    try:
        import coacd
    except ImportError as e:
        raise ActiveTouchError(
            "coacd is not installed (pip install coacd), or use the vhacd decomposition"
        ) from e

    coacd.set_log_level("error")
    # Tuned for speed (a few seconds for a mug-like mesh); ~1 mm surface error at 0.1 m.
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(verts, dtype=np.float64), np.asarray(faces, dtype=np.int64)),
        threshold=0.05,
        preprocess_mode="auto",
        preprocess_resolution=40,
        resolution=1000,
        mcts_nodes=10,
        mcts_iterations=60,
        mcts_max_depth=2,
        max_convex_hull=-1,
        seed=0,
    )
    return [np.asarray(v, dtype=np.float64) for v, _f in parts if len(v) >= 4]


@contextlib.contextmanager
def _quiet_fds() -> Iterator[None]:
    """Silence C-level stdout/stderr (V-HACD prints its progress there)."""
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)


def _decompose_vhacd(verts: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    import pybullet as p

    with tempfile.TemporaryDirectory() as td:
        src, dst, log = Path(td) / "in.obj", Path(td) / "out.obj", Path(td) / "log.txt"
        write_obj(src, verts, faces)
        with _quiet_fds():
            cid = p.connect(p.DIRECT)  # a fresh client, so no simulation state is touched
            try:
                p.vhacd(
                    str(src),
                    str(dst),
                    str(log),
                    resolution=200000,
                    concavity=0.001,
                    physicsClientId=cid,
                )
            finally:
                p.disconnect(cid)
        if not dst.exists():
            raise DataError("V-HACD produced no output")
        return read_obj_groups(dst)


# --------------------------------------------------------------------------------------------
# The library
# --------------------------------------------------------------------------------------------


class ObjectLibrary:
    """Objects stored under `root` (normally ``paths.objects_dir(paths.data_dir())``)."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)

    @classmethod
    def in_data_dir(cls, data: Path | str | None = None) -> ObjectLibrary:
        from activetouch import paths

        return cls(paths.objects_dir(paths.data_dir(data)))

    # -- queries -----------------------------------------------------------------------------

    def names(self) -> list[str]:
        """Objects present: builtins in the paper's order, then imported ones by name."""
        if not self.root.is_dir():
            return []
        have = {
            p.name
            for p in self.root.iterdir()
            if p.is_dir() and not p.name.startswith(".") and (p / "object.json").is_file()
        }
        ordered = BUILTIN_OBJECTS + _generated_objects()
        return [n for n in ordered if n in have] + sorted(have - set(ordered))

    def __contains__(self, name: str) -> bool:
        return (self.root / name / "object.json").is_file()

    def get(self, name: str) -> ObjectSpec:
        d = self.root / name
        if not NAME_RE.match(name) or not (d / "object.json").is_file():
            known = ", ".join(self.names()) or "none"
            hint = (
                " (run ensure_builtins / `activetouch objects list`)"
                if name in BUILTIN_OBJECTS
                else ""
            )
            raise DataError(f"unknown object {name!r} in {self.root}{hint}; known: {known}")
        return _read_spec(d)

    def specs(self) -> list[ObjectSpec]:
        return [self.get(n) for n in self.names()]

    # -- builtins ----------------------------------------------------------------------------

    def ensure_builtins(self, names: list[str] | tuple[str, ...] | None = None) -> list[str]:
        """Generate the builtins that are missing or from an older generator; returns the
        names (re)generated. Safe to call from several processes at once."""
        wanted = list(BUILTIN_OBJECTS if names is None else names)
        for n in wanted:
            if n not in BUILDERS and n not in _generated_objects():
                raise DataError(f"no builtin object {n!r}; builtins: {', '.join(BUILTIN_OBJECTS)}")
        todo = [n for n in wanted if not self._builtin_current(n)]
        if not todo:
            return []
        made = []
        with self._lock():
            for n in todo:
                if self._builtin_current(n):  # another process made it meanwhile
                    continue
                self._install(n, lambda d, n=n: _build_builtin(n, d))
                made.append(n)
        return made

    def ensure_set(self, name: str) -> list[str]:
        """Generate a generated set (e.g. "hard") like the builtins; returns the names made."""
        return self.ensure_builtins(generated_set(name))

    def _builtin_current(self, name: str) -> bool:
        f = self.root / name / "object.json"
        if not f.is_file():
            return False
        try:
            meta = json.loads(f.read_text())
        except (OSError, ValueError):
            return False
        return (
            meta.get("source") == "builtin" and meta.get("generator_version") == GENERATOR_VERSION
        )

    # -- imports -----------------------------------------------------------------------------

    def add(
        self,
        name: str,
        path: Path | str,
        scale: float = 1.0,
        *,
        overwrite: bool = False,
        decomposition: str = "coacd",
    ) -> ObjectSpec:
        """Import a mesh (OBJ, STL or URDF) scaled by `scale` into the library as `name`.

        The object frame is put at its bounding-box centre. Concave meshes are split into
        convex parts. On any error the library is left as it was.
        """
        if not isinstance(name, str) or not NAME_RE.match(name):
            raise ActiveTouchError(
                f"invalid object name {name!r}: use 1-64 letters, digits, '_' or '-', "
                "starting with a letter or digit"
            )
        if name in BUILTIN_OBJECTS or name in _generated_objects():
            raise ActiveTouchError(f"{name!r} is a builtin object and cannot be replaced")
        if name in self and not overwrite:
            raise ActiveTouchError(
                f"object {name!r} already exists in {self.root} (replace it with --force)"
            )
        if decomposition not in ("coacd", "vhacd"):
            raise ActiveTouchError(f"unknown decomposition {decomposition!r} (use coacd or vhacd)")
        src = Path(path)
        mesh = load_mesh(src, scale)
        built, info = _import_meshes(mesh, src, decomposition)
        meta = {
            "name": name,
            "source": "imported",
            "set": "user",
            "scale": float(scale),
            "source_file": str(src.resolve()),
            "sha256": _sha256(src),
            "rgba": [0.7, 0.7, 0.75, 1.0],
            **info,
        }
        with self._lock():
            self._install(name, lambda d: _write_object_dir(d, built, meta))
        return self.get(name)

    def remove(self, name: str) -> None:
        if name in BUILTIN_OBJECTS or name in _generated_objects():
            raise ActiveTouchError(f"{name!r} is a builtin object and cannot be removed")
        if name not in self:
            raise DataError(f"unknown object {name!r} in {self.root}")
        with self._lock():
            shutil.rmtree(self.root / name)

    # -- plumbing ----------------------------------------------------------------------------

    @contextlib.contextmanager
    def _lock(self) -> Iterator[None]:
        self.root.mkdir(parents=True, exist_ok=True)
        with open(self.root / ".lock", "a") as f:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(f.fileno(), fcntl.LOCK_UN)

    def _install(self, name: str, fill: Callable[[Path], None]) -> None:
        """Build an object directory in a temporary place, then swap it in by renames."""
        tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{name}-", dir=self.root))
        old: Path | None = None
        try:
            fill(tmp)
            _fsync_dir(tmp)
            final = self.root / name
            if final.exists():
                old = Path(tempfile.mkdtemp(prefix=f".old-{name}-", dir=self.root))
                os.rename(final, old / name)
            os.rename(tmp, final)
        except BaseException:
            if old is not None and not (self.root / name).exists():
                os.rename(old / name, self.root / name)
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        finally:
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)


def _build_builtin(name: str, d: Path) -> None:
    if name in BUILDERS:
        shape, set_name, rgba = BUILDERS[name](), None, COLOURS[name]
    else:
        from activetouch.sim.library import hard

        shape, set_name, rgba = hard.HARD_BUILDERS[name][1](), hard.HARD_SET, hard.colour(name)
    built = shape_to_meshes(shape)
    write_obj(d / "visual.obj", built.verts, built.faces)
    meta = {
        "name": name,
        "source": "builtin",
        "set": set_name or ("sim" if name in PAPER_SIM_OBJECTS else "real"),
        "scale": 1.0,
        "generator_version": GENERATOR_VERSION,
        "decomposition": "lathe",
        "rgba": list(rgba),
        **({"family": hard.family(name)} if set_name else {}),
        # A builtin's source is its generated surface: the hash pins the geometry.
        "sha256": _sha256(d / "visual.obj"),
        # The body's axis of revolution (off the bbox centre when there is a handle/spout).
        "axis_xy": [round(float(a), 6) for a in built.axis_xy],
    }
    _write_object_dir(d, built, meta)


def fill_holes(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Close each boundary loop of a consistently wound mesh with a fan around its centroid.

    Returns (verts, faces, number of holes closed); the input unchanged if the open edges do
    not form loops (then the caller sees the mesh is still open)."""
    f = np.asarray(faces, dtype=np.int64)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    have = {(int(a), int(b)) for a, b in directed}
    boundary = [(a, b) for a, b in map(tuple, directed.tolist()) if (b, a) not in have]
    nxt: dict[int, list[int]] = {}
    for a, b in sorted(boundary):
        nxt.setdefault(a, []).append(b)
    v = [np.asarray(verts, dtype=np.float64)]
    new_faces = [f]
    n_v = len(verts)
    holes = 0
    # Open edges of a consistently wound surface form cycles (in = out at every vertex, also
    # where two holes touch), so walking from any open edge comes back to its start.
    while nxt:
        start = min(nxt)
        loop = [start]
        while True:
            outs = nxt.get(loop[-1])
            if not outs:
                return verts, faces, 0
            b = outs.pop(0)
            if not outs:
                del nxt[loop[-1]]
            if b == start:
                break
            loop.append(b)
        ring = np.asarray(loop)
        v.append(v[0][ring].mean(axis=0, keepdims=True))
        # Each open edge a->b belongs to a face; the patch face runs b->a to match it.
        new_faces.append(np.stack([np.roll(ring, -1), ring, np.full(len(ring), n_v)], axis=1))
        n_v += 1
        holes += 1
    return np.vstack(v), np.vstack(new_faces), holes


def _simplified_for_decomposition(verts: np.ndarray, faces: np.ndarray):
    """Large meshes slow the decomposition down: merge edges shorter than 0.5 mm first."""
    if len(faces) <= 20000:
        return verts, faces
    try:
        m = _mesh_manifold(verts, faces).simplify(5e-4)
    except ValueError:
        return verts, faces
    mesh = m.to_mesh64()
    return np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def _import_meshes(mesh, src: Path, method: str) -> tuple[_Built, dict]:
    import trimesh

    lo, hi = mesh.bounds
    ext = hi - lo
    if float(ext.min()) < 1e-6:
        raise DataError(
            f"{src}: the mesh is flat (extents {np.round(ext, 6).tolist()} m): zero volume"
        )
    if not (PLAUSIBLE_SIZE_M[0] <= float(ext.max()) <= PLAUSIBLE_SIZE_M[1]):
        warnings.warn(
            f"{src}: object is {float(ext.max()):.4g} m across after scaling; "
            "is the unit right (e.g. --scale 0.001 for millimetres)?",
            stacklevel=3,
        )
    centre = (lo + hi) / 2.0
    verts = np.asarray(mesh.vertices, dtype=np.float64) - centre
    faces = np.asarray(mesh.faces, dtype=np.int64)
    watertight = bool(mesh.is_watertight)
    solid, holes = mesh, 0
    if not watertight:
        fv, ff, holes = fill_holes(verts, faces)
        solid = trimesh.Trimesh(fv, ff, process=False)
        if holes and solid.is_watertight and solid.is_winding_consistent:
            warnings.warn(
                f"{src}: mesh is not watertight; closed {holes} hole(s) for its collision shape",
                stacklevel=3,
            )
        else:
            solid = None
            warnings.warn(
                f"{src}: mesh is not watertight and its holes could not be closed; "
                "its collision shape is its convex hull (repair the mesh for a faithful one)",
                stacklevel=3,
            )
    hull_vol = float(mesh.convex_hull.volume)
    if solid is None:
        volume = hull_vol
        clouds, used = [verts], "convex-hull"
    else:
        volume = abs(float(solid.volume))
        if volume < 1e-12:
            raise DataError(f"{src}: the mesh encloses zero volume")
        if hull_vol <= volume * 1.02:
            clouds, used = [verts], "convex"
        else:
            sv, sf = np.asarray(solid.vertices), np.asarray(solid.faces, dtype=np.int64)
            if float(solid.volume) < 0:
                sf = sf[:, ::-1]
            clouds, used = decompose(*_simplified_for_decomposition(sv, sf), method), method
            if not clouds:
                raise DataError(f"{src}: convex decomposition ({method}) produced no parts")
    parts = [convex_hull_mesh(c) for c in clouds]
    info = {
        "decomposition": used,
        "watertight": watertight,
        "holes_closed": holes,
        "volume": volume,
    }
    return _Built(verts, faces, parts), info


def _read_spec(d: Path) -> ObjectSpec:
    f = d / "object.json"
    try:
        meta = json.loads(f.read_text())
        ext = np.asarray(meta["extents"], dtype=np.float64).reshape(3)
        spec = ObjectSpec(
            name=str(meta["name"]),
            source=str(meta["source"]),
            visual_mesh=d / "visual.obj",
            collision_meshes=sorted(d.glob("collision_*.obj")),
            scale=float(meta["scale"]),
            extents=ext,
            set=str(meta["set"]),
            rgba=tuple(float(c) for c in meta.get("rgba", (0.8, 0.8, 0.8, 1.0))),  # type: ignore[arg-type]
            compound_mesh=(d / "compound.obj") if (d / "compound.obj").is_file() else None,
            meta=meta,
        )
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise DataError(f"{f}: unreadable object description ({e})") from e
    if meta.get("format") != FORMAT_VERSION:
        raise DataError(f"{f}: object format {meta.get('format')!r}, expected {FORMAT_VERSION}")
    if not spec.visual_mesh.is_file() or not spec.collision_meshes:
        raise DataError(f"{d}: object is incomplete (visual.obj or collision_*.obj missing)")
    return spec


# --------------------------------------------------------------------------------------------
# PyBullet
# --------------------------------------------------------------------------------------------


def spawn_object(
    client_id: int,
    spec: ObjectSpec,
    *,
    visual: bool = True,
    position: tuple[float, float, float] | None = None,
) -> int:
    """Create the object as a fixed body standing on the table: its centre at
    (0, 0, extents[2] / 2) unless `position` is given. Returns the body id."""
    import pybullet as p

    compound = spec.compound_mesh
    tmp: str | None = None
    if compound is None:
        # PyBullet's shape arrays stop at 16 children; one OBJ with a group per part does not.
        fd, tmp = tempfile.mkstemp(suffix=".obj")
        os.close(fd)
        Path(tmp).write_text("".join(_regroup(spec.collision_meshes)))
        compound = Path(tmp)
    try:
        col = p.createCollisionShape(p.GEOM_MESH, fileName=str(compound), physicsClientId=client_id)
    finally:
        if tmp:
            os.unlink(tmp)
    if col < 0:
        raise DataError(f"{compound}: PyBullet could not load the collision mesh")
    vis = -1
    if visual:
        vis = p.createVisualShape(
            p.GEOM_MESH,
            fileName=str(spec.visual_mesh),
            rgbaColor=list(spec.rgba),
            physicsClientId=client_id,
        )
    pos = (0.0, 0.0, spec.height / 2.0) if position is None else tuple(position)
    return p.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=col,
        baseVisualShapeIndex=vis,
        basePosition=pos,
        physicsClientId=client_id,
    )


def _regroup(files: list[Path]) -> Iterator[str]:
    base = 0
    for i, fpath in enumerate(files):
        yield f"o part_{i:03d}\n"
        n = 0
        for line in Path(fpath).read_text().splitlines():
            if line.startswith("v "):
                n += 1
                yield line + "\n"
            elif line.startswith("f "):
                idx = [int(t.split("/")[0]) + base for t in line.split()[1:]]
                yield "f " + " ".join(map(str, idx)) + "\n"
        base += n
