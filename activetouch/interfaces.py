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
- An `Arm` is joint-level: it knows its joints, their limits and how to follow a timed joint
  trajectory. Turning a wrist pose (hand frame in the object frame, where training poses are
  stored) into joint motion is the motion layer's job (`activetouch.planning.motion`), so a
  driver stays small.
- `stop()` on either device may be called from any thread while a command runs; it takes
  effect at once and stays in force (commands raise `StoppedError`) until `clear_stop()`.
"""

from __future__ import annotations

import abc
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.clock import SYSTEM_CLOCK, Clock
from activetouch.errors import StoppedError

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

    def compose(self, other: Pose) -> Pose:
        """`other` (a pose in this pose's frame) in the frame this pose is in: self * other."""
        r = Rotation.from_quat(self.quat)
        return Pose(r.apply(other.xyz) + self.xyz, (r * Rotation.from_quat(other.quat)).as_quat())

    def inverse(self) -> Pose:
        """The pose of the parent frame in this one: p.compose(p.inverse()) is the identity."""
        r = Rotation.from_quat(self.quat).inv()
        return Pose(-r.apply(self.xyz), r.as_quat())


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

    def only(self, keep: np.ndarray) -> Grasp:
        """This grasp with only the contacts where `keep` ((n,) bool) is true."""
        return Grasp(
            sensor_ids=self.sensor_ids[keep],
            xyz=self.xyz[keep],
            pressures=self.pressures[keep],
            finger_angles=self.finger_angles,
            preshape=self.preshape,
        )


@dataclass(frozen=True)
class HandState:
    """A snapshot of the hand: all sensors, not just those in contact."""

    pressures: np.ndarray  # (38,) pressure above the zero offset
    contact: np.ndarray  # (38,) bool
    finger_angles: np.ndarray  # (3,) proximal joint angles, rad
    preshape: float
    stamp: float  # seconds, monotonic clock of the producer
    stale: bool = False  # the hand's stream is lost: these values are old
    wall_stamp: float = 0.0  # time.time() at `stamp` (0: unknown), for readers elsewhere


@dataclass(frozen=True)
class JointState:
    names: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    stamp: float


@dataclass(frozen=True)
class JointTrajectory:
    """A timed joint trajectory: positions (n_points, n_joints) at times (n_points,) seconds,
    with velocities and accelerations (same shape) where the planner timed them."""

    names: tuple[str, ...]
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    accelerations: np.ndarray | None = None


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits, in the order of `Arm.joint_names`: rad (or m), rad/s, rad/s^2."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self) -> None:
        for name in ("lower", "upper", "velocity", "acceleration"):
            object.__setattr__(
                self, name, np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            )
        n = len(self.lower)
        if not (len(self.upper) == len(self.velocity) == len(self.acceleration) == n):
            raise ValueError("joint limits differ in length")
        if np.any(self.lower > self.upper) or np.any(self.velocity <= 0):
            raise ValueError("joint limits: lower > upper or a non-positive velocity")

    def violations(self, names: tuple[str, ...], q: np.ndarray, tol: float = 1e-9) -> list[str]:
        """Human-readable list of the joints of `q` (n_points, n) outside the limits."""
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        out: list[str] = []
        for j, name in enumerate(names):
            lo, hi = float(q[:, j].min()), float(q[:, j].max())
            if lo < self.lower[j] - tol or hi > self.upper[j] + tol:
                out.append(
                    f"{name} reaches [{lo:.4g}, {hi:.4g}] outside "
                    f"[{self.lower[j]:.4g}, {self.upper[j]:.4g}]"
                )
        return out


@dataclass(frozen=True)
class Placed:
    """What a simulated robot put on its table (`DeviceContext.add_place`)."""

    object: str
    extents: tuple[float, float, float]  # bounding-box size, metres


def extents_of(values: Any) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


class StopLatch:
    """The stop flag every device keeps: set from any thread, checked by running commands,
    in force until cleared."""

    def __init__(self, clock: Clock = SYSTEM_CLOCK) -> None:
        self._event = threading.Event()
        self.clock = clock

    def set(self) -> None:
        self._event.set()

    def clear(self) -> None:
        self._event.clear()

    @property
    def is_set(self) -> bool:
        return self._event.is_set()

    def check(self, what: str) -> None:

        if self._event.is_set():
            raise StoppedError(f"{what}: the device is stopped (clear the stop first)")

    def wait(self, timeout: float) -> bool:
        """Sleep up to `timeout` s (on the latch's clock); True at once if the stop is (or
        becomes) set."""
        return self.clock.wait(self._event, timeout)


class Hand(abc.ABC):
    """A tactile hand that can do guarded enclosure grasps."""

    @property
    def robot_seconds(self) -> float | None:
        """Seconds the hand's commands so far took in robot time, for a simulated hand whose
        wall time is not the robot's (the twin closes in milliseconds); None: a real hand,
        whose commands take as long as they take."""
        return None

    @property
    def n_sensors(self) -> int:
        """How many tactile sensors the hand has (sensor ids are 0 .. n_sensors - 1): the
        ReFlex's 38 unless the hand says otherwise (the BarrettHand's 96 cells)."""
        return N_SENSORS

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
        """Close every finger in steps until it touches or reaches its limit; report contacts.

        Raises `StoppedError` if `stop()` is called meanwhile (within one control step)."""

    @abc.abstractmethod
    def state(self) -> HandState: ...

    def mask_sensors(self, sensor_ids: Sequence[int]) -> bool:
        """Ignore these sensors (and only these, replacing an earlier mask) until told
        otherwise: no finger stops on them and no grasp reports them (a sensor that reads
        contact with the hand open cannot be touched). False: this hand cannot (then the
        caller drops their contacts from the grasps itself)."""
        return False

    def sensor_flags(self) -> dict[int, str]:
        """Sensor id -> the flag its tactile calibration gave it (``dead``, ``saturated``,
        ``noisy``, ``drifting``); empty for a hand with none applied."""
        return {}

    def set_contact_thresholds(self, thresholds: Sequence[float]) -> bool:
        """Per-sensor contact thresholds (`n_sensors` of them, sensor units) measured from the
        noise at rest: a sensor counts as in contact only above its own and the hand's
        configured threshold, for stopping a finger and in the grasps, until set again. False:
        this hand cannot (the caller then drops the contacts under them from the grasps
        itself)."""
        return False

    def own_contact_thresholds(self) -> np.ndarray | None:
        """(n_sensors,) the thresholds the hand itself counts contact over (its configuration
        or tactile calibration; never those of `set_contact_thresholds`), sensor units above
        the zero offset. None: this hand does not tell (or senses no pressure)."""
        return None

    def sensor_sites(self) -> np.ndarray | None:
        """(n_sensors, 3) where each sensor is now, in the hand frame, at the joint angles the
        hand reports (as a grasp's contacts are placed). None: this hand cannot tell."""
        return None

    @abc.abstractmethod
    def stop(self) -> None:
        """Halt the fingers now, from any thread, also during `guarded_close`; motion commands
        are refused until `clear_stop()`."""

    @abc.abstractmethod
    def clear_stop(self) -> None:
        """Allow motion commands again after `stop()`."""

    def __enter__(self) -> Hand:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


class Arm(abc.ABC):
    """A joint-level arm carrying the hand."""

    @property
    @abc.abstractmethod
    def joint_names(self) -> tuple[str, ...]: ...

    @property
    @abc.abstractmethod
    def limits(self) -> JointLimits: ...

    @abc.abstractmethod
    def connect(self) -> None: ...

    @abc.abstractmethod
    def disconnect(self) -> None: ...

    @abc.abstractmethod
    def joint_state(self) -> JointState: ...

    @abc.abstractmethod
    def execute(self, trajectory: JointTrajectory) -> None:
        """Run a timed joint trajectory to its end (blocking). Raises on failure: a trajectory
        outside the joint limits is refused before anything moves (`UnreachableError`); a
        stop during it raises `StoppedError`."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Halt motion now and hold position; callable from another thread while `execute`
        runs. Further motion is refused until `clear_stop()`."""

    @abc.abstractmethod
    def clear_stop(self) -> None:
        """Allow motion again after `stop()`."""

    def estop(self) -> None:
        """Emergency stop: `stop()`, plus the robot's own e-stop where it has one (Baxter's
        ``robot/set_super_stop``, which disables the motors until a reset)."""
        self.stop()

    def enable(self) -> None:  # noqa: B027 - optional: most arms have no enabled state
        """Enable the motors, for arms that have such a state (Baxter); others are always
        enabled. Never called by the service on its own unless configured to."""

    def disable(self) -> None:  # noqa: B027 - optional, as enable
        """Disable the motors (the arm goes limp or holds on its brakes, as the robot does)."""

    def __enter__(self) -> Arm:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


class HandWrapper(Hand):
    """A `Hand` that forwards everything to `inner`: subclass it and override only what a
    wrapper changes (pacing, an interlock, a fault)."""

    def __init__(self, inner: Hand) -> None:
        self.inner = inner

    def connect(self) -> None:
        self.inner.connect()

    def disconnect(self) -> None:
        self.inner.disconnect()

    def open(self) -> None:
        self.inner.open()

    def preshape(self, angle: float) -> None:
        self.inner.preshape(angle)

    def guarded_close(self) -> Grasp:
        return self.inner.guarded_close()

    def state(self) -> HandState:
        return self.inner.state()

    def mask_sensors(self, sensor_ids: Sequence[int]) -> bool:
        return self.inner.mask_sensors(sensor_ids)

    def set_contact_thresholds(self, thresholds: Sequence[float]) -> bool:
        return self.inner.set_contact_thresholds(thresholds)

    def sensor_flags(self) -> dict[int, str]:
        return self.inner.sensor_flags()

    def own_contact_thresholds(self) -> np.ndarray | None:
        return self.inner.own_contact_thresholds()

    def sensor_sites(self) -> np.ndarray | None:
        return self.inner.sensor_sites()

    def stop(self) -> None:
        self.inner.stop()

    def clear_stop(self) -> None:
        self.inner.clear_stop()

    @property
    def robot_seconds(self) -> float | None:
        return self.inner.robot_seconds

    @property
    def n_sensors(self) -> int:
        return self.inner.n_sensors


class ArmWrapper(Arm):
    """An `Arm` that forwards everything to `inner` (as `HandWrapper`)."""

    def __init__(self, inner: Arm) -> None:
        self.inner = inner

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.inner.joint_names

    @property
    def limits(self) -> JointLimits:
        return self.inner.limits

    def connect(self) -> None:
        self.inner.connect()

    def disconnect(self) -> None:
        self.inner.disconnect()

    def joint_state(self) -> JointState:
        return self.inner.joint_state()

    def execute(self, trajectory: JointTrajectory) -> None:
        self.inner.execute(trajectory)

    def stop(self) -> None:
        self.inner.stop()

    def clear_stop(self) -> None:
        self.inner.clear_stop()

    def estop(self) -> None:
        self.inner.estop()

    def enable(self) -> None:
        self.inner.enable()

    def disable(self) -> None:
        self.inner.disable()
