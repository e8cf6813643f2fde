"""Wrist motion of a floating wrist: an arm whose six joints are the hand frame's pose in the
robot base frame (x, y, z in metres; roll, pitch, yaw in rad, fixed axes x-y-z).

The twin's `twin-floating` arm and the fake arm have such joints. Going from the object frame
to them is one rigid transform (the object placement), so no IK is needed; the trajectory is
the straight joint-space line from where the wrist is, timed by the joint velocity limits."""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.config import WorkcellConfig
from activetouch.errors import ActiveTouchError, UnreachableError
from activetouch.interfaces import Arm, JointLimits, JointTrajectory, Pose
from activetouch.planning.motion.base import Placement, WristMotion, trajectory_positions

WRIST_JOINTS = ("wrist_x", "wrist_y", "wrist_z", "wrist_roll", "wrist_pitch", "wrist_yaw")


def floating_limits(workcell: WorkcellConfig) -> JointLimits:
    """A floating wrist's workspace: over the table (and half a metre around it), up to
    1.5 m above it; its speeds are nominal (they time the motions of the twin and the fake)."""
    centre = np.asarray(workcell.table_center, dtype=np.float64)
    half = np.asarray(workcell.table_size, dtype=np.float64) / 2 + 0.5
    top = workcell.table_top_z
    lower = [centre[0] - half[0], centre[1] - half[1], top - 0.1, -np.pi, -np.pi / 2, -np.pi]
    upper = [centre[0] + half[0], centre[1] + half[1], top + 1.5, np.pi, np.pi / 2, np.pi]
    return JointLimits(
        lower=np.array(lower),
        upper=np.array(upper),
        velocity=np.array([0.5, 0.5, 0.5, 2.0, 2.0, 2.0]),
        acceleration=np.array([2.0, 2.0, 2.0, 8.0, 8.0, 8.0]),
    )


def wrist_joints_to_pose(q: np.ndarray) -> Pose:
    q = np.asarray(q, dtype=np.float64).reshape(6)
    return Pose(q[:3], Rotation.from_euler("xyz", q[3:]).as_quat())


def pose_to_wrist_joints(pose: Pose) -> np.ndarray:
    with warnings.catch_warnings():
        # Palm straight up or down: roll and yaw are one angle; scipy puts it all in roll and
        # warns. The rotation is still exact, which is all a floating wrist needs.
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_quat(pose.quat).as_euler("xyz")
    return np.concatenate([pose.xyz, rpy])


def wrist_trajectory_positions(trajectory: JointTrajectory) -> np.ndarray:
    """(n_points, 6) positions of a floating-wrist trajectory in `WRIST_JOINTS` order."""
    return trajectory_positions(trajectory, WRIST_JOINTS)


def wrap_angles(delta: np.ndarray) -> np.ndarray:
    """Angle differences into (-pi, pi]: the short way round."""
    return (np.asarray(delta) + np.pi) % (2 * np.pi) - np.pi


def straight_trajectory(
    start: np.ndarray, goal: np.ndarray, velocity: np.ndarray
) -> JointTrajectory:
    """From `start` to `goal` (wrist joints), the angles the short way round, in the time the
    slowest joint needs at its velocity limit."""
    start = np.asarray(start, dtype=np.float64)
    goal = np.asarray(goal, dtype=np.float64)
    delta = goal - start
    delta[3:] = wrap_angles(delta[3:])
    duration = float(np.max(np.abs(delta) / np.asarray(velocity)))
    # End on `goal` itself (not start + delta): where the wrist lands must not depend on
    # where it came from, down to the last bit (the twin keys its noise by the pose).
    return JointTrajectory(
        names=WRIST_JOINTS,
        times=np.array([0.0, max(duration, 1e-3)]),
        positions=np.stack([start, goal]),
    )


class FloatingWristMotion(WristMotion):
    """Moves an arm with `WRIST_JOINTS` so that the hand frame reaches an object-frame pose."""

    def __init__(self, arm: Arm, placement: Placement | None = None) -> None:
        if tuple(arm.joint_names) != WRIST_JOINTS:
            raise ActiveTouchError(
                f"a floating wrist needs the joints {', '.join(WRIST_JOINTS)}; this arm has "
                f"{', '.join(arm.joint_names)}"
            )
        self.arm = arm
        self.placement = placement or Placement(np.zeros(3))

    def target_joints(self, pose: Pose) -> np.ndarray:
        return pose_to_wrist_joints(self.placement.to_base(pose))

    def move_to(self, pose: Pose) -> None:
        self.last_motion_s = 0.0  # stays 0 unless this motion completes
        goal = self.target_joints(pose)
        limits = self.arm.limits
        bad = limits.violations(WRIST_JOINTS, goal[None, :])
        if bad:
            raise UnreachableError(f"wrist pose outside the workspace: {'; '.join(bad)}")
        start = self.arm.joint_state().position
        trajectory = straight_trajectory(start, goal, limits.velocity)
        self.arm.execute(trajectory)
        # Robot time is the trajectory's own duration (what a real arm would take), not the
        # wall time the twin needed to replay it.
        self.last_motion_s = float(trajectory.times[-1] - trajectory.times[0])
        self.robot_seconds += self.last_motion_s
        self.moves += 1
