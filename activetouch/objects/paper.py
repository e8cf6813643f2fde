"""The paper's objects (Zhang et al., IROS 2017): its 7 simulated and 5 real ones, rebuilt
as lathe profiles, swept handles and spouts (sizes in metres; r = radius)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from activetouch.objects.shapes import (
    Shape,
    cut_cavity,
    half_section,
    half_turn_z,
    handle,
    inner_radius_max,
    lathe,
    manifold3d_module,
    mirrored,
    profile,
    radius_at,
    rect,
    solid_of_revolution,
    tube,
    vessel_section,
)


def cup_like(
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
    r_out = radius_at(pr, handle_z)
    zspan = ring * stretch + thick
    x_cut = inner_radius_max(cavity, handle_z - zspan, handle_z + zspan) + 0.0005
    h = handle((r_out + gap, handle_z), ring, stretch, thick, wide, x_cut)
    return cut_cavity(body + h, mirrored(cavity))


def make_cup() -> Shape:
    """A tea cup: tapered, thin-walled, a thin round C handle."""
    ctrl = [(0.027, 0.0), (0.028, 0.004), (0.031, 0.012), (0.036, 0.035), (0.041, 0.072)]
    return cup_like(ctrl, 0.003, 0.006, 0.043, 0.016, 1.25, 0.0035, 0.0035, 0.009)


def make_mug() -> Shape:
    """A coffee mug: straight cylinder, thick walls, a thick D-shaped handle."""
    ctrl = [(0.038, 0.0), (0.0415, 0.004), (0.042, 0.012), (0.042, 0.098)]
    return cup_like(ctrl, 0.0045, 0.008, 0.05, 0.021, 1.45, 0.0065, 0.0095, 0.011)


def make_mug_real() -> Shape:
    """A glass mug: slightly barrelled, thick glass base, a tall round handle."""
    ctrl = [(0.036, 0.0), (0.0385, 0.006), (0.0405, 0.04), (0.0405, 0.075), (0.039, 0.105)]
    return cup_like(ctrl, 0.004, 0.014, 0.055, 0.02, 1.7, 0.0055, 0.0055, 0.012)


def open_vessel(ctrl: list[tuple[float, float]], wall: float, floor: float) -> Shape:
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
    return open_vessel(ctrl, 0.004, 0.009)


def make_bowl_real() -> Shape:
    """A cereal bowl: deeper, straighter (conical) sides."""
    ctrl = [(0.03, 0.0), (0.031, 0.006), (0.04, 0.01), (0.055, 0.025), (0.066, 0.045), (0.07, 0.06)]
    return open_vessel(ctrl, 0.0035, 0.008)


def make_glass_real() -> Shape:
    """A drinking glass (tumbler): tapered, thin wall, heavy base."""
    ctrl = [(0.029, 0.0), (0.0305, 0.003), (0.031, 0.01), (0.037, 0.12)]
    return open_vessel(ctrl, 0.0025, 0.012)


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
    return solid_of_revolution(ctrl)


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
    return solid_of_revolution(ctrl)


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
    return solid_of_revolution(ctrl)


def make_toilet_paper() -> Shape:
    """A toilet-paper roll: a thick tube around a hollow cardboard core."""
    m = manifold3d_module()
    r_in, r_out, h, rad = 0.021, 0.055, 0.1, 0.004
    # Rounded outer edges (a soft roll); the cardboard core's faces stay flat.
    corners = m.CrossSection.circle(rad, 32)
    section = (
        rect(r_in, 0.0, r_out - rad, h)
        + rect(r_in, rad, r_out, h - rad)
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
    return lathe(half_section(pr[1:-1]))


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
    body = solid_of_revolution(body_ctrl)
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
    lid = solid_of_revolution(lid_ctrl, step=0.0015)
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
    hdl = half_turn_z(handle((0.068 + 0.012, 0.058), 0.026, 1.3, 0.006, 0.008, x_cut=0.05))
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
