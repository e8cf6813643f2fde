"""Contact preprocessing shared by training collection and recognition.

A finger that closes onto the table reports a real contact, but it says nothing about the
object. The object's pose is known (the paper's setting), so the support plane is known in the
object frame, and contacts within a margin of it are dropped before they become triangles."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.interfaces import Grasp, Pose


def hand_to_object(pose: Pose, xyz_hand: np.ndarray) -> np.ndarray:
    """(n, 3) points from the hand frame into the object frame, the hand being at `pose`."""
    R = Rotation.from_quat(pose.quat).as_matrix()
    return np.asarray(xyz_hand, dtype=np.float64).reshape(-1, 3) @ R.T + pose.xyz


def drop_support_contacts(grasp: Grasp, pose: Pose, support_z: float, margin_m: float) -> Grasp:
    """`grasp` without the contacts lying within `margin_m` above the support plane
    z = `support_z` (object frame) or below it."""
    z = hand_to_object(pose, grasp.xyz)[:, 2]
    keep = z >= support_z + margin_m
    return grasp if keep.all() else grasp.only(keep)
