"""The ReFlex hand model (`activetouch.models.reflex`) is the one source of the hand's collision
boxes and kinematics: checked against the URDF it writes, loaded in PyBullet DIRECT mode, and
against what the copies it replaced gave (reflex_pins.json: calibration's hand_boxes, probing's
hand_points, planning's reflex_boxes, the drivers' contact_sites and build_urdf's text, written
at commit 8d223b7 by tests/models/make_reflex_pins.py, deleted since with the copies)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
from scipy.spatial.transform import Rotation

from activetouch.calibration.object_frame import Boxes, box_sdf, hand_boxes
from activetouch.calibration.probing import hand_points
from activetouch.models.reflex import (
    DEFAULT_GEOMETRY,
    DISTAL_SENSOR_X_GAZEBO,
    DISTAL_SENSOR_Z_GAZEBO,
    Box,
    ReflexGeometry,
    build_urdf,
    collision_boxes,
    geometry_with_distal_sites,
    link_boxes,
    link_frames,
    rot_y,
    sensor_link_name,
    sensor_positions,
    urdf_file,
)

PINS = json.loads(Path(__file__).with_name("reflex_pins.json").read_text())
GEOMETRIES = {
    "default": ReflexGeometry(),
    "gazebo": geometry_with_distal_sites(DISTAL_SENSOR_X_GAZEBO, DISTAL_SENSOR_Z_GAZEBO, 0.28),
}
CONFIGS = [tuple(p["config"]) for p in PINS["hand_points"]]
EXACT = 1e-9  # the dedupe may reorder float operations, nothing more
URDF_TOL = 3e-6  # the URDF prints 6 significant digits (pi as 3.14159: 2.7e-6 off)


def stacked(boxes: list[Box]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.array([b.rotation for b in boxes]),
        np.array([b.position for b in boxes]),
        np.array([b.half for b in boxes]),
    )


@pytest.fixture(scope="module")
def bullet(tmp_path_factory):
    """`load(gname)` -> (client, body, {joint name: index}, {link name: index})."""
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
def test_collision_boxes_are_the_urdf_boxes_in_pybullet(bullet, gname, config) -> None:
    pre, prox, dist = config
    rot, centre, half = stacked(collision_boxes(GEOMETRIES[gname], pre, prox, dist))
    b_rot, b_centre, b_half = bullet_boxes(bullet, gname, pre, prox, dist)
    np.testing.assert_allclose(centre, b_centre, atol=URDF_TOL)
    np.testing.assert_allclose(half, b_half, atol=URDF_TOL)
    np.testing.assert_allclose(rot, b_rot, atol=URDF_TOL)


@pytest.mark.parametrize("gname", list(GEOMETRIES))
@pytest.mark.parametrize("config", CONFIGS)
def test_link_frames_are_pybullets(bullet, gname, config) -> None:
    pre, prox, dist = config
    c, body, links = pose_bullet(bullet, gname, pre, prox, dist)
    frames = link_frames(GEOMETRIES[gname], pre, prox, dist)
    assert set(frames) == {b.link for b in link_boxes(GEOMETRIES[gname])}
    for name, t in frames.items():
        if links[name] < 0:
            continue  # the base frame is the hand frame by definition
        s = pb.getLinkState(body, links[name], computeForwardKinematics=True, physicsClientId=c)
        np.testing.assert_allclose(t[:3, 3], s[4], atol=URDF_TOL, err_msg=name)
        np.testing.assert_allclose(
            t[:3, :3], Rotation.from_quat(s[5]).as_matrix(), atol=URDF_TOL, err_msg=name
        )


@pytest.mark.parametrize("config", CONFIGS)
def test_sensor_positions_are_the_urdf_sites_in_pybullet(bullet, config) -> None:
    """What the drivers place contacts with (the default geometry)."""
    pre, prox, dist = config
    c, body, links = pose_bullet(bullet, "default", pre, prox, dist)
    got = [
        pb.getLinkState(
            body, links[sensor_link_name(s)], computeForwardKinematics=True, physicsClientId=c
        )[4]
        for s in range(38)
    ]
    np.testing.assert_allclose(
        sensor_positions(DEFAULT_GEOMETRY, pre, prox, dist), np.array(got), atol=URDF_TOL
    )


def test_the_model_gives_the_copies_pinned_numbers() -> None:
    for p in PINS["hand_boxes"]:
        pre, prox, dist = p["config"]
        g = GEOMETRIES[p["geometry"]]
        rot, centre, half = stacked(collision_boxes(g, pre, prox, dist))
        calib = hand_boxes(g, pre, prox, dist)
        for got in ((rot, centre, half), (calib.rot, calib.centre, calib.half)):
            np.testing.assert_allclose(got[0], p["rot"], rtol=0, atol=EXACT)
            np.testing.assert_allclose(got[1], p["centre"], rtol=0, atol=EXACT)
            np.testing.assert_allclose(got[2], p["half"], rtol=0, atol=EXACT)
    for p in PINS["hand_points"]:
        pre, prox, dist = p["config"]
        np.testing.assert_allclose(hand_points(pre, prox, dist), p["points"], rtol=0, atol=EXACT)
    for p in PINS["contact_sites"]:  # the drivers' sites: the default geometry
        pre, prox, dist = p["config"]
        got = sensor_positions(DEFAULT_GEOMETRY, pre, prox, dist)
        np.testing.assert_allclose(got, p["sites"], rtol=0, atol=EXACT)


@pytest.mark.parametrize("pinned", PINS["reflex_boxes"], ids=lambda p: f"preshape{p['preshape']}")
def test_planning_boxes_against_its_old_copy(pinned: dict) -> None:
    """Planning now collides the URDF's boxes (robot.load_arm: collision_boxes of the open
    hand, named reflex_<name>). Its old copy had no swivels and one box per distal link to the
    full distal length: housing, pad and proximal boxes are unchanged; the URDF's boxes lie
    inside the old ones; the old square fingertips reached up to 5.5 mm past the chamfered
    fingertips the twin collides."""
    new = collision_boxes(None, pinned["preshape"])
    by_name = {f"reflex_{b.name}": b for b in new}
    old = pinned["boxes"]
    assert len(old) == 8 and len(new) == 13 and {o["name"] for o in old} <= set(by_name)
    for o in old:
        t, lo, hi = np.array(o["pose"]), np.array(o["lo"]), np.array(o["hi"])
        if "distal" in o["name"]:
            continue
        b = by_name[o["name"]]
        np.testing.assert_allclose(b.rotation, t[:3, :3], rtol=0, atol=EXACT)
        np.testing.assert_allclose(b.position, t[:3, :3] @ (lo + hi) / 2 + t[:3, 3], atol=EXACT)
        np.testing.assert_allclose(b.half, (hi - lo) / 2, rtol=0, atol=EXACT)
    # Containment, on random points inside each box.
    rng = np.random.default_rng(0)

    def inside(rot, centre, half, n: int) -> np.ndarray:
        return np.concatenate(
            [
                rng.uniform(-1, 1, (n, 3)) * h @ r.T + c
                for r, c, h in zip(rot, centre, half, strict=True)
            ]
        )

    old_rot = np.array([np.array(o["pose"])[:3, :3] for o in old])
    old_centre = np.array(
        [
            r @ np.add(o["lo"], o["hi"]) / 2 + np.array(o["pose"])[:3, 3]
            for r, o in zip(old_rot, old, strict=True)
        ]
    )
    old_half = np.array([np.subtract(o["hi"], o["lo"]) / 2 for o in old])
    new_rot, new_centre, new_half = stacked(new)
    new_pts = inside(new_rot, new_centre, new_half, 2000)
    assert box_sdf(new_pts, Boxes(old_rot, old_centre, old_half)).max() <= 1e-12
    old_pts = inside(old_rot, old_centre, old_half, 5000)
    assert 0.004 < box_sdf(old_pts, Boxes(new_rot, new_centre, new_half)).max() < 0.0056


def canonical_urdf(text: str) -> list:
    """Links and joints with their elements, order inside a link ignored (numbers as printed)."""

    def canon(e: ET.Element) -> tuple:
        return (e.tag, tuple(sorted(e.attrib.items())), tuple(sorted(canon(c) for c in e)))

    return [canon(e) for e in ET.fromstring(text)]


@pytest.mark.parametrize("key", list(PINS["urdf_text"]))
def test_the_urdf_is_the_pinned_one(key: str) -> None:
    """build_urdf now writes link_boxes: the same links, joints and numbers; only a
    fingertip's visual and collision elements swapped places."""
    gname, links = key.split("/")
    got = build_urdf(GEOMETRIES[gname], links == "True")
    assert canonical_urdf(got) == canonical_urdf(PINS["urdf_text"][key])


def test_box_helpers() -> None:
    b = Box.from_bounds("b", "base", (0.0, -1.0, 2.0), np.array([2.0, 1.0, 3.0]))
    np.testing.assert_array_equal(b.position, [1.0, 0.0, 2.5])
    np.testing.assert_array_equal(b.size, [2.0, 2.0, 1.0])
    np.testing.assert_array_equal(b.corners()[0], [0.0, -1.0, 2.0])
    np.testing.assert_array_equal(b.corners()[-1], [2.0, 1.0, 3.0])
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot_y(0.3), (0.1, 0.2, 0.3)
    m = b.moved(t)
    np.testing.assert_allclose(m.corners(), b.corners() @ t[:3, :3].T + t[:3, 3], atol=1e-15)
    np.testing.assert_allclose(m.pose, t @ b.pose, atol=1e-15)
    assert (m.name, m.link) == ("b", "base")
