"""Twin stand-ins with errors whose true values a test knows: an arm whose hand sits on its
flange through a mount that differs from the configured one."""

from __future__ import annotations

import numpy as np

from activetouch.interfaces import Arm, ArmWrapper, JointState, JointTrajectory, Pose
from activetouch.planning.motion.floating import (
    WRIST_JOINTS,
    pose_to_wrist_joints,
    wrist_joints_to_pose,
    wrist_trajectory_positions,
)


class MountedArm(ArmWrapper):
    """Wraps a floating-wrist arm (the twin's: its joints are the hand pose) so that its joints
    are the flange pose and the hand hangs off the flange through `true_mount`."""

    def __init__(self, inner: Arm, true_mount: Pose) -> None:
        super().__init__(inner)
        self.true_mount = true_mount
        self._inv = true_mount.inverse()

    def joint_state(self) -> JointState:

        js = self.inner.joint_state()
        flange = wrist_joints_to_pose(js.position).compose(self._inv)
        return JointState(js.names, pose_to_wrist_joints(flange), js.velocity, js.stamp)

    def execute(self, trajectory: JointTrajectory) -> None:

        q = wrist_trajectory_positions(trajectory)
        hand_q = np.stack(
            [pose_to_wrist_joints(wrist_joints_to_pose(row).compose(self.true_mount)) for row in q]
        )
        self.inner.execute(JointTrajectory(WRIST_JOINTS, trajectory.times, hand_q))
