"""A byte-level Baxter as seen through zenoh-bridge-ros1, for tests and demos without a robot.

It speaks the bridge's Zenoh keys and ROS 1 bytes, packed and parsed here by hand with
`struct` from the message definitions (never through the driver's rosbags codec, so a bug in
one cannot hide the same bug in the other):

- publishes ``/robot/joint_states`` (both arms, head and torso, like the robot) and
  ``/robot/state`` (AssemblyState) at `rate_hz` (100 Hz);
- follows POSITION_MODE ``/robot/limb/<side>/joint_command`` with a first-order lag, limited to
  the URDF velocity limits times the speed ratio (``set_speed_ratio``, default 0.3 as on the
  robot) and clamped to the joint limits;
- holds its current position when commands stop for longer than ``joint_command_timeout``
  (0.2 s default), as Baxter does;
- honours ``/robot/set_super_enable`` (Bool), ``set_super_stop`` and ``set_super_reset``
  (Empty) with the robot_enable.py semantics;
- faults on demand: dropped or delayed joint states, a lagging joint, an e-stop press,
  a disabled robot;
- optionally a `Body` that moves with the joints (the Baxter twin: ``arm.emulate = "twin"``,
  `activetouch.rigs.baxter_emulated`), which may block a step (a contact).

Run it: ``python -m activetouch.emulators.baxter_bridge --listen tcp/127.0.0.1:7448``.
"""

from __future__ import annotations

import argparse
import collections
import logging
import math
import signal
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

log = logging.getLogger(__name__)

_JOINTS = ("s0", "s1", "e0", "e1", "w0", "w1", "w2")
# URDF limits (baxter_description/urdf/baxter.urdf), the same for both arms.
_LOWER = np.array([-1.70167993878, -2.147, -3.05417993878, -0.05, -3.059, -1.57079632679, -3.059])
_UPPER = np.array([1.70167993878, 1.047, 3.05417993878, 2.618, 3.059, 2.094, 3.059])
_VEL = np.array([1.5, 1.5, 1.5, 1.5, 4.0, 4.0, 4.0])
_NEUTRAL = np.array([0.0, -0.55, 0.0, 0.75, 0.0, 1.26, 0.0])  # baxter_interface move_to_neutral
_EXTRA = ("head_nod", "head_pan", "torso_t0")  # the robot reports these too; drivers must filter

# md5 sums written out again here on purpose (not imported from the driver).
_TYPES = {
    "JointCommand": ("baxter_core_msgs/JointCommand", "19bfec8434dd568ab3c633d187c36f2e"),
    "AssemblyState": ("baxter_core_msgs/AssemblyState", "356d9dd237ce73b2667da9235f541933"),
    "JointState": ("sensor_msgs/JointState", "3066dcd76a6cfaef579bd0f34173e9fd"),
    "Bool": ("std_msgs/Bool", "8b94c1b53db61fb6aed406028ad6332a"),
    "Empty": ("std_msgs/Empty", "d41d8cd98f00b204e9800998ecf8427e"),
    "Float64": ("std_msgs/Float64", "fdb28210bfa9d7c91146260178d9a584"),
}


def key(kind: str, topic: str, namespace: str = "*", legacy: bool = False) -> str:
    """The bridge key of `topic` carrying message `kind` (a key of `_TYPES`)."""
    ros_type, md5 = _TYPES[kind]
    hexed = "".join(f"{b:02x}" for b in ros_type.encode("ascii"))
    parts = [hexed, md5] + ([] if legacy else [namespace]) + [topic.strip("/")]
    return "/".join(parts)


# --------------------------------------------------------------------------- ROS 1 bytes


class WireError(ValueError):
    """Bytes that are not a valid ROS 1 message of the expected type."""


def _string(s: str) -> bytes:
    b = s.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _f64_array(a: np.ndarray) -> bytes:
    a = np.asarray(a, dtype="<f8").reshape(-1)
    return struct.pack("<I", len(a)) + a.tobytes()


