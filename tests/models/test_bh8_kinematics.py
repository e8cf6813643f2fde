"""The BH8 kinematic model against the public descriptions it comes from."""

from __future__ import annotations

import math

import numpy as np
import pytest

from activetouch.models import bh8 as k


def test_knuckles_where_the_public_models_put_them():
    # Joint 2 (the knuckle) of F1 / F2 sits Aw = 25 mm either side and A1 = 50 mm out from the
    # palm centre at height Dw; F3's A1 out on the other side (OpenRAVE: +-0.025, 0.05).
    for f, x, y in [(0, -0.025, -0.05), (1, 0.025, -0.05), (2, 0.0, 0.05)]:
        t = k.outer_link_frame(f, 0.0, 0.0, 0.0)
        # The inner link (A2 = 70 mm) runs from the knuckle to joint 3.
        knuckle = t[:3, 3] - 0.070 * np.array(
            [0.0, math.copysign(math.cos(k.PHI2), y), math.sin(k.PHI2)]
        )
        assert knuckle == pytest.approx([x, y, k.DW], abs=1e-9)


def test_spread_turns_f1_and_f2_oppositely_and_closing_brings_tips_in():
    a = k.fingertip(0, 0.5, 0.0, 0.0)
    b = k.fingertip(1, 0.5, 0.0, 0.0)
    assert a[0] == pytest.approx(-b[0]) and a[1] == pytest.approx(b[1])
    open_tip, closed_tip = k.fingertip(2, 0.0, 0.0, 0.0), k.fingertip(2, 0.0, 1.5, 0.5)
    assert abs(closed_tip[1]) < abs(open_tip[1])


def test_cells_are_96_and_pads_face_the_palm_axis():
    sites = k.cell_positions(0.0, np.full(3, 0.8), np.full(3, 0.8 / 3))
    assert sites.shape == (96, 3) and np.all(np.isfinite(sites))
    for f in range(3):
        t = k.outer_link_frame(f, 0.0, 0.8, 0.8 / 3)
        axis_pts = k.FINGER_CELLS * np.array([1.0, 0.0, 1.0]) @ t[:3, :3].T + t[:3, 3]
        pad = sites[24 * f : 24 * f + 24]
        # Each cell is D3 closer to the hand's axis (x = y = 0 line) than the link's axis.
        assert np.all(np.abs(pad[:, 1]) < np.abs(axis_pts[:, 1]))
    assert np.allclose(sites[72:, 2], k.DW)
