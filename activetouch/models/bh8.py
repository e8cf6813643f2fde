"""The BarrettHand BH8-280/282 model: kinematics, where each of the 96 tactile cells is,
collision boxes and the URDF the twin loads.

Source: the BH8-series User's Manual (Barrett Technology, D3000), section "Kinematics": each
finger is its own manipulator referred to a wrist frame at the centre of the palm, in Craig's
(modified) Denavit-Hartenberg notation, with the link parameters of its Table "D-H Link
Parameters for Fingers":

| joint | a(i-1) | alpha(i-1) | d(i) | theta(i) |
|---|---|---|---|---|
| 1 | r * Aw | 0 | Dw | r * spread - (pi/2) * j |
| 2 | A1 | pi/2 | 0 | inner + Phi2 |
| 3 | A2 | 0 | 0 | outer + Phi3 |
| tip | A3 | -pi/2 | D3 | 0 |

with r = (-1, 1, 0) and j = (1, 1, -1) for F1, F2, F3 (F3, the thumb, does not spread), and
Aw 25 mm, A1 50 mm, A2 70 mm, A3 50 mm, Dw 84 mm, D3 9.5 mm, Phi2 2.46 deg, Phi3 50 deg.
The frame assignment was read in the manual's public copy (BH8-262 manual, Table 9). Of the
numbers, Aw 25 mm, A1 50 mm, A2 70 mm, Phi3 50 deg and the outer = inner / 3 coupling agree
with OpenRAVE's public BarrettHand model (rdiankov/openrave, src/robots/barretthand.kinbody.xml:
finger bases at +-0.025 m, knuckle 0.05 m, inner link 0.07 m, outer mimic 0.33333 x inner +
0.8727 rad); A3, Dw, D3 and Phi2 are the manual's values as recorded here, not cross-checked:
check them against your hand's manual.

The pads are modelled, not measured: a fingertip pad is 8 rows x 3 columns of cells on the
outer link's inner face (rows 12 ... 47 mm from the outer joint along the link, columns 6 mm
apart across it, on the face D3 off the link's axis, where the tip frame sits); the palm pad is
6 x 4 cells, 10 mm apart, on the palm plane z = Dw around the palm's centre. Cell k of pad p
has hand-wide id ``24 p + k`` (p: 0 F1, 1 F2, 2 F3, 3 palm); cell 0 is nearest the joint
(fingers) or at -x, -y (palm), rows first.

Frames: the wrist (hand) frame has the palm face at z = Dw, F1 and F2 at -y (at x = -+Aw when
the spread is 0), the thumb F3 at +y; an open finger (inner = outer = 0) lies in the palm
plane pointing outwards and closing lifts it over the palm. Each link's frame is its D-H frame
(joint i's z axis is its axis), and the URDF's joints are those frames, so PyBullet's links
and `link_frames` agree (tested).

Collision boxes (`link_boxes`) are modelled from the manual's outline drawing, not from a CAD
model: the palm a 100 x 100 mm block from the wrist flange to the palm face, each knuckle a
50 x 25 x 25 mm block under the palm face, the inner links 70 x 18 x 24 mm, the outer links
55 mm long with their pad face D3 off the link axis. Ranges: spread 0 .. 180 deg, inner 0 ..
140 deg, the outer link 48 deg past its coupled angle (the BH8 data sheet's figures).

Transmission (libbarrett's `Hand` and protocol facts C): inner = motor / 125, outer = motor /
375 while the TorqueSwitch holds; once the inner link is stopped the switch breaks away and
the whole motor travel goes to the outer link (outer = motor * (1/125 + 1/375) - inner).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from activetouch.models.urdf import Box, box_link, cached_urdf, rpy_of, urdf_joint

AW, A1, A2, A3, DW, D3 = 0.025, 0.050, 0.070, 0.050, 0.084, 0.0095
PHI2, PHI3 = math.radians(2.46), math.radians(50.0)
R = (-1.0, 1.0, 0.0)
J = (1.0, 1.0, -1.0)
CELLS_PER_PAD = 24
N_PADS = 4
N_CELLS = CELLS_PER_PAD * N_PADS
PAD_NAMES = ("F1", "F2", "F3", "palm")

_ROWS = np.linspace(0.012, 0.047, 8)
_COLS = np.array([-0.006, 0.0, 0.006])
# Fingertip cells in the outer link's frame (x along the link, y to the pad face, z across).
FINGER_CELLS = np.array([[x, D3, z] for x in _ROWS for z in _COLS])
_PX = (np.arange(6) - 2.5) * 0.010
_PY = (np.arange(4) - 1.5) * 0.010
PALM_CELLS = np.array([[x, y, DW] for y in _PY for x in _PX])


def _dh(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """Craig's modified D-H transform: RotX(alpha) TransX(a) RotZ(theta) TransZ(d)."""
    ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
    return np.array(
        [
            [ct, -st, 0.0, a],
            [st * ca, ct * ca, -sa, -sa * d],
            [st * sa, ct * sa, ca, ca * d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def outer_link_frame(finger: int, spread: float, inner: float, outer: float) -> np.ndarray:
    """4x4 pose of finger `finger`'s outer-link (joint 3) frame in the wrist frame."""
    r, j = R[finger], J[finger]
    t = _dh(r * AW, 0.0, DW, r * spread - (math.pi / 2) * j)
    t = t @ _dh(A1, math.pi / 2, 0.0, inner + PHI2)
    return t @ _dh(A2, 0.0, 0.0, outer + PHI3)


def fingertip(finger: int, spread: float, inner: float, outer: float) -> np.ndarray:
    """(3,) fingertip point (the manual's tip frame) in the wrist frame, metres."""
    t = outer_link_frame(finger, spread, inner, outer) @ _dh(A3, -math.pi / 2, D3, 0.0)
    return t[:3, 3].copy()


def cell_positions(spread: float, inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """(96, 3) hand-frame positions of every cell at these joint angles."""
    out = np.empty((N_CELLS, 3))
    for f in range(3):
        t = outer_link_frame(f, spread, float(inner[f]), float(outer[f]))
        out[24 * f : 24 * f + 24] = FINGER_CELLS @ t[:3, :3].T + t[:3, 3]
    out[72:] = PALM_CELLS
    return out


def inner_link_frame(finger: int, spread: float, inner: float) -> np.ndarray:
    """4x4 pose of finger `finger`'s inner-link (joint 2) frame in the wrist frame."""
    r, j = R[finger], J[finger]
    t = _dh(r * AW, 0.0, DW, r * spread - (math.pi / 2) * j)
    return t @ _dh(A1, math.pi / 2, 0.0, inner + PHI2)


# `[grid]` values for the BH8's size (the ReFlex's are the defaults): the palm face Dw above
# the wrist, the fingers already centred on the approach axis (F1/F2 and F3 knuckles at -+50
# mm), a closer palm (the 120 mm fingers lie flat when open and reach 70 mm over the palm when
# the inner link stands).
GRID_DEFAULTS = {"palm_offset_m": DW, "center_offset_m": 0.0, "margin_m": 0.05}
# The pose belief's contact floor for 96 cells: with the same per-cell spurious rate the BH8
# reports 2.5 times the ReFlex's false contacts per grasp, and a higher floor lets one fewer
# rule a class out (tuning seeds 100-109, all errors, tree: 84.3 % against 77.1 % with the
# ReFlex's 1e-3, 7 runs better and 2 worse of 70; docs/results/bh8).
DEFAULT_SETTINGS: dict[str, dict[str, float]] = {
    "grid": GRID_DEFAULTS,
    "recognition": {"pose_floor": 0.01},
}

# -- ranges and transmission -------------------------------------------------------------------

SPREAD_LIMIT = math.pi
INNER_LIMIT = math.radians(140.0)
OUTER_BEYOND_COUPLED = math.radians(48.0)
OUTER_LIMIT = INNER_LIMIT / 3 + OUTER_BEYOND_COUPLED
INNER_RATIO, OUTER_RATIO = 125.0, 375.0  # motor radians per link radian


def coupled_outer(inner: np.ndarray | float) -> np.ndarray:
    """The outer link's angle while the TorqueSwitch holds: inner / 3."""
    return np.asarray(inner, dtype=np.float64) * (INNER_RATIO / OUTER_RATIO)


def outer_from_motor(motor: np.ndarray | float, inner: np.ndarray | float) -> np.ndarray:
    """The outer angle from the motor angle and the (possibly stopped) inner angle."""
    return np.asarray(motor) * (1 / INNER_RATIO + 1 / OUTER_RATIO) - np.asarray(inner)


def motor_of(inner: np.ndarray | float, outer: np.ndarray | float) -> np.ndarray:
    """The motor angle that puts the links at `inner`, `outer` (inverse of the above)."""
    return (np.asarray(inner) + np.asarray(outer)) / (1 / INNER_RATIO + 1 / OUTER_RATIO)


# -- links, boxes, URDF ------------------------------------------------------------------------

PALM_LINK = "palm"
KNUCKLE_LINKS = ("knuckle_1", "knuckle_2", "knuckle_3")
INNER_LINKS = ("inner_1", "inner_2", "inner_3")
OUTER_LINKS = ("outer_1", "outer_2", "outer_3")
SPREAD_JOINTS = ("spread_1", "spread_2")  # F3 does not spread: its knuckle is fixed
INNER_JOINTS = ("inner_1", "inner_2", "inner_3")
OUTER_JOINTS = ("outer_1", "outer_2", "outer_3")
N_FINGER_CELLS = 3 * CELLS_PER_PAD  # cells 0..71 are on the fingertips, 72..95 on the palm

PALM_HALF_XY = 0.05
MASSES = {"palm": 0.9, "knuckle": 0.05, "inner": 0.08, "outer": 0.04}  # kg, 1.2 kg in all


def link_boxes() -> list[Box]:
    """Every collision box in its link's frame: palm, then per finger knuckle, inner, outer."""
    h = PALM_HALF_XY
    out = [Box.from_bounds("palm", PALM_LINK, (-h, -h, 0.0), (h, h, DW))]
    for f in range(3):
        out.append(
            Box.from_bounds(
                f"knuckle_{f}", KNUCKLE_LINKS[f], (0.0, -0.0125, -0.025), (A1, 0.0125, 0.0)
            )
        )
        out.append(
            Box.from_bounds(f"inner_{f}", INNER_LINKS[f], (0.0, -0.009, -0.012), (A2, 0.009, 0.012))
        )
        out.append(
            Box.from_bounds(
                f"outer_{f}", OUTER_LINKS[f], (0.0, -0.008, -0.0115), (A3 + 0.005, D3, 0.0115)
            )
        )
    return out


def link_frames(
    spread: float = 0.0,
    inner: np.ndarray | Sequence[float] | None = None,
    outer: np.ndarray | Sequence[float] | None = None,
) -> dict[str, np.ndarray]:
    """4x4 wrist-frame pose of every link at these joint angles (open by default)."""
    inn = np.zeros(3) if inner is None else np.asarray(inner, dtype=np.float64)
    out_ = np.zeros(3) if outer is None else np.asarray(outer, dtype=np.float64)
    frames = {PALM_LINK: np.eye(4)}
    for f in range(3):
        r, j = R[f], J[f]
        frames[KNUCKLE_LINKS[f]] = _dh(r * AW, 0.0, DW, r * spread - (math.pi / 2) * j)
        frames[INNER_LINKS[f]] = inner_link_frame(f, spread, float(inn[f]))
        frames[OUTER_LINKS[f]] = outer_link_frame(f, spread, float(inn[f]), float(out_[f]))
    return frames


def collision_boxes(
    spread: float = 0.0,
    inner: np.ndarray | Sequence[float] | None = None,
    outer: np.ndarray | Sequence[float] | None = None,
) -> list[Box]:
    """The URDF's boxes in the wrist frame at these joint angles."""
    frames = link_frames(spread, inner, outer)
    return [b.moved(frames[b.link]) for b in link_boxes()]


def _origin(t: np.ndarray) -> tuple[tuple[float, ...], tuple[float, float, float]]:
    return tuple(float(v) for v in t[:3, 3]), rpy_of(t[:3, :3])


def build_urdf() -> str:
    """The BH8's URDF: the boxes above, joints on the D-H frames (axis z each)."""
    boxes: dict[str, list[Box]] = {}
    for b in link_boxes():
        boxes.setdefault(b.link, []).append(b)
    parts = ['<?xml version="1.0"?>\n<robot name="barrett_bh8">\n']
    parts.append(box_link(PALM_LINK, MASSES["palm"], boxes[PALM_LINK]))
    for f in range(3):
        r, j = R[f], J[f]
        xyz, rpy = _origin(_dh(r * AW, 0.0, DW, -(math.pi / 2) * j))
        parts.append(box_link(KNUCKLE_LINKS[f], MASSES["knuckle"], boxes[KNUCKLE_LINKS[f]]))
        if f < 2:  # theta1 = r * spread: F1 turns about -z, F2 about +z, both by the spread
            parts.append(
                urdf_joint(
                    SPREAD_JOINTS[f],
                    "revolute",
                    PALM_LINK,
                    KNUCKLE_LINKS[f],
                    xyz,
                    rpy,
                    axis=(0.0, 0.0, float(r)),
                    limits=(0.0, SPREAD_LIMIT),
                )
            )
        else:
            parts.append(
                urdf_joint("knuckle_3_fixed", "fixed", PALM_LINK, KNUCKLE_LINKS[f], xyz, rpy)
            )
        xyz, rpy = _origin(_dh(A1, math.pi / 2, 0.0, PHI2))
        parts.append(box_link(INNER_LINKS[f], MASSES["inner"], boxes[INNER_LINKS[f]]))
        parts.append(
            urdf_joint(
                INNER_JOINTS[f],
                "revolute",
                KNUCKLE_LINKS[f],
                INNER_LINKS[f],
                xyz,
                rpy,
                axis=(0.0, 0.0, 1.0),
                limits=(0.0, INNER_LIMIT),
            )
        )
        xyz, rpy = _origin(_dh(A2, 0.0, 0.0, PHI3))
        parts.append(box_link(OUTER_LINKS[f], MASSES["outer"], boxes[OUTER_LINKS[f]]))
        parts.append(
            urdf_joint(
                OUTER_JOINTS[f],
                "revolute",
                INNER_LINKS[f],
                OUTER_LINKS[f],
                xyz,
                rpy,
                axis=(0.0, 0.0, 1.0),
                limits=(0.0, OUTER_LIMIT),
            )
        )
    parts.append("</robot>\n")
    return "".join(parts)


def urdf_file(cache_dir: Path | None = None) -> Path:
    return cached_urdf(build_urdf(), "barrett_bh8", cache_dir)


def grasp_free_sites(spread: float, inner: np.ndarray, contact_ids: np.ndarray) -> np.ndarray:
    """(F, 3) wrist-frame points a grasp shows to be outside the object: the palm cells it
    left without contact, and every fingertip cell at 35 % and 70 % of its finger's final
    inner angle, where the finger passed freely with the TorqueSwitch holding (outer =
    inner / 3). The final fingertip cells are not used: after a breakaway the outer angle is
    not in the grasp (the driver reports the inner angles)."""
    inner = np.asarray(inner, dtype=np.float64).reshape(3)
    quiet = np.ones(N_CELLS, dtype=bool)
    quiet[np.asarray(contact_ids, dtype=np.int64)] = False
    quiet[:N_FINGER_CELLS] = False
    free = [PALM_CELLS[quiet[N_FINGER_CELLS:]]]
    for frac in (0.35, 0.7):
        a = inner * frac
        free.append(cell_positions(spread, a, coupled_outer(a))[:N_FINGER_CELLS])
    return np.concatenate(free)
