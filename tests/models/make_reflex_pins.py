"""Writes reflex_pins.json: the outputs of every copy of the ReFlex collision boxes and contact
kinematics as they are before the house refactor (run once, at the commit that adds it):

    python -m tests.models.make_reflex_pins

The refactor deletes the copies; test_reflex_model.py then checks the one model against these
numbers, so the dedupe is shown to change none of them."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from activetouch.calibration.object_frame import hand_boxes
from activetouch.calibration.probing import hand_points
from activetouch.drivers.reflex.kinematics import contact_sites
from activetouch.models.reflex import (
    DISTAL_SENSOR_X_GAZEBO,
    DISTAL_SENSOR_Z_GAZEBO,
    ReflexGeometry,
    build_urdf,
    geometry_with_distal_sites,
)
from activetouch.planning.motion.robot import reflex_boxes

PINS = Path(__file__).with_name("reflex_pins.json")

# (preshape, proximal, distal): open, the ranges' middles, the limits, a negative preshape.
CONFIGS = [
    (0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
    (0.8, [0.3, 1.0, 2.0], [0.5, 0.2, 1.2]),
    (1.6, [np.pi, 0.1, 0.0], [2.74, 0.0, 0.4]),
    (-0.4, [0.7, 2.5, 1.3], [0.1, 1.9, 0.0]),
]
GEOMETRIES = {
    "default": ReflexGeometry(),
    "gazebo": geometry_with_distal_sites(DISTAL_SENSOR_X_GAZEBO, DISTAL_SENSOR_Z_GAZEBO, 0.28),
}


def capture() -> dict:
    out: dict = {"hand_boxes": [], "hand_points": [], "reflex_boxes": [], "contact_sites": []}
    for gname, g in GEOMETRIES.items():
        for pre, prox, dist in CONFIGS:
            b = hand_boxes(g, pre, prox, dist)
            out["hand_boxes"].append(
                {
                    "geometry": gname,
                    "config": [pre, prox, dist],
                    "rot": b.rot.tolist(),
                    "centre": b.centre.tolist(),
                    "half": b.half.tolist(),
                }
            )
    for pre, prox, dist in CONFIGS:  # hand_points and contact_sites use the default geometry
        out["hand_points"].append(
            {"config": [pre, prox, dist], "points": hand_points(pre, prox, dist).tolist()}
        )
        out["contact_sites"].append(
            {
                "config": [pre, prox, dist],
                "sites": contact_sites(pre, np.array(prox), np.array(dist)).tolist(),
            }
        )
    for pre in (0.0, 0.8, 1.6):
        out["reflex_boxes"].append(
            {
                "preshape": pre,
                "boxes": [
                    {"name": n, "pose": t.tolist(), "lo": lo.tolist(), "hi": hi.tolist()}
                    for n, t, lo, hi in reflex_boxes(pre)
                ],
            }
        )
    out["urdf_sha256"] = {
        f"{gname}/{links}": hashlib.sha256(build_urdf(g, links).encode()).hexdigest()
        for gname, g in GEOMETRIES.items()
        for links in (True, False)
    }
    # The texts too: a refactor may reorder elements inside a link and change no number.
    out["urdf_text"] = {
        f"{gname}/{links}": build_urdf(g, links)
        for gname, g in GEOMETRIES.items()
        for links in (True, False)
    }
    return out


if __name__ == "__main__":
    PINS.write_text(json.dumps(capture(), indent=1) + "\n")
    print(f"wrote {PINS}")
