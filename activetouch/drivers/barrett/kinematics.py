"""A simple BH8 kinematic model: where each of the 96 tactile cells is in the hand frame.

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
"""

from __future__ import annotations

import math

import numpy as np

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
