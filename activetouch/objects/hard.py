"""The generated hard library: 33 objects of 6-25 cm in look-alike families (issue 15).

On the paper's 7 objects every policy is right after one or two grasps, so the planner cannot
show what it is for. Here objects come in families whose members differ in one feature that a
grasp may or may not find: a mug with and without a handle or with the handle at another height,
bottles that differ only in the neck, boxes a centimetre apart, a cylinder and slightly tapered
ones, bowls of other depths, balls a centimetre apart. Everything is procedural (lathe profiles,
swept handles, boxes) with the same exact convex parts as the paper's builtins, so the set is
byte-for-byte reproducible and nothing is downloaded. Sizes are metres; profiles are (r, z).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from activetouch.objects.paper import cup_like, open_vessel
from activetouch.objects.shapes import (
    Shape,
    half_section,
    lathe,
    manifold3d_module,
    solid_of_revolution,
)

HARD_SET = "hard"


def _box(x: float, y: float, z: float) -> Shape:
    corners = np.array([[i * x, j * y, k * z] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return Shape(manifold3d_module().Manifold.cube((x, y, z)), [corners])


# --- mugs: one body, the handle absent or at three heights ----------------------------------

_MUG = [(0.038, 0.0), (0.0405, 0.004), (0.041, 0.012), (0.041, 0.095)]


def _mug(handle_z: float | None) -> Callable[[], Shape]:
    def make() -> Shape:
        if handle_z is None:
            return open_vessel(_MUG, 0.0045, 0.008)
        return cup_like(_MUG, 0.0045, 0.008, handle_z, 0.018, 1.2, 0.006, 0.009, 0.01)

    return make


# --- bottles: one body, four necks ------------------------------------------------------------


def _bottle(neck: str) -> Callable[[], Shape]:
    body = [(0.03, 0.0), (0.0335, 0.004), (0.034, 0.012), (0.034, 0.13)]
    necks = {
        "long": [(0.028, 0.15), (0.014, 0.17), (0.012, 0.215), (0.0, 0.2152)],
        "short": [(0.028, 0.15), (0.014, 0.165), (0.012, 0.18), (0.0, 0.1802)],
        "wide": [(0.03, 0.145), (0.022, 0.16), (0.02, 0.19), (0.0, 0.1902)],
        "lip": [
            *[(0.028, 0.15), (0.014, 0.17), (0.012, 0.2)],
            *[(0.016, 0.203), (0.016, 0.21), (0.0, 0.2102)],
        ],
    }

    def make() -> Shape:
        return solid_of_revolution(body + necks[neck])

    return make


# --- cylinders and slightly tapered ones ------------------------------------------------------


def _cylinder(r_bottom: float, r_top: float, h: float) -> Callable[[], Shape]:
    def make() -> Shape:
        return solid_of_revolution([(r_bottom, 0.0), (r_top, h), (0.0, h + 0.0002)])

    return make


# --- bowls, glasses, balls, jars, cones -------------------------------------------------------


def _bowl(depth: float, radius: float, foot: bool) -> Callable[[], Shape]:
    def make() -> Shape:
        base = 0.034
        ctrl = [(base, 0.0)]
        if foot:
            ctrl += [(base + 0.001, 0.008), (base + 0.01, 0.012)]
        ctrl += [
            (base + 0.45 * (radius - base) + 0.01, 0.45 * depth),
            (radius - 0.004, 0.85 * depth),
            (radius, depth),
        ]
        return open_vessel(ctrl, 0.004, 0.008)

    return make


def _glass(r_bottom: float, r_top: float, h: float) -> Callable[[], Shape]:
    def make() -> Shape:
        ctrl = [(r_bottom, 0.0), (r_bottom + 0.001, 0.004), (r_top, h)]
        return open_vessel(ctrl, 0.003, 0.012)

    return make


def _ball(rx: float, rz: float) -> Callable[[], Shape]:
    def make() -> Shape:
        a = np.linspace(-np.pi / 2, np.pi / 2, 33)[1:-1]
        pr = np.stack([rx * np.cos(a), rz + rz * np.sin(a)], 1)
        return lathe(half_section(pr))

    return make


def _jar(lid_r: float) -> Callable[[], Shape]:
    def make() -> Shape:
        return solid_of_revolution(
            [
                (0.04, 0.0),
                (0.0425, 0.005),
                (0.043, 0.014),
                (0.043, 0.08),
                (0.036, 0.092),
                (0.0362, 0.093),
                (lid_r, 0.0935),
                (lid_r, 0.11),
                (lid_r - 0.002, 0.113),
                (0.0, 0.1132),
            ]
        )

    return make


def _frustum(r_bottom: float, r_top: float, h: float) -> Callable[[], Shape]:
    return _cylinder(r_bottom, r_top, h)


# name -> (family, builder)
HARD_BUILDERS: dict[str, tuple[str, Callable[[], Shape]]] = {
    "h_mug_plain": ("mug", _mug(None)),
    "h_mug_handle_low": ("mug", _mug(0.03)),
    "h_mug_handle_mid": ("mug", _mug(0.048)),
    "h_mug_handle_high": ("mug", _mug(0.066)),
    "h_bottle_long_neck": ("bottle", _bottle("long")),
    "h_bottle_short_neck": ("bottle", _bottle("short")),
    "h_bottle_wide_neck": ("bottle", _bottle("wide")),
    "h_bottle_lip_neck": ("bottle", _bottle("lip")),
    "h_box_8x8x8": ("box", lambda: _box(0.08, 0.08, 0.08)),
    "h_box_9x8x8": ("box", lambda: _box(0.09, 0.08, 0.08)),
    "h_box_10x8x8": ("box", lambda: _box(0.10, 0.08, 0.08)),
    "h_box_8x8x9": ("box", lambda: _box(0.08, 0.08, 0.09)),
    "h_box_10x10x10": ("box", lambda: _box(0.10, 0.10, 0.10)),
    "h_box_6x6x12": ("box", lambda: _box(0.06, 0.06, 0.12)),
    "h_cyl_r40": ("cylinder", _cylinder(0.04, 0.04, 0.12)),
    "h_cyl_taper_r40_35": ("cylinder", _cylinder(0.04, 0.035, 0.12)),
    "h_cyl_taper_r40_30": ("cylinder", _cylinder(0.04, 0.03, 0.12)),
    "h_cyl_r35": ("cylinder", _cylinder(0.035, 0.035, 0.12)),
    "h_cyl_r40_tall": ("cylinder", _cylinder(0.04, 0.04, 0.13)),
    "h_bowl_shallow": ("bowl", _bowl(0.06, 0.075, False)),
    "h_bowl_deep": ("bowl", _bowl(0.08, 0.075, False)),
    "h_bowl_foot": ("bowl", _bowl(0.06, 0.075, True)),
    "h_glass_straight": ("glass", _glass(0.033, 0.034, 0.12)),
    "h_glass_tapered": ("glass", _glass(0.029, 0.037, 0.12)),
    "h_glass_short": ("glass", _glass(0.033, 0.036, 0.09)),
    "h_ball_8": ("ball", _ball(0.04, 0.04)),
    "h_ball_9": ("ball", _ball(0.045, 0.045)),
    "h_ellipsoid_9x7": ("ball", _ball(0.045, 0.035)),
    "h_egg_8x10": ("ball", _ball(0.04, 0.05)),
    "h_jar_lid_flush": ("jar", _jar(0.0415)),
    "h_jar_lid_wide": ("jar", _jar(0.047)),
    "h_cone_frustum": ("cone", _frustum(0.05, 0.02, 0.1)),
    "h_cone_frustum_steep": ("cone", _frustum(0.05, 0.03, 0.1)),
}

HARD_OBJECTS: tuple[str, ...] = tuple(HARD_BUILDERS)


def family(name: str) -> str:
    return HARD_BUILDERS[name][0]


def colour(name: str) -> tuple[float, float, float, float]:
    """A fixed colour per family (renders group look-alikes)."""
    palette = {
        "mug": (0.2, 0.35, 0.7, 1.0),
        "bottle": (0.25, 0.55, 0.3, 1.0),
        "box": (0.75, 0.6, 0.4, 1.0),
        "cylinder": (0.6, 0.6, 0.65, 1.0),
        "bowl": (0.85, 0.55, 0.3, 1.0),
        "glass": (0.8, 0.92, 0.95, 0.6),
        "ball": (0.85, 0.2, 0.2, 1.0),
        "jar": (0.8, 0.7, 0.45, 1.0),
        "cone": (0.5, 0.4, 0.7, 1.0),
    }
    return palette[family(name)]
