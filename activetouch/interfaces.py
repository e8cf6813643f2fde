"""The hardware boundary: the `Hand` and `Arm` interfaces and the values that cross it.

Real drivers (`activetouch.drivers`) and the PyBullet twin (`activetouch.sim`) both implement
these; nothing above them (planner, recognition session, service) knows which one it has.
Shaped after LeRobot's `Robot`: connect / observe / act / disconnect.

Conventions used everywhere in the package:
- Quaternions are (x, y, z, w), as in PyBullet and ROS.
- Tactile sensor ids: finger f (0 pointer, 1 middle, 2 thumb), sensor s (0 nearest the palm
  ... 4 last proximal, 5..8 distal, 8 the fingertip) has id ``f * 9 + s``; the 11 palm sensors
  are ids 27..37. (The ReFlex wire order differs: drivers remap to this.)
- Contact XYZ are sensor-frame origins in the hand (ReFlex base link) frame, in metres.
- Wrist poses handed to an `Arm` are of the hand frame in the object frame (origin at the
  object centre, z up), which is where training poses are stored.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np

N_FINGERS = 3
SENSORS_PER_FINGER = 9
N_FINGER_SENSORS = N_FINGERS * SENSORS_PER_FINGER  # 27
N_PALM_SENSORS = 11
N_SENSORS = N_FINGER_SENSORS + N_PALM_SENSORS  # 38


def sensor_id(finger: int, sensor: int) -> int:
    """Id of sensor `sensor` (0..8) on finger `finger` (0..2)."""
    if not (0 <= finger < N_FINGERS and 0 <= sensor < SENSORS_PER_FINGER):
        raise ValueError(f"no sensor {sensor} on finger {finger}")
    return finger * SENSORS_PER_FINGER + sensor


@dataclass(frozen=True)
class Pose:
    """A rigid pose: translation in metres and unit quaternion (x, y, z, w)."""

    xyz: np.ndarray
    quat: np.ndarray

    def __post_init__(self) -> None:
        xyz = np.asarray(self.xyz, dtype=np.float64).reshape(3)
        quat = np.asarray(self.quat, dtype=np.float64).reshape(4)
        n = float(np.linalg.norm(quat))
        if not np.all(np.isfinite(xyz)) or not np.isfinite(n) or n < 1e-9:
            raise ValueError(f"invalid pose xyz={xyz} quat={quat}")
        object.__setattr__(self, "xyz", xyz)
        object.__setattr__(self, "quat", quat / n)

    def as_array(self) -> np.ndarray:
        """(7,) array: x, y, z, qx, qy, qz, qw."""
        return np.concatenate([self.xyz, self.quat])

    @classmethod
    def from_array(cls, a: np.ndarray) -> Pose:
        a = np.asarray(a, dtype=np.float64).reshape(7)
        return cls(a[:3], a[3:])


@dataclass(frozen=True)
class Grasp:
    """What one guarded enclosure grasp yields; the same type from the twin and the hardware."""

    sensor_ids: np.ndarray  # (n,) int, sensors in contact
    xyz: np.ndarray  # (n, 3) float, their positions in the hand frame
    pressures: np.ndarray  # (n,) float, pressure above the zero offset
    finger_angles: np.ndarray  # (3,) proximal joint angles at the end of the close, rad
    preshape: float = 0.0  # rad

    def __post_init__(self) -> None:
        ids = np.asarray(self.sensor_ids, dtype=np.int64).reshape(-1)
        xyz = np.asarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        pr = np.asarray(self.pressures, dtype=np.float64).reshape(-1)
        if not (len(ids) == len(xyz) == len(pr)):
            raise ValueError("sensor_ids, xyz and pressures differ in length")
        object.__setattr__(self, "sensor_ids", ids)
        object.__setattr__(self, "xyz", xyz)
        object.__setattr__(self, "pressures", pr)
        object.__setattr__(
            self, "finger_angles", np.asarray(self.finger_angles, dtype=np.float64).reshape(-1)
        )

    @property
    def n_contacts(self) -> int:
        return len(self.sensor_ids)


@dataclass(frozen=True)
class HandState:
    """A snapshot of the hand: all sensors, not just those in contact."""

    pressures: np.ndarray  # (38,) pressure above the zero offset
    contact: np.ndarray  # (38,) bool
    finger_angles: np.ndarray  # (3,) proximal joint angles, rad
    preshape: float
    stamp: float  # seconds, monotonic clock of the producer


@dataclass(frozen=True)
class JointState:
    names: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    stamp: float


@dataclass(frozen=True)
class JointTrajectory:
    """A timed joint trajectory: positions (n_points, n_joints) at times (n_points,) seconds."""

    names: tuple[str, ...]
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray | None = None
    meta: dict = field(default_factory=dict)


class Hand(abc.ABC):
    """A tactile hand that can do guarded enclosure grasps."""

    @abc.abstractmethod
    def connect(self) -> None: ...

    @abc.abstractmethod
    def disconnect(self) -> None: ...

    @abc.abstractmethod
    def open(self) -> None:
        """Open all fingers fully (preshape unchanged)."""

    @abc.abstractmethod
    def preshape(self, angle: float) -> None:
        """Turn fingers 0 and 1 about their swivels to `angle` rad (0 cylinder ... 1.57 pinch)."""

    @abc.abstractmethod
    def guarded_close(self) -> Grasp:
        """Close every finger in steps until it touches or reaches its limit; report contacts."""

    @abc.abstractmethod
    def state(self) -> HandState: ...

    def __enter__(self) -> Hand:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


class Arm(abc.ABC):
    """An arm carrying the hand."""

    @abc.abstractmethod
    def connect(self) -> None: ...

    @abc.abstractmethod
    def disconnect(self) -> None: ...

    @abc.abstractmethod
    def joint_state(self) -> JointState: ...

    @abc.abstractmethod
    def execute(self, trajectory: JointTrajectory) -> None:
        """Run a timed joint trajectory to its end (blocking). Raises on failure."""

    @abc.abstractmethod
    def move_wrist(self, pose: Pose) -> None:
        """Bring the hand frame to `pose` (object frame), planning the motion itself.

        Raises `activetouch.errors.UnreachableError` when the pose cannot be reached."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Halt motion now and hold position."""

    def __enter__(self) -> Arm:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()
