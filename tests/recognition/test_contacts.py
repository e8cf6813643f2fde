import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.interfaces import Grasp, Pose
from activetouch.recognition.contacts import drop_support_contacts, hand_to_object


def test_hand_to_object_applies_the_wrist_pose():
    q = Rotation.from_euler("y", 90, degrees=True).as_quat()
    pose = Pose(np.array([0.1, 0.0, 0.05]), q)
    p = hand_to_object(pose, np.array([[0.0, 0.0, 0.1]]))
    np.testing.assert_allclose(p, [[0.2, 0.0, 0.05]], atol=1e-12)


def test_contacts_on_the_table_are_dropped_others_kept():
    # Hand looking straight down from 0.2 m above the object centre: hand +z = object -z.
    q = Rotation.from_euler("x", 180, degrees=True).as_quat()
    pose = Pose(np.array([0.0, 0.0, 0.2]), q)
    # Object 0.1 m tall: the table is at z = -0.05 in the object frame, i.e. 0.25 m along +z.
    xyz = np.array([[0.0, 0.0, 0.15], [0.02, 0.0, 0.249], [0.0, 0.03, 0.26], [0.0, 0.0, 0.2]])
    g = Grasp(np.arange(4), xyz, np.ones(4), np.zeros(3))
    out = drop_support_contacts(g, pose, support_z=-0.05, margin_m=0.005)
    assert out.sensor_ids.tolist() == [0, 3]
    np.testing.assert_array_equal(out.xyz, xyz[[0, 3]])
    same = drop_support_contacts(g, pose, support_z=-1.0, margin_m=0.005)
    assert same is g
