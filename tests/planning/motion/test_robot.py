import xml.etree.ElementTree as ET

import numpy as np
import pytest

from activetouch.errors import ConfigError
from activetouch.planning.motion.robot import (
    BaxterMotionConfig,
    find_baxter_description,
    hand_pose,
    mirror_arm,
)


def test_limits_are_baxters(baxter):
    assert baxter.joint_names == tuple(
        f"left_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")
    )
    np.testing.assert_allclose(
        baxter.lower, [-1.7017, -2.147, -3.0542, -0.05, -3.059, -1.5708, -3.059], atol=1e-4
    )
    np.testing.assert_allclose(
        baxter.upper, [1.7017, 1.047, 3.0542, 2.618, 3.059, 2.094, 3.059], atol=1e-4
    )
    np.testing.assert_allclose(baxter.velocity, [1.5] * 4 + [4.0] * 3)


def test_srdf_disabled_pairs_are_gone_and_hand_is_checked(baxter):
    _, srdf, _ = find_baxter_description(BaxterMotionConfig())
    disabled = {
        frozenset((e.get("link1"), e.get("link2")))
        for e in ET.parse(srdf).getroot().iter("disable_collisions")
    }
    objs = baxter.geom.geometryObjects
    names = [o.name.rsplit("_", 1)[0] for o in objs]
    pairs = [(int(p.first), int(p.second)) for p in baxter.geom.collisionPairs]
    assert not [p for p in pairs if frozenset((names[p[0]], names[p[1]])) in disabled]
    assert not [p for p in pairs if objs[p[0]].parentJoint == 0 and objs[p[1]].parentJoint == 0]
    assert not any(o.name.startswith("l_gripper") for o in objs)
    hand = set(baxter.hand_geoms)
    # The twin URDF's boxes: housing, pad, 2 swivels, 3 x (proximal, distal, fingertip).
    assert len(hand) == 13
    partners = {o for a, b in pairs for o in (a, b) if a in hand or b in hand} - hand
    assert {"torso_0", "left_upper_elbow_0"} <= {str(objs[i].name) for i in partners}


def test_hand_frame_is_link_frame_times_mount(baxter):
    import pinocchio as pin

    cfg = BaxterMotionConfig()
    data = baxter.model.createData()
    q = baxter.ready
    pin.forwardKinematics(baxter.model, data, q)
    link = pin.updateFramePlacement(baxter.model, data, baxter.link_frame).homogeneous
    hand = hand_pose(baxter, data, q)
    expected = link @ cfg.hand_mount
    np.testing.assert_allclose(hand.xyz, expected[:3, 3], atol=1e-12)
    # ReFlex palm normal (+z) is the hand link's z: the mount only turns about z.
    np.testing.assert_allclose(expected[:3, 2], link[:3, 2], atol=1e-12)


def test_config_checks_side():
    with pytest.raises(ConfigError):
        BaxterMotionConfig(side="middle").check()


def test_mirror():
    np.testing.assert_allclose(mirror_arm(mirror_arm([1, 2, 3, 4, 5, 6, 7])), [1, 2, 3, 4, 5, 6, 7])
