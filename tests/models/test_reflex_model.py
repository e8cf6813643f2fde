"""The ReFlex hand model's copies pinned before the house refactor: collision boxes of the
calibration (hand_boxes), of motion planning (reflex_boxes), the probing corners (hand_points),
the driver's contact sites (contact_sites), against the URDF in PyBullet and against the numbers
they gave at the time (reflex_pins.json, written by make_reflex_pins.py)."""

from __future__ import annotations

import hashlib
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
from scipy.spatial.transform import Rotation

from activetouch.calibration.object_frame import hand_boxes
from activetouch.calibration.probing import hand_points
from activetouch.drivers.reflex.kinematics import contact_sites
from activetouch.models.reflex import (
    DISTAL_SENSOR_X_GAZEBO,
    DISTAL_SENSOR_Z_GAZEBO,
    ReflexGeometry,
    build_urdf,
    geometry_with_distal_sites,
    sensor_link_name,
    urdf_file,
)
from activetouch.planning.motion.robot import reflex_boxes

PINS = json.loads(Path(__file__).with_name("reflex_pins.json").read_text())
GEOMETRIES = {
    "default": ReflexGeometry(),
    "gazebo": geometry_with_distal_sites(DISTAL_SENSOR_X_GAZEBO, DISTAL_SENSOR_Z_GAZEBO, 0.28),
}
CONFIGS = [tuple(p["config"]) for p in PINS["hand_points"]]
EXACT = 1e-9  # the dedupe may reorder float operations, nothing more
URDF_TOL = 3e-6  # the URDF prints 6 significant digits (pi as 3.14159: 2.7e-6 off)


@pytest.fixture(scope="module")
def bullet(tmp_path_factory):
    """`load(geom)` -> (client, body, {joint name: index}, {link name: index}) in DIRECT mode."""
    c = pb.connect(pb.DIRECT)
    root = tmp_path_factory.mktemp("urdf")
    bodies: dict[str, tuple] = {}

    def load(gname: str):
        if gname not in bodies:
            path = urdf_file(GEOMETRIES[gname], root, sensor_links=True)
            body = pb.loadURDF(str(path), physicsClientId=c)
            joints, links = {}, {"base": -1}
            for j in range(pb.getNumJoints(body, physicsClientId=c)):
                info = pb.getJointInfo(body, j, physicsClientId=c)
                joints[info[1].decode()], links[info[12].decode()] = j, j
            bodies[gname] = (c, body, joints, links)
        return bodies[gname]

    yield load
    pb.disconnect(c)


def pose_bullet(load, gname: str, pre: float, prox, dist):
    c, body, joints, links = load(gname)
    # The URDF turns both swivels about -z: finger 1 (preshape_2) turns the other way.
    values = {"preshape_1": pre, "preshape_2": -pre}
    for f in range(3):
        values[f"proximal_{f + 1}"], values[f"distal_{f + 1}"] = prox[f], dist[f]
    for name, v in values.items():
        pb.resetJointState(body, joints[name], v, physicsClientId=c)
    return c, body, links


def bullet_boxes(load, gname: str, pre: float, prox, dist):
    """(rot (b,3,3), centre (b,3), half (b,3)) of every collision box, links in URDF order."""
    c, body, links = pose_bullet(load, gname, pre, prox, dist)
    rots, centres, halves = [], [], []
    for link in sorted(links.values()):
        if link < 0:
            com_xyz, com_q = pb.getBasePositionAndOrientation(body, physicsClientId=c)
        else:
            s = pb.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=c)
            com_xyz, com_q = s[0], s[1]
        r_com = Rotation.from_quat(com_q)
        # Collision frames are given in the link's inertial (COM) frame.
        for d in pb.getCollisionShapeData(body, link, physicsClientId=c):
            assert d[2] == pb.GEOM_BOX
            rots.append((r_com * Rotation.from_quat(d[6])).as_matrix())
            centres.append(r_com.apply(d[5]) + np.asarray(com_xyz))
            halves.append(np.asarray(d[3]) / 2)
    return np.array(rots), np.array(centres), np.array(halves)


@pytest.mark.parametrize("gname", list(GEOMETRIES))
@pytest.mark.parametrize("config", CONFIGS)
def test_calibration_boxes_are_the_urdf_boxes_in_pybullet(bullet, gname, config) -> None:
    pre, prox, dist = config
    b = hand_boxes(GEOMETRIES[gname], pre, prox, dist)
    rot, centre, half = bullet_boxes(bullet, gname, pre, prox, dist)
    np.testing.assert_allclose(b.centre, centre, atol=URDF_TOL)
    np.testing.assert_allclose(b.half, half, atol=URDF_TOL)
    np.testing.assert_allclose(b.rot, rot, atol=URDF_TOL)