def pack_joint_state(
    seq: int,
    stamp: float,
    names: list[str],
    position: np.ndarray,
    velocity: np.ndarray,
    effort: np.ndarray,
    frame_id: str = "",
) -> bytes:
    """sensor_msgs/JointState: Header{uint32 seq, time(uint32 sec, uint32 nsec), string frame_id},
    string[] name, float64[] position, velocity, effort."""
    sec = int(stamp)
    nsec = min(round((stamp - sec) * 1e9), 999_999_999)
    out = [struct.pack("<III", seq & 0xFFFFFFFF, sec, nsec), _string(frame_id)]
    out.append(struct.pack("<I", len(names)))
    out += [_string(n) for n in names]
    out += [_f64_array(position), _f64_array(velocity), _f64_array(effort)]
    return b"".join(out)


def pack_assembly_state(
    ready: bool, enabled: bool, stopped: bool, error: bool, button: int, source: int
) -> bytes:
    """baxter_core_msgs/AssemblyState: 4 bools, uint8 estop_button, uint8 estop_source."""
    return struct.pack("<6B", ready, enabled, stopped, error, button, source)


class _Reader:
    def __init__(self, raw: bytes) -> None:
        self.raw = bytes(raw)
        self.at = 0

    def take(self, n: int) -> bytes:
        if n < 0 or self.at + n > len(self.raw):
            raise WireError(f"truncated: need {n} B at offset {self.at} of {len(self.raw)}")
        b = self.raw[self.at : self.at + n]
        self.at += n
        return b

    def u32(self) -> int:
        return int(struct.unpack("<I", self.take(4))[0])

    def string(self) -> str:
        try:
            return self.take(self.u32()).decode("utf-8")
        except UnicodeDecodeError as e:
            raise WireError(f"string is not UTF-8: {e}") from None

    def end(self) -> None:
        if self.at != len(self.raw):
            raise WireError(f"{len(self.raw) - self.at} trailing bytes")


def parse_joint_command(raw: bytes) -> tuple[int, list[float], list[str]]:
    """baxter_core_msgs/JointCommand: int32 mode, float64[] command, string[] names."""
    r = _Reader(raw)
    (mode,) = struct.unpack("<i", r.take(4))
    n = r.u32()
    command = list(struct.unpack(f"<{n}d", r.take(8 * n)))  # take() bounds n by the bytes left
    m = r.u32()
    if m > len(raw):
        raise WireError(f"names array length {m} exceeds the message")
    names = [r.string() for _ in range(m)]
    r.end()
    return mode, command, names


def parse_scalar(raw: bytes, fmt: str) -> float | bool:
    """std_msgs/Bool (fmt "<B") or std_msgs/Float64 (fmt "<d")."""
    if len(raw) != struct.calcsize(fmt):
        raise WireError(f"expected {struct.calcsize(fmt)} B, got {len(raw)}")
    (v,) = struct.unpack(fmt, raw)
    return bool(v) if fmt == "<B" else float(v)


# --------------------------------------------------------------------------- the robot


@dataclass
class Faults:
    """Faults switched on by tests or the CLI (all off by default)."""

    drop_states: bool = False  # publish no joint states at all
    state_delay_s: float = 0.0  # publish joint states this old
    lag_joint: str = ""  # e.g. "left_e1": this joint moves at `lag_speed_factor` of its limit
    lag_speed_factor: float = 0.05


@dataclass
class _Arm:
    q: np.ndarray
    target: np.ndarray
    last_command: float = -math.inf  # monotonic time of the last accepted command
    timeout_s: float = 0.2
    speed_ratio: float = 0.3
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(7))
    commands: collections.deque = field(default_factory=lambda: collections.deque(maxlen=10000))


@dataclass
class EmulatorSettings:
    namespace: str = "*"
    legacy: bool = False
    rate_hz: float = 100.0
    lag_tau_s: float = 0.05  # first-order lag of the joint position loop
    enabled: bool = False  # the robot starts disabled, as after power-up
    start: dict[str, float] = field(default_factory=dict)  # joint name -> initial position
    # The bridge does not forward joint_command (zenoh-plugin-ros1 issue #92: a topic with
    # only ROS subscribers may never be bridged): states flow, commands vanish.
    drop_commands: bool = False


