"""The wrist-motion interface and the object placement it works in."""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.config import WorkcellConfig
from activetouch.errors import ActiveTouchError
from activetouch.interfaces import JointTrajectory, Pose


@dataclass(frozen=True)
class Placement:
    """The object frame in the robot base frame (origin at the object's bounding-box centre,
    z up; turned about z only, as an object standing on a table is)."""

    xyz: np.ndarray
    yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "xyz", np.asarray(self.xyz, dtype=np.float64).reshape(3))

    @property
    def rotation(self) -> Rotation:
        return Rotation.from_euler("z", self.yaw_rad)

    @property
    def pose(self) -> Pose:
        """The object frame's pose in the base frame."""
        return Pose(self.xyz, self.rotation.as_quat())

    def to_base(self, pose: Pose) -> Pose:
        """A pose in the object frame, expressed in the base frame."""
        return self.pose.compose(pose)

    def to_object(self, pose: Pose) -> Pose:
        """A pose in the base frame, expressed in the object frame."""
        return self.pose.inverse().compose(pose)

    def support_z(self, table_top_z: float) -> float:
        """The table plane's height in the object frame (z is shared: the object only yaws)."""
        return float(table_top_z) - float(self.xyz[2])


def workcell_placement(workcell: WorkcellConfig) -> Placement:
    """The object placement a workcell configures (a real robot's, until calibration)."""
    return Placement(np.asarray(workcell.object_xyz), np.radians(workcell.object_yaw_deg))


class WristMotion(abc.ABC):
    """Brings the hand frame to a wrist pose given in the object frame.

    Robot time, counted by implementations that move something (readers take differences,
    e.g. around one recognition; these class defaults stay 0 for wrists that count nothing):
    `robot_seconds` is the sum of the durations of executed trajectories (trajectory time,
    as the robot takes it; a motion stopped at a contact, `MotionBlockedError`, adds the part it
    moved, any other failure nothing), `planning_seconds` the wall
    time spent planning them (failed plans included), `moves` the completed motions, and
    `last_motion_s` / `last_planning_s` the same for the last `move_to` alone."""

    placement: Placement
    robot_seconds: float = 0.0
    planning_seconds: float = 0.0
    moves: int = 0
    last_motion_s: float = 0.0
    last_planning_s: float = 0.0

    @abc.abstractmethod
    def move_to(self, pose: Pose) -> None:
        """Move the hand frame to `pose` (object frame) and return once there.

        Raises `UnreachableError` when no collision-free motion reaches it (the arm then stays
        where it was or where it stopped, safely), `StoppedError` when the arm was stopped."""

    def set_placement(self, placement: Placement) -> None:
        """Where the object now is (a twin placed it, or calibration measured it)."""
        self.placement = placement


def trajectory_positions(trajectory: JointTrajectory, joints: tuple[str, ...]) -> np.ndarray:
    """(n_points, len(joints)) positions of `trajectory` in the order of `joints` (it may name
    them in any order); ActiveTouchError for other joints, mismatched shapes, NaN or times
    going backwards."""
    names = tuple(trajectory.names)
    if sorted(names) != sorted(joints) or len(names) != len(joints):
        raise ActiveTouchError(f"a trajectory needs the joints {', '.join(joints)}; got {names}")
    pos = np.asarray(trajectory.positions, dtype=np.float64)
    times = np.asarray(trajectory.times, dtype=np.float64).reshape(-1)
    if pos.ndim != 2 or pos.shape != (len(times), len(names)) or len(times) == 0:
        raise ActiveTouchError(
            f"trajectory positions of shape {pos.shape} do not match {len(times)} times "
            f"x {len(names)} joints"
        )
    if not np.all(np.isfinite(pos)) or not np.all(np.isfinite(times)):
        raise ActiveTouchError("trajectory holds NaN or infinite values")
    if np.any(np.diff(times) < 0):
        raise ActiveTouchError("trajectory times go backwards")
    return pos[:, [names.index(n) for n in joints]]
