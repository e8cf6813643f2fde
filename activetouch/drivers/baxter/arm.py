"""Baxter arm driver (``arm.type = "baxter"``): one arm through zenoh-bridge-ros1.

No ROS on this side: the driver opens its own Zenoh session to the bridge and exchanges raw
ROS 1 bytes on the bridge's keys (`activetouch.drivers.baxter.ros1`).

- State: ``/robot/joint_states`` (the latest message, filtered to the side's seven joints) and
  ``/robot/state`` (enabled / e-stop). A state older than `state_timeout_s` is an error.
- `execute` streams POSITION_MODE JointCommands at `command_hz`, sampling the timed
  trajectory (linear between its points), after (re)sending ``joint_command_timeout`` and
  ``set_speed_ratio`` (latched on the robot; re-sent because a bridge does not latch). It
  aborts with `TrackingError` naming the joint when a commanded and measured position differ
  by more than `tracking_tolerance_rad` for longer than `tracking_grace_s`, and finishes when
  the measured state settles at the goal.
- `stop()` latches and commands the measured position at once (hold). With
  `super_stop_on_stop` it also asserts Baxter's own e-stop (``robot/set_super_stop``).
- If commands stop (daemon killed, network cut), Baxter leaves position control after
  ``joint_command_timeout`` and holds its current joint angles.
- Enabling is explicit (`enable`, `disable`, `reset`); `enable_on_connect` opts in.
- ``emulate = "twin"``: no robot; the same driver against the byte-level emulator in this
  process on loopback Zenoh, its joints carrying the Baxter twin's arm and hand
  (`activetouch.rigs.baxter_emulated`); it counts as simulated.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from activetouch.clock import SYSTEM_CLOCK, Clock
from activetouch.device_types import ArmConfig
from activetouch.drivers.baxter import ros1
from activetouch.errors import (
    ConfigError,
    MessageError,
    NodeUnavailableError,
    StoppedError,
    TrackingError,
    UnreachableError,
)
from activetouch.interfaces import Arm, JointLimits, JointState, JointTrajectory, StopLatch
from activetouch.planning.motion.base import workcell_placement
from activetouch.planning.motion.baxter import BaxterWristMotion
from activetouch.planning.motion.robot import BaxterMotionConfig, load_arm

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext
    from activetouch.planning.motion.base import WristMotion

log = logging.getLogger(__name__)

# URDF (baxter_description/urdf/baxter.urdf) limits, identical for both arms, s0..w2.
LOWER = (-1.70167993878, -2.147, -3.05417993878, -0.05, -3.059, -1.57079632679, -3.059)
UPPER = (1.70167993878, 1.047, 3.05417993878, 2.618, 3.059, 2.094, 3.059)
VELOCITY = (1.5, 1.5, 1.5, 1.5, 4.0, 4.0, 4.0)


@dataclass
class BaxterArmConfig(ArmConfig):
    """``[arm] type = "baxter"``: one Baxter arm behind zenoh-bridge-ros1."""

    # "left" | "right"; empty: `motion.side` ("left" by default). The motion layer's side
    # follows this one (a twin-baxter config names its side only in [arm.motion]).
    side: str = ""
    # The chunk after the md5 in the bridge's keys. The bridge's default is the literal "*"
    # (it puts and subscribes on ".../*/topic"), which also matches any named namespace.
    bridge_namespace: str = ros1.DEFAULT_BRIDGE_NAMESPACE
    # "namespaced": <hex type>/<md5>/<namespace>/<topic> (zenoh-plugin-ros1 main since
    # 2025-02); "legacy": <hex type>/<md5>/<topic> (1.0.0-rc.1 and older).
    bridge_format: str = "auto"  # auto | namespaced | legacy (docs/protocols/baxter.md)
    command_hz: float = 100.0
    # Zenoh endpoints of the bridge (its session is separate from the service's).
    connect: list[str] = field(default_factory=lambda: ["tcp/127.0.0.1:7448"])
    listen: list[str] = field(default_factory=list)
    zenoh_config: str = ""
    command_timeout_s: float = 0.2  # Baxter holds when no command came for this long
    speed_ratio: float = 1.0  # of Baxter's position-mode speed; <1 makes the arm lag the stream
    tracking_tolerance_rad: float = 0.2  # JTAS default per-joint trajectory tolerance
    tracking_grace_s: float = 0.5
    goal_tolerance_rad: float = 0.008726646  # baxter_interface JOINT_ANGLE_TOLERANCE (0.5 deg)
    settle_timeout_s: float = 2.0  # after the last point, to reach the goal tolerance
    start_tolerance_rad: float = 0.05  # first point vs measured position
    state_timeout_s: float = 0.5  # joint / robot state older than this is lost
    connect_timeout_s: float = 5.0  # wait for the first joint state
    require_enabled: bool = True  # refuse to move unless /robot/state says enabled
    enable_on_connect: bool = False  # never enable the robot unless told to
    enable_timeout_s: float = 2.0  # robot_enable.py: enable 2 s, disable 5 s, reset/stop 3 s
    super_stop_on_stop: bool = False  # stop() also asserts Baxter's e-stop (needs a reset)
    acceleration_rad_s2: float = 1.5  # reported limit for the motion layer's timing
    # The motion layer (IK, collision-checked paths, timing): ``[arm.motion]``, as twin-baxter.
    motion: BaxterMotionConfig = field(default_factory=BaxterMotionConfig)
    # "twin": no robot; an in-process emulator on loopback Zenoh whose joints carry the Baxter
    # twin's arm and the twin's hand (twin_emulated.py). The driver is unchanged.
    emulate: str = ""
    # emulate = "twin": trajectory seconds between the twin arm's checked samples (twin-baxter's
    # setting, so a twin-baxter config runs with `--set arm.type=baxter`).
    sample_dt: float = 0.01
    # twin-baxter's pacing, accepted for the same reason and ignored: the emulator runs in real
    # time, as the robot does.
    time_scale: float = 0.0

    @property
    def simulated(self) -> bool:  # type: ignore[override]
        # An emulated robot stands in for the real one: recognitions place the object.
        return self.emulate == "twin"

    def check(self) -> None:
        self.side = self.side or self.motion.side
        ros1.joint_names(self.side)
        self.motion.side = self.side
        self.motion.check()
        if self.emulate not in ("", "twin"):
            raise ConfigError(f"arm.emulate: {self.emulate!r} is not one of '', 'twin'")
        if not 0 < self.sample_dt <= 0.01:
            raise ConfigError(f"arm.sample_dt must be in (0, 0.01] s, got {self.sample_dt}")
        if self.bridge_format not in ros1.BRIDGE_FORMAT_CHOICES:
            raise ConfigError(
                f"arm.bridge_format: expected one of {ros1.BRIDGE_FORMAT_CHOICES}, "
                f"got {self.bridge_format!r}"
            )
        ros1.check_namespace(self.bridge_namespace)
        if not (1.0 / self.command_timeout_s < self.command_hz <= 1000.0):
            raise ConfigError(
                f"arm.command_hz {self.command_hz} must be above 1/command_timeout_s "
                f"({1.0 / self.command_timeout_s:g} Hz) and at most 1000"
            )
        if not 0.0 < self.speed_ratio <= 1.0:
            raise ConfigError(f"arm.speed_ratio {self.speed_ratio} must be in (0, 1]")
        positive = (
            "command_timeout_s", "tracking_tolerance_rad", "tracking_grace_s",
            "goal_tolerance_rad", "settle_timeout_s", "start_tolerance_rad", "state_timeout_s",
            "connect_timeout_s", "enable_timeout_s", "acceleration_rad_s2",
        )  # fmt: skip
        for name in positive:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"arm.{name} must be a positive number, got {v}")
        if not self.connect and not self.listen:
            raise ConfigError("arm.connect / arm.listen: give the bridge's Zenoh endpoint")

    def make(self, ctx: DeviceContext) -> Arm:
        self.check()
        if self.emulate:  # the rig's config class (activetouch.rigs) makes that one
            raise ConfigError(f"arm.emulate = {self.emulate!r}: made through the device registry")
        return BaxterArm(self)

    def make_wrist(self, arm: Arm, ctx: DeviceContext) -> WristMotion:
        """`BaxterWristMotion`: with ``emulate = "twin"`` the twin-baxter type's (placement and
        object shape from the twin world); on the robot the workcell's table and object frame
        (the object has no shape yet: transits do not avoid it)."""

        wc = ctx.cfg.workcell
        # the same shared name as twin-baxter's model (sim/baxter.py BAXTER_MODEL)
        model = ctx.shared("baxter-model", lambda: load_arm(self.motion))
        return BaxterWristMotion(
            arm, workcell_placement(wc), wc.table_center, wc.table_size, self.motion, model
        )


@dataclass(frozen=True)
class _Stamped:
    value: Any
    at: float  # time.monotonic() of receipt


def sample(times: np.ndarray, positions: np.ndarray, t: float) -> np.ndarray:
    """Positions of the timed trajectory at time `t` (linear between points, ends held)."""
    return np.array([np.interp(t, times, positions[:, j]) for j in range(positions.shape[1])])


def reorder(traj: JointTrajectory, names: tuple[str, ...]) -> np.ndarray:
    """The trajectory's positions with columns in `names` order; UnreachableError if the
    joints differ."""
    if sorted(traj.names) != sorted(names) or len(set(traj.names)) != len(traj.names):
        raise UnreachableError(f"trajectory joints {list(traj.names)} are not this arm's {names}")
    pos = np.asarray(traj.positions, dtype=np.float64)
    return pos[:, [traj.names.index(n) for n in names]]


def check_trajectory(
    traj: JointTrajectory, names: tuple[str, ...], limits: JointLimits
) -> tuple[np.ndarray, np.ndarray]:
    """(times from 0, positions in `names` order), or UnreachableError before anything moves."""
    times = np.asarray(traj.times, dtype=np.float64).reshape(-1)
    pos = reorder(traj, names)
    if pos.ndim != 2 or len(times) != len(pos) or len(times) < 1:
        raise UnreachableError("trajectory: times and positions differ in length or are empty")
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(pos))):
        raise UnreachableError("trajectory: non-finite times or positions")
    if np.any(np.diff(times) <= 0):
        raise UnreachableError("trajectory: times must increase strictly")
    bad = limits.violations(names, pos)
    if bad:
        raise UnreachableError("trajectory outside the joint limits: " + "; ".join(bad))
    if len(times) > 1:
        # mean speeds between points (a lower bound of the peak): 5 % slack for rounding
        speed = np.abs(np.diff(pos, axis=0)) / np.diff(times)[:, None]
        over = np.nonzero(speed.max(axis=0) > limits.velocity * 1.05)[0]
        if len(over):
            j = int(over[0])
            raise UnreachableError(
                f"trajectory too fast: {names[j]} at {speed[:, j].max():.3g} rad/s "
                f"(limit {limits.velocity[j]:.3g})"
            )
    return times - times[0], pos


def not_following(q_start: np.ndarray, q: np.ndarray, side: str) -> str:
    """What to say when fresh joint states show the arm has not moved at all under a command:
    the commands are likely not reaching Baxter (zenoh-plugin-ros1 issue #92)."""
    if float(np.max(np.abs(np.asarray(q) - np.asarray(q_start)))) > 2e-3:
        return ""
    return (
        f". Joint states arrive but the arm has not moved at all: the bridge is probably not "
        f"forwarding /robot/limb/{side}/joint_command (zenoh-plugin-ros1 issue #92: a topic "
        "with only ROS subscribers may not be bridged). Run the bridge in `auto` mode, started "
        f"after Baxter's nodes; `rostopic info /robot/limb/{side}/joint_command` must list it as "
        "a publisher, else relay the topic from ROS. Check too that the arm is enabled"
    )


class BaxterArm(Arm):
    """One Baxter arm over zenoh-bridge-ros1. Pass `session` (a `zenoh.Session`) to share one;
    otherwise `connect()` opens its own from the config's endpoints and closes it again.
    `clock` paces the command stream (its schedule and the waits between commands; a test
    clock judges the stream in the driver's own time); state freshness is on the system's."""

    def __init__(
        self, cfg: BaxterArmConfig, session: Any = None, clock: Clock = SYSTEM_CLOCK
    ) -> None:
        cfg.check()
        self.cfg = cfg
        self._names = ros1.joint_names(cfg.side)
        self._limits = JointLimits(
            np.array(LOWER),
            np.array(UPPER),
            np.array(VELOCITY),
            np.full(7, cfg.acceleration_rad_s2),
        )
        self._topics = ros1.Topics(cfg.side)
        self._external = session
        self._zs: Any = None
        self._session: Any = None
        self._codec: ros1.Ros1Codec | None = None
        self._clock = clock
        self._latch = StopLatch(clock)
        self._pub_lock = threading.Lock()  # orders trajectory commands before a stop's hold
        self._cond = threading.Condition()
        self._joints: _Stamped | None = None  # (position, velocity, stamp)
        self._robot: _Stamped | None = None  # ros1.RobotState
        self._malformed = 0
        self._best_lag = math.inf  # s, smallest (wall clock - header stamp) seen
        self._subs: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self._detected: tuple[str, str] | None = None  # (format, namespace) with `auto`

    # ---------------------------------------------------------------- Arm properties
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._names

    @property
    def limits(self) -> JointLimits:
        return self._limits

    def key(self, ros_type: str, topic: str) -> str:
        fmt, ns = self.bridge_format, self.bridge_namespace
        if fmt == "auto":
            raise ConfigError(
                "arm.bridge_format = auto: the format is not known before a joint state"
            )
        return ros1.bridge_key(ros_type, topic, ns, fmt)

    @property
    def bridge_format(self) -> str:
        """The key format in use: the configured one, or the one detected (`auto`)."""
        return self._detected[0] if self._detected is not None else self.cfg.bridge_format

    @property
    def bridge_namespace(self) -> str:
        return self._detected[1] if self._detected is not None else self.cfg.bridge_namespace

    def _joint_state_keys(self) -> tuple[str, ...]:
        t = self._topics
        if self.cfg.bridge_format == "auto":
            return ros1.auto_keys(ros1.JOINT_STATE, t.joint_states)
        return (self.key(ros1.JOINT_STATE, t.joint_states),)

    # ---------------------------------------------------------------- connection
    def connect(self) -> None:
        if self._session is not None:
            return
        self._codec = ros1.Ros1Codec()  # checks the md5 sums before anything is sent
        if self._external is not None:
            self._session = self._external
        else:
            # deferred: loads zenoh, needed only when no session is passed in
            from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings

            self._zs = ZenohSession(
                ZenohSettings(
                    listen=tuple(self.cfg.listen),
                    connect=tuple(self.cfg.connect),
                    config_file=Path(self.cfg.zenoh_config) if self.cfg.zenoh_config else None,
                )
            )
            self._session = self._zs.session
        t = self._topics
        try:
            self._subs = [
                self._session.declare_subscriber(k, self._on_joint_state)
                for k in self._joint_state_keys()
            ]
            self._wait_joints(self.cfg.connect_timeout_s)
            if self.cfg.bridge_format == "auto":
                log.info(
                    "Baxter %s arm: the bridge speaks the %s key format%s",
                    self.cfg.side,
                    self.bridge_format,
                    f" (namespace {self.bridge_namespace!r})" if self.bridge_namespace else "",
                )
            self._subs.append(
                self._session.declare_subscriber(
                    self.key(ros1.ASSEMBLY_STATE, t.robot_state), self._on_robot_state
                )
            )
            # Publishers on the format the bridge speaks. Declaring them does not make the
            # bridge bridge a topic: it bridges what ROS has (docs/protocols/baxter.md).
            for ros_type, topic in (
                (ros1.JOINT_COMMAND, t.joint_command),
                (ros1.FLOAT64, t.speed_ratio),
                (ros1.FLOAT64, t.command_timeout),
                (ros1.BOOL, t.enable),
                (ros1.EMPTY, t.stop),
                (ros1.EMPTY, t.reset),
            ):
                self._pubs[topic] = self._session.declare_publisher(self.key(ros_type, topic))
            if self.cfg.enable_on_connect:
                self.enable()
        except BaseException:
            self.disconnect()
            raise

    def disconnect(self) -> None:
        for obj in (*self._subs, *self._pubs.values()):
            try:
                obj.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self._subs, self._pubs = [], {}
        if self._zs is not None:
            self._zs.close()
        self._zs = self._session = None

    # ---------------------------------------------------------------- Zenoh callbacks
    # Parse and store only: never call Zenoh or block in a callback.
    def _on_joint_state(self, sample: Any) -> None:
        assert self._codec is not None
        if self._detected is None and self.cfg.bridge_format == "auto":
            self._detected = ros1.format_of_key(
                str(sample.key_expr), ros1.JOINT_STATE, self._topics.joint_states
            )
        try:
            msg = self._codec.parse_joint_state(bytes(sample.payload.to_bytes()))
        except MessageError as e:
            self._malformed += 1
            log.debug("dropping a joint state: %s", e)
            return
        sel = msg.select(self._names)
        if sel is None or not (np.all(np.isfinite(sel[0])) and np.all(np.isfinite(sel[1]))):
            return  # another arm's or head's message, or garbage values
        now = time.monotonic()
        # Delayed states: the robot's clock and ours differ by an unknown offset, so compare
        # each message's transit lag with the smallest seen (relaxed by 1 ms/s for clock
        # drift). A message later than that by more than state_timeout_s counts as lost.
        lag = time.time() - msg.stamp
        with self._cond:
            if self._joints is not None:
                self._best_lag = min(lag, self._best_lag + 1e-3 * (now - self._joints.at))
            else:
                self._best_lag = lag
            late = max(lag - self._best_lag, 0.0)
            self._joints = _Stamped((sel[0], sel[1], msg.stamp), now - late)
            self._cond.notify_all()

    def _on_robot_state(self, sample: Any) -> None:
        assert self._codec is not None
        try:
            st = self._codec.parse_robot_state(bytes(sample.payload.to_bytes()))
        except MessageError as e:
            self._malformed += 1
            log.debug("dropping a robot state: %s", e)
            return
        with self._cond:
            self._robot = _Stamped(st, time.monotonic())
            self._cond.notify_all()

    # ---------------------------------------------------------------- state
    def _wait_joints(self, timeout: float) -> _Stamped:
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                js = self._joints
                if js is not None and time.monotonic() - js.at <= self.cfg.state_timeout_s:
                    return js
                left = deadline - time.monotonic()
                if left <= 0:
                    raise NodeUnavailableError(
                        f"Baxter {self.cfg.side} arm: no joint state on "
                        f"{' or '.join(self._joint_state_keys())} "
                        f"within {timeout:g} s (is zenoh-bridge-ros1 running and connected?)"
                    )
                self._cond.wait(left)

    def _fresh_joints(self) -> tuple[np.ndarray, np.ndarray]:
        js = self._joints
        if js is None or time.monotonic() - js.at > self.cfg.state_timeout_s:
            age = "never" if js is None else f"{time.monotonic() - js.at:.2f} s ago"
            raise NodeUnavailableError(
                f"Baxter {self.cfg.side} arm: joint states lost (last {age}, "
                f"timeout {self.cfg.state_timeout_s:g} s)"
            )
        return js.value[0], js.value[1]

    def robot_state(self) -> ros1.RobotState | None:
        """The latest fresh ``/robot/state``, or None if none came within `state_timeout_s`."""
        rs = self._robot
        if rs is None or time.monotonic() - rs.at > self.cfg.state_timeout_s:
            return None
        return rs.value

    def joint_state(self) -> JointState:
        self._require_connected()
        q, v = self._fresh_joints()
        return JointState(self._names, q.copy(), v.copy(), self._joints.at)

    def _require_connected(self) -> None:
        if self._session is None:
            raise NodeUnavailableError("Baxter arm: not connected")

    def _check_robot(self, what: str) -> None:
        if not self.cfg.require_enabled:
            return
        st = self.robot_state()
        if st is None:  # e.g. right after connect: wait for one, briefly
            deadline = time.monotonic() + self.cfg.state_timeout_s
            with self._cond:
                while (st := self.robot_state()) is None and time.monotonic() < deadline:
                    self._cond.wait(max(deadline - time.monotonic(), 0.0))
        if st is None:
            raise NodeUnavailableError(
                f"{what}: no /robot/state within {self.cfg.state_timeout_s:g} s"
            )
        if st.stopped or not st.enabled:
            raise StoppedError(f"{what}: Baxter is {st.describe()}")

    # ---------------------------------------------------------------- publishing
    def _put(self, topic: str, payload: bytes) -> None:
        pub = self._pubs.get(topic)
        if pub is None:
            raise NodeUnavailableError("Baxter arm: not connected")
        pub.put(payload)

    def _command(self, q: np.ndarray) -> None:
        assert self._codec is not None
        self._put(self._topics.joint_command, self._codec.joint_command(self._names, q))

    def _send_settings(self) -> None:
        assert self._codec is not None
        self._put(self._topics.command_timeout, self._codec.float64(self.cfg.command_timeout_s))
        self._put(self._topics.speed_ratio, self._codec.float64(self.cfg.speed_ratio))

    # ---------------------------------------------------------------- motion
    def execute(self, trajectory: JointTrajectory) -> None:
        self._require_connected()
        times, pos = check_trajectory(trajectory, self._names, self._limits)
        self._latch.check("execute")
        self._check_robot("execute")
        q0, _ = self._fresh_joints()
        dev = np.abs(pos[0] - q0)
        j = int(np.argmax(dev))
        if dev[j] > self.cfg.start_tolerance_rad:
            raise UnreachableError(
                f"trajectory starts {dev[j]:.3f} rad from the measured {self._names[j]} "
                f"(tolerance {self.cfg.start_tolerance_rad:g})"
            )
        try:
            self._stream(times, pos)
        except StoppedError:
            raise
        except BaseException:
            self._hold_quietly()
            raise

    def _stream(self, times: np.ndarray, pos: np.ndarray) -> None:
        cfg = self.cfg
        period = 1.0 / cfg.command_hz
        goal = pos[-1]
        off_since: np.ndarray = np.full(7, math.nan)  # when each joint left the tolerance
        settle_deadline = times[-1] + cfg.settle_timeout_s
        next_settings = 0.0
        q_start, _ = self._fresh_joints()
        clock = self._clock
        t0 = clock.monotonic()
        k = 0
        while True:
            t = clock.monotonic() - t0
            if t >= next_settings:  # re-sent each second: a bridge does not latch them
                self._send_settings()
                next_settings = t + 1.0
            cmd = sample(times, pos, t)
            with self._pub_lock:
                if self._latch.is_set:
                    break
                self._command(cmd)
            q, _ = self._fresh_joints()
            self._check_robot("execute")
            # tracking: commanded vs measured, per joint, beyond tolerance for a grace time
            err = np.abs(cmd - q)
            off = err > cfg.tracking_tolerance_rad
            off_since = np.where(off, np.where(np.isnan(off_since), t, off_since), math.nan)
            late = np.nonzero(off & (t - off_since > cfg.tracking_grace_s))[0]
            if len(late):
                j = int(late[0])
                raise TrackingError(
                    f"Baxter {self._names[j]} is {err[j]:.3f} rad from its command for "
                    f"> {cfg.tracking_grace_s:g} s (tolerance {cfg.tracking_tolerance_rad:g} "
                    "rad): motion aborted, holding" + not_following(q_start, q, self.cfg.side)
                )
            if t >= times[-1]:
                goal_err = np.abs(goal - q)
                if np.all(goal_err <= cfg.goal_tolerance_rad):
                    return
                if t > settle_deadline:
                    j = int(np.argmax(goal_err))
                    raise TrackingError(
                        f"Baxter {self._names[j]} did not settle at its goal: "
                        f"{goal_err[j]:.4f} rad off after {cfg.settle_timeout_s:g} s"
                    )
            k += 1
            # absolute schedule keeps the command rate at command_hz; wakes at once on stop
            if self._latch.wait(max(t0 + k * period - clock.monotonic(), 0.0)):
                break
        raise StoppedError("execute: the arm was stopped")

    def _hold_quietly(self) -> None:
        """Command the measured position once; used when a motion fails (best effort)."""
        try:
            js = self._joints
            if js is not None and self._session is not None:
                with self._pub_lock:
                    self._command(js.value[0])
        except Exception:
            log.debug("hold command failed", exc_info=True)

    def stop(self) -> None:
        self._latch.set()
        js = self._joints
        if self._session is not None and js is not None:
            with self._pub_lock:  # after this the streaming loop sends nothing more
                self._command(js.value[0])
        if self.cfg.super_stop_on_stop and self._session is not None:
            assert self._codec is not None
            self._put(self._topics.stop, self._codec.empty())

    def clear_stop(self) -> None:
        self._latch.clear()

    # ---------------------------------------------------------------- robot enable
    def _until(self, what: str, topic: str, payload: bytes, done: Any, timeout: float) -> None:
        """Publish `payload` on `topic` at 100 Hz until `done(state)` (robot_enable.py)."""
        self._require_connected()
        deadline = time.monotonic() + timeout
        while True:
            st = self.robot_state()
            if st is not None and done(st):
                return
            if time.monotonic() > deadline:
                now = "no /robot/state" if st is None else st.describe()
                raise NodeUnavailableError(f"Baxter {what}: not done within {timeout:g} s ({now})")
            self._put(topic, payload)
            time.sleep(0.01)

    def reset(self) -> None:
        """Clear a software e-stop or error (``robot/set_super_reset``); leaves it disabled."""
        assert self._codec is not None
        st = self.robot_state()
        if st is not None and st.stopped and st.estop_button == 1:
            raise StoppedError("Baxter reset: the e-stop button is pressed; release it first")
        self._until(
            "reset",
            self._topics.reset,
            self._codec.empty(),
            lambda s: not (s.enabled or s.stopped or s.error or s.estop_button or s.estop_source),
            3.0,
        )

    def enable(self) -> None:
        """Enable the motors (``robot/set_super_enable`` True until enabled), resetting first
        if stopped."""
        assert self._codec is not None
        st = self.robot_state()
        if st is not None and st.stopped:
            self.reset()
        self._until(
            "enable",
            self._topics.enable,
            self._codec.bool(True),
            lambda s: s.enabled,
            self.cfg.enable_timeout_s,
        )

    def disable(self) -> None:
        assert self._codec is not None
        self._until(
            "disable", self._topics.enable, self._codec.bool(False), lambda s: not s.enabled, 5.0
        )

    def estop(self) -> None:
        """Latch the stop, hold, and assert Baxter's own e-stop until it reports stopped."""
        assert self._codec is not None
        self.stop()
        self._until("e-stop", self._topics.stop, self._codec.empty(), lambda s: s.stopped, 3.0)