@pytest.mark.parametrize("pre", [0.0, 0.8, 1.6])
def test_planning_boxes_today_against_the_urdf_ones(pre: float) -> None:
    """reflex_boxes agrees with the URDF on housing, pad and proximal links; it has no swivels,
    and each distal link is one box to the full distal length instead of distal box plus the
    tilted fingertip box."""
    urdf = hand_boxes(None, pre)
    plan = {n: (t, np.asarray(lo), np.asarray(hi)) for n, t, lo, hi in reflex_boxes(pre)}
    assert len(plan) == 8 and len(urdf) == 13
    # hand_boxes order: housing, pad, then per finger [swivel], proximal, distal, fingertip.
    order = {"housing": 0, "pad": 1}
    i = 2
    for f in range(3):
        i += f < 2
        order[f"proximal_{f}"], order[f"distal_{f}"] = i, i + 1
        i += 3
    for name, k in order.items():
        t, lo, hi = plan[f"reflex_{name}"]
        if name.startswith("distal"):
            assert hi[0] == ReflexGeometry().distal_size[0] > ReflexGeometry().chamfer_start_x
            continue
        np.testing.assert_allclose(t[:3, :3], urdf.rot[k], atol=EXACT)
        np.testing.assert_allclose(t[:3, :3] @ (lo + hi) / 2 + t[:3, 3], urdf.centre[k], atol=EXACT)
        np.testing.assert_allclose((hi - lo) / 2, urdf.half[k], atol=EXACT)


@pytest.mark.parametrize("config", CONFIGS)
def test_probing_points_are_the_finger_box_corners(config) -> None:
    pre, prox, dist = config
    b = hand_boxes(None, pre, prox, dist)
    signs = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    fingers = [k for k in range(len(b)) if k >= 2 and k not in (2, 6)]  # not housing, pad, swivels
    corners = [b.centre[k] + ((2 * signs - 1) * b.half[k]) @ b.rot[k].T for k in fingers]
    np.testing.assert_allclose(hand_points(pre, prox, dist), np.concatenate(corners), atol=EXACT)


@pytest.mark.parametrize("config", CONFIGS)
def test_driver_contact_sites_are_the_urdf_sites_in_pybullet(bullet, config) -> None:
    pre, prox, dist = config
    c, body, links = pose_bullet(bullet, "default", pre, prox, dist)
    got = [
        pb.getLinkState(
            body, links[sensor_link_name(s)], computeForwardKinematics=True, physicsClientId=c
        )[4]
        for s in range(38)
    ]
    np.testing.assert_allclose(
        contact_sites(pre, np.array(prox), np.array(dist)), np.array(got), atol=URDF_TOL
    )


def canonical_urdf(text: str) -> list:
    """Links and joints with their elements, order inside a link ignored (numbers as printed)."""

    def canon(e: ET.Element) -> tuple:
        return (e.tag, tuple(sorted(e.attrib.items())), tuple(sorted(canon(c) for c in e)))

    return [canon(e) for e in ET.fromstring(text)]


@pytest.mark.parametrize("key", list(PINS["urdf_text"]))
def test_the_urdf_is_the_pinned_one(key: str) -> None:
    gname, links = key.split("/")
    got = build_urdf(GEOMETRIES[gname], links == "True")
    assert canonical_urdf(got) == canonical_urdf(PINS["urdf_text"][key])


def test_the_copies_give_the_pinned_numbers() -> None:
    for p in PINS["hand_boxes"]:
        pre, prox, dist = p["config"]
        b = hand_boxes(GEOMETRIES[p["geometry"]], pre, prox, dist)
        np.testing.assert_allclose(b.rot, p["rot"], rtol=0, atol=EXACT)
        np.testing.assert_allclose(b.centre, p["centre"], rtol=0, atol=EXACT)
        np.testing.assert_allclose(b.half, p["half"], rtol=0, atol=EXACT)
    for p in PINS["hand_points"]:
        pre, prox, dist = p["config"]
        np.testing.assert_allclose(hand_points(pre, prox, dist), p["points"], rtol=0, atol=EXACT)
    for p in PINS["contact_sites"]:
        pre, prox, dist = p["config"]
        got = contact_sites(pre, np.array(prox), np.array(dist))
        np.testing.assert_allclose(got, p["sites"], rtol=0, atol=EXACT)
    for p in PINS["reflex_boxes"]:
        got = reflex_boxes(p["preshape"])
        assert [n for n, *_ in got] == [b["name"] for b in p["boxes"]]
        for (_, t, lo, hi), want in zip(got, p["boxes"], strict=True):
            np.testing.assert_allclose(t, want["pose"], rtol=0, atol=EXACT)
            np.testing.assert_allclose(lo, want["lo"], rtol=0, atol=EXACT)
            np.testing.assert_allclose(hi, want["hi"], rtol=0, atol=EXACT)
    for key, digest in PINS["urdf_sha256"].items():
        gname, links = key.split("/")
        text = build_urdf(GEOMETRIES[gname], links == "True")
        assert hashlib.sha256(text.encode()).hexdigest() == digest, key