class Body(Protocol):
    """Something the emulated joints carry (e.g. the Baxter twin's arm and hand)."""

    def follow(self, side: str, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
        """Move `side`'s arm from `q_from` to `q_to` (s0..w2, one control tick); return where it
        got (`q_to`, or short of it when something blocks the way). Called by the control loop
        with the emulator's lock held: no Zenoh, no waiting on the emulator."""
        ...


class BaxterEmulator:
    """The emulated robot on an open Zenoh session (`zenoh.Session`). Close it (or use `with`).
    `body`, if given, moves with the joints and may block them (`Body`)."""

    def __init__(
        self, session, settings: EmulatorSettings | None = None, body: Body | None = None
    ) -> None:
        self.s = settings or EmulatorSettings()
        self.body = body
        self._session = session
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.faults = Faults()
        self.arms: dict[str, _Arm] = {}
        for side in ("left", "right"):
            q = _NEUTRAL.copy()
            for j, name in enumerate(_JOINTS):
                q[j] = self.s.start.get(f"{side}_{name}", q[j])
            self.arms[side] = _Arm(q=q, target=q.copy())
        self.enabled = self.s.enabled
        self.stopped = False
        self.error = False
        self.button = 0
        self.source = 0
        self.malformed = 0  # messages rejected by the parsers
        self._seq = 0
        self._history: collections.deque = collections.deque(maxlen=1000)
        k = self._key
        self._pub_js = session.declare_publisher(k("JointState", "/robot/joint_states"))
        self._pub_state = session.declare_publisher(k("AssemblyState", "/robot/state"))
        subs = [
            (k("Bool", "/robot/set_super_enable"), self._on_enable),
            (k("Empty", "/robot/set_super_stop"), self._on_super_stop),
            (k("Empty", "/robot/set_super_reset"), self._on_reset),
        ]
        for side in ("left", "right"):
            base = f"/robot/limb/{side}/"
            subs += [
                (k("JointCommand", base + "joint_command"), self._on_command(side)),
                (k("Float64", base + "set_speed_ratio"), self._on_ratio(side)),
                (k("Float64", base + "joint_command_timeout"), self._on_timeout(side)),
            ]
        self._subs = [session.declare_subscriber(key_, cb) for key_, cb in subs]
        self._thread = threading.Thread(target=self._run, name="baxter-emulator", daemon=True)
        self._thread.start()

    def _key(self, kind: str, topic: str) -> str:
        return key(kind, topic, self.s.namespace, self.s.legacy)

    # --- Zenoh callbacks: parse and update state under the lock, nothing else
    def _payload(self, sample) -> bytes:
        return bytes(sample.payload.to_bytes())

    def _on_command(self, side: str):
        def cb(sample) -> None:
            if self.s.drop_commands:
                return
            try:
                mode, command, names = parse_joint_command(self._payload(sample))
            except WireError:
                self.malformed += 1
                return
            now = time.monotonic()
            with self._lock:
                arm = self.arms[side]
                arm.commands.append((now, mode, tuple(names), tuple(command)))
                if mode != 1 or len(command) != len(names) or not self.enabled:
                    return  # only position mode is emulated; a disabled robot ignores commands
                for name, value in zip(names, command, strict=True):
                    if not name.startswith(side + "_") or name[len(side) + 1 :] not in _JOINTS:
                        continue
                    if math.isfinite(value):
                        arm.target[_JOINTS.index(name[len(side) + 1 :])] = value
                arm.last_command = now

        return cb

    def _on_ratio(self, side: str):
        def cb(sample) -> None:
            try:
                v = float(parse_scalar(self._payload(sample), "<d"))
            except WireError:
                self.malformed += 1
                return
            if math.isfinite(v):
                with self._lock:
                    self.arms[side].speed_ratio = min(max(v, 0.0), 1.0)

        return cb

    def _on_timeout(self, side: str):
        def cb(sample) -> None:
            try:
                v = float(parse_scalar(self._payload(sample), "<d"))
            except WireError:
                self.malformed += 1
                return
            if math.isfinite(v) and v > 0:
                with self._lock:
                    self.arms[side].timeout_s = v

        return cb

    def _on_enable(self, sample) -> None:
        try:
            v = bool(parse_scalar(self._payload(sample), "<B"))
        except WireError:
            self.malformed += 1
            return
        with self._lock:
            if v and (self.stopped or self.error):
                return  # an e-stopped robot must be reset first
            if v and not self.enabled:
                for arm in self.arms.values():  # enabling holds where the arm is
                    arm.target = arm.q.copy()
                    arm.last_command = -math.inf
            self.enabled = v

    def _on_super_stop(self, sample) -> None:
        if len(self._payload(sample)) != 0:
            self.malformed += 1
            return
        with self._lock:
            self._estop(button=2, source=2)  # software stop: asserted by a non-user source

    def _on_reset(self, sample) -> None:
        if len(self._payload(sample)) != 0:
            self.malformed += 1
            return
        with self._lock:
            if self.button == 1:
                return  # the red button is still pressed: a reset cannot clear it
            self.stopped = self.error = self.enabled = False
            self.button = self.source = 0

    # --- faults and inspection (tests, CLI)
    def _estop(self, button: int, source: int) -> None:
        self.stopped, self.enabled = True, False
        self.button, self.source = button, source

    def press_estop(self) -> None:
        """The red button: stopped, disabled, button PRESSED, source USER."""
        with self._lock:
            self._estop(button=1, source=1)

    def release_estop(self) -> None:
        with self._lock:
            if self.button == 1:
                self.button = 3  # RELEASED: still stopped until a reset

    def disable(self) -> None:
        with self._lock:
            self.enabled = False

    def positions(self, side: str) -> np.ndarray:
        with self._lock:
            return self.arms[side].q.copy()

    def commands(self, side: str) -> list[tuple[float, int, tuple[str, ...], tuple[float, ...]]]:
        with self._lock:
            return list(self.arms[side].commands)

    def speed_ratio(self, side: str) -> float:
        with self._lock:
            return self.arms[side].speed_ratio

    def command_timeout(self, side: str) -> float:
        with self._lock:
            return self.arms[side].timeout_s

    def holding(self, side: str) -> bool:
        """True once `side`'s arm holds (disabled, or no command within its timeout): from
        then on it does not move until a new command comes."""
        with self._lock:
            arm = self.arms[side]
            return not (self.enabled and time.monotonic() - arm.last_command <= arm.timeout_s)

    def teleport(self, side: str, q: np.ndarray) -> None:
        """Put `side`'s arm at `q` at once, holding (a simulated reset, e.g. after placing an
        object in the twin; never what a robot does). The body is not told."""
        with self._lock:
            arm = self.arms[side]
            arm.q = np.clip(np.asarray(q, dtype=np.float64), _LOWER, _UPPER)
            arm.target = arm.q.copy()
            arm.velocity = np.zeros(7)
            arm.last_command = -math.inf

    # --- the control loop
    def _step(self, dt: float, now: float) -> None:
        for side, arm in self.arms.items():
            fresh = now - arm.last_command <= arm.timeout_s
            if not (self.enabled and fresh):
                arm.target = arm.q.copy()  # timeout / disabled: hold where it is
                arm.velocity = np.zeros(7)
                continue
            vmax = _VEL * arm.speed_ratio
            if self.faults.lag_joint.startswith(side + "_"):
                j = _JOINTS.index(self.faults.lag_joint[len(side) + 1 :])
                vmax = vmax.copy()
                vmax[j] *= self.faults.lag_speed_factor
            goal = np.clip(arm.target, _LOWER, _UPPER)
            v = np.clip((goal - arm.q) / self.s.lag_tau_s, -vmax, vmax)
            q = np.clip(arm.q + v * dt, _LOWER, _UPPER)
            if self.body is not None and np.any(q != arm.q):
                # The body may stop short (a contact): the arm is where the body got.
                got = np.asarray(self.body.follow(side, arm.q.copy(), q.copy()))
                q = np.clip(got, _LOWER, _UPPER)
                v = (q - arm.q) / dt
            arm.q = q
            arm.velocity = v

    def _snapshot(self, now: float) -> tuple[bytes, bytes]:
        names: list[str] = []
        pos: list[float] = []
        vel: list[float] = []
        for side, arm in self.arms.items():
            names += [f"{side}_{j}" for j in _JOINTS]
            pos += list(arm.q)
            vel += list(arm.velocity)
        names += list(_EXTRA)
        pos += [0.0] * len(_EXTRA)
        vel += [0.0] * len(_EXTRA)
        self._seq += 1
        js = pack_joint_state(self._seq, time.time(), names, pos, vel, np.zeros(len(names)))
        ready = self.enabled and not self.stopped
        st = pack_assembly_state(
            ready, self.enabled, self.stopped, self.error, self.button, self.source
        )
        return js, st

    def _run(self) -> None:
        period = 1.0 / self.s.rate_hz
        last = time.monotonic()
        tick = 0
        while not self._stop.is_set():
            tick += 1
            # absolute schedule: the rate does not drift with the work done per tick
            delay = last + tick * period - time.monotonic() if tick > 1 else period
            if self._stop.wait(max(delay, 0.0)):
                break
            now = time.monotonic()
            with self._lock:
                self._step(period, now)
                js, st = self._snapshot(now)
                faults = Faults(**vars(self.faults))
            self._history.append((now, js))
            try:
                if faults.state_delay_s > 0:
                    old = [b for t, b in self._history if t <= now - faults.state_delay_s]
                    js = old[-1] if old else b""
                if not faults.drop_states and js:
                    self._pub_js.put(js)
                self._pub_state.put(st)
            except Exception:  # session closing under us
                log.debug("emulator publish failed", exc_info=True)
                break

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        for obj in (*self._subs, self._pub_js, self._pub_state):
            try:
                obj.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self._subs = []

    def __enter__(self) -> BaxterEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def main(argv: list[str] | None = None) -> int:
    # deferred: loads zenoh
    from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings

    p = argparse.ArgumentParser(prog="python -m activetouch.emulators.baxter_bridge")
    p.add_argument("--listen", action="append", default=[], help="Zenoh endpoint to listen on")
    p.add_argument("--connect", action="append", default=[], help="Zenoh endpoint to connect to")
    p.add_argument("--namespace", default="*", help="bridge namespace chunk (bridge default *)")
    p.add_argument("--legacy", action="store_true", help="keys without the namespace chunk")
    p.add_argument("--enabled", action="store_true", help="start enabled")
    p.add_argument("--rate-hz", type=float, default=100.0)
    p.add_argument("--lag-joint", default="", help="fault: this joint moves very slowly")
    p.add_argument("--drop-states", action="store_true", help="fault: publish no joint states")
    p.add_argument("--state-delay-s", type=float, default=0.0, help="fault: stale joint states")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    listen = tuple(a.listen) or (() if a.connect else ("tcp/127.0.0.1:7448",))
    settings = ZenohSettings(listen=listen, connect=tuple(a.connect))
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    es = EmulatorSettings(namespace=a.namespace, legacy=a.legacy, rate_hz=a.rate_hz)
    es.enabled = a.enabled
    with ZenohSession(settings) as zs, BaxterEmulator(zs.session, es) as emu:
        emu.faults = Faults(
            drop_states=a.drop_states, state_delay_s=a.state_delay_s, lag_joint=a.lag_joint
        )
        log.info("Baxter emulator on %s (namespace %r, legacy %s)", listen, a.namespace, a.legacy)
        print("ready", flush=True)
        done.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
