"""ReFlex SF over USB serial (``hand.type = "reflex-sf"``): four Dynamixel MX-28 servos,
Protocol 1.0, through dynamixel-sdk (ids 1-3 fingers, 4 preshape).

The SF has no tactile sensors and no proximal encoders. Contact is a finger stalling under
load: during the guarded close a finger whose load passes `contact_load` stops there and is
reported as one contact at its distal link's sensor site `contact_site` from the kinematics
(free-finger coupling: proximal = spool / (1 + k), distal = k * proximal). Three fingers give
at most three contacts: one triangle per grasp, which the triangle descriptor still uses.

Servo conventions are reflex-ros-pkg's (``reflex_sf.yaml``, ``reflex_usb_motor.py``), so a
lab's ``reflex_sf_motor_zero_points.yaml`` can be used as it is: the servos are multi-turn (raw
0..28672, 2π/4096 rad per tick); each has a zero point in *motor* radians (the hand open,
`hand.motor_zero_points`) and an inversion by servo id ([+1, -1, +1, -1]: f2 and the preshape
turn the other way); joint = inversion * (motor - zero) / gear; goals are bounded to the joint's
travel from its zero (3.75 rad fingers, 1.75 preshape). Load is negated for non-inverted
servos and smoothed (EMA 0.25), and an overloaded servo is loosened on every reading, holding
included, as upstream does.

Connecting moves nothing: it reads the servos, refuses readings that cannot be true (a servo
that reads far outside its travel from its zero point, an alarm bit, over-temperature) with an
error naming the servo, and sets the servos' speed; torque comes on with the first motion
command, after a hold goal at the position read. A poll thread reads position, load, voltage
and temperature of every servo at `control_hz`; commands share the bus lock with it. `stop()`
writes hold goals at once (between two transactions) and a running close raises at its next
step; servos that stop answering for `stream_timeout_s` make the hand stale; an implausible
reading while running turns the torque off and fails every further command with its reason.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from activetouch import paths
from activetouch.calibration import store
from activetouch.device_types import HandConfig
from activetouch.drivers.reflex import kinematics
from activetouch.drivers.reflex.common import (
    CloseStep,
    RateLimitedWarning,
    ReflexHandState,
    ServoFaultError,
    StallDetector,
    StreamLostError,
    close_step,
)
from activetouch.drivers.reflex.kinematics import MX28_SCALE
from activetouch.errors import ConfigError, StoppedError
from activetouch.interfaces import (
    N_FINGERS,
    N_SENSORS,
    SENSORS_PER_FINGER,
    Grasp,
    Hand,
    StopLatch,
)
from activetouch.models.reflex import DEFAULT_GEOMETRY, sensor_positions

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext

log = logging.getLogger(__name__)

# MX-28, Protocol 1.0 control table.
ADDR_TORQUE_ENABLE = 24
ADDR_GOAL_POSITION = 30
ADDR_MOVING_SPEED = 32
ADDR_PRESENT_POSITION = 36  # then speed (38), load (40), 2 bytes each; voltage 42, temperature 43
RAW_MAX = 28672  # the SF's multi-turn range (reflex_sf.yaml motor `max`)
# Status-packet error bits that mean the servo is not fit to move (Protocol 1.0): input
# voltage, angle limit, overheating, range, overload (checksum and instruction bits are ours).
ALARM_BITS = {0x01: "input voltage", 0x02: "angle limit", 0x04: "overheating", 0x08: "range",
              0x20: "overload"}  # fmt: skip
SPEED_UNIT_RAD_S = 0.114 * 2 * 3.141592653589793 / 60  # moving speed register: 0.114 rpm/unit
STANDARD_BAUDS = (
    9600,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    500000,
    576000,
    921600,
    1000000,
)


# Motor radians with the hand open: reflex-ros-pkg's public reflex_sf_motor_zero_points.yaml.
DEFAULT_ZERO_POINTS = [25.21, 26.17, 23.58, 23.46]


@dataclass
class ReflexSFConfig(HandConfig):
    """Settings of a ReFlex SF (docs/protocols/reflex.md)."""

    # The SF's servos run at 57142 bps (register value 34); a USB adapter opened at 57600 is
    # within UART tolerance of it, and dynamixel-sdk opens only standard rates.
    port: str = "/dev/ttyUSB0"
    baud: int = 57600
    motor_ids: list[int] = field(default_factory=lambda: [1, 2, 3, 4])
    gear_ratio: list[float] = field(default_factory=lambda: [1.42, 1.42, 1.42, 1.5])
    # By servo id, upstream's motor_to_joint_inverted False/True/False/True.
    motor_inverted: list[int] = field(default_factory=lambda: [1, -1, 1, -1])
    # Motor radians with the hand open, as upstream stores them (reflex_sf_motor_zero_points.yaml;
    # these are its public values): replace them with your hand's, or `calibrate fingers`.
    motor_zero_points: list[float] = field(default_factory=lambda: list(DEFAULT_ZERO_POINTS))
    motor_zero_rad: list[float] | None = None  # gone (it was joint-side): check() says so
    motor_travel_rad: list[float] = field(default_factory=lambda: [3.75, 3.75, 3.75, 1.75])
    # Use the zero points stored by `calibrate fingers` / `calibrate import` (per device name
    # `serial`, else the type) unless hand.motor_zero_points is set to other than the default.
    load_calibration: bool = True
    serial: str = ""
    # A reading further than this (joint rad) outside [0, travel] cannot be the hand's.
    plausible_margin_rad: float = 0.5
    max_temperature_c: int = 70
    load_filter: float = 0.25  # EMA weight of a new load reading (upstream 0.25)
    # Load (fraction of the maximum) at which a closing finger counts as in contact; the
    # preshape's entry is its overload threshold.
    contact_load: list[float] = field(default_factory=lambda: [0.25, 0.25, 0.25, 0.55])
    contact_site: int = 6  # sensor index (5..8, on the distal link) reported as the contact
    flexure_coupling: float = 0.25  # free finger: distal = k * proximal (as the twin)
    # Raw MX-28 speed units (0.114 rpm each): 377 is upstream's default_motor_speed 4.5 rad/s.
    moving_speed: int = 377
    control_hz: float = 40.0
    stream_timeout_s: float = 0.2
    # At connect: how long the servos may take to answer a first read (a bus that drops a
    # reply, a USB adapter still settling); one register write is tried this many times.
    connect_timeout_s: float = 1.0
    write_tries: int = 3
    spool_step_rad: float = 0.05
    spool_limit_rad: float = 3.5
    preshape_limit_rad: float = 1.6
    backoff_rad: float = 0.05
    stall_steps: int = 15
    stall_tolerance_rad: float = 0.01
    close_timeout_s: float = 15.0
    arrival_tolerance_rad: float = 0.05
    move_timeout_s: float = 3.0
    warn_interval_s: float = 5.0

    def check(self) -> None:
        if self.motor_zero_rad is not None:
            raise ConfigError(
                "hand.motor_zero_rad is gone: it was joint-side; set hand.motor_zero_points, the "
                "servos' positions with the hand open in motor radians (upstream's zero_point in "
                "reflex_sf_motor_zero_points.yaml), or run `activetouch calibrate fingers`"
            )
        for name, n in (
            ("motor_ids", 4),
            ("gear_ratio", 4),
            ("motor_inverted", 4),
            ("motor_zero_points", 4),
            ("motor_travel_rad", 4),
            ("contact_load", 4),
        ):
            if len(getattr(self, name)) != n:
                raise ConfigError(f"hand.{name}: expected {n} values")
        if any(not 0 <= i <= 252 for i in self.motor_ids) or len(set(self.motor_ids)) != 4:
            raise ConfigError("hand.motor_ids: four distinct ids in 0..252")
        if any(v not in (1, -1) for v in self.motor_inverted):
            raise ConfigError("hand.motor_inverted: each value must be 1 or -1")
        if self.baud not in STANDARD_BAUDS:
            raise ConfigError(f"hand.baud: {self.baud} is not a rate dynamixel-sdk can open")
        if not 5 <= self.contact_site <= 8:
            raise ConfigError("hand.contact_site: a distal sensor index, 5..8")
        if any(not 0 < v <= 1 for v in self.contact_load):
            raise ConfigError("hand.contact_load: fractions in (0, 1]")
        for k, (z, g, t, s) in enumerate(
            zip(self.motor_zero_points, self.gear_ratio, self.motor_travel_rad,
                self.motor_inverted, strict=True)
        ):  # fmt: skip
            far = z + s * t * g
            if not (0 <= z / MX28_SCALE <= RAW_MAX and 0 <= far / MX28_SCALE <= RAW_MAX):
                raise ConfigError(
                    f"hand.motor_zero_points[{k}] = {z} rad: the finger's travel from there "
                    f"leaves the servo's range 0..{RAW_MAX} ticks (motor radians, upstream's "
                    "zero_point; not joint radians)"
                )
        if not 0 < self.load_filter <= 1:
            raise ConfigError("hand.load_filter: a weight in (0, 1]")
        for name in (
            "control_hz",
            "stream_timeout_s",
            "connect_timeout_s",
            "spool_step_rad",
            "close_timeout_s",
        ):
            if not getattr(self, name) > 0:
                raise ConfigError(f"hand.{name}: must be > 0")

    def make(self, ctx: DeviceContext) -> Hand:
        self.check()
        cfg = self
        if self.load_calibration:
            cfg = with_stored_zero_points(self, ctx.data)
        return ReflexSFHand(cfg)


def with_stored_zero_points(cfg: ReflexSFConfig, data: object) -> ReflexSFConfig:
    """`cfg` with the stored finger calibration's zero points, when there is one and the
    configuration did not set its own (a setting given explicitly wins, and says so)."""

    device = cfg.serial or cfg.type
    rec = store.load(paths.data_dir(data), "fingers", device)  # type: ignore[arg-type]
    if rec is None or "motor_zero_points" not in rec.values:
        log.warning(
            "ReFlex SF: no finger calibration stored for %s: using hand.motor_zero_points %s "
            "(`activetouch calibrate fingers` or `calibrate import` makes one)",
            device,
            cfg.motor_zero_points,
        )
        return cfg
    stored = [float(v) for v in rec.values["motor_zero_points"]]
    if list(cfg.motor_zero_points) != DEFAULT_ZERO_POINTS:
        log.warning(
            "ReFlex SF: hand.motor_zero_points is set (%s): the stored calibration (%s) is not "
            "used",
            cfg.motor_zero_points,
            stored,
        )
        return cfg
    log.info("ReFlex SF: zero points %s from the calibration of %s", stored, rec.measured_at)
    return dataclasses.replace(cfg, motor_zero_points=stored)


def joint_angles(
    raw: np.ndarray, zero: np.ndarray, gear: np.ndarray, inv: np.ndarray
) -> np.ndarray:
    """Joint-side angles of raw positions: inversion * (motor rad - zero point) / gear."""
    return inv * (np.asarray(raw, dtype=np.float64) * MX28_SCALE - zero) / gear


def raw_goals(joint: np.ndarray, zero: np.ndarray, gear: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """Raw goal positions for joint-side angles (the inverse of `joint_angles`)."""
    motor = zero + inv * np.asarray(joint, dtype=np.float64) * gear
    return np.rint(motor / MX28_SCALE).astype(np.int64)


def upstream_load(raw: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """One load reading as reflex-ros-pkg sees it: (raw & 0x3FF) / 1024, negative when bit 10
    is set (dynamixel_io), then negated for non-inverted servos (`_handle_motor_load`). Both
    kinds of servo then read negative while they tighten against something."""
    raw = np.asarray(raw, dtype=np.int64)
    dxl = (raw & 0x3FF) / 1024.0 * np.where(raw & 0x400, -1.0, 1.0)
    return np.where(np.asarray(inv) > 0, -dxl, dxl)


def implausible(
    cfg: ReflexSFConfig, servo: int, raw: int, joint: float, temperature: int, error: int
) -> str | None:
    """Why a servo reading cannot be the hand's, with what to check; None if it can."""
    alarms = [name for bit, name in ALARM_BITS.items() if error & bit]
    if alarms:
        return (
            f"ReFlex SF servo {servo} reports {', '.join(alarms)} (status 0x{error:02x}): power "
            "the hand down and check its supply, cabling and that nothing jams the finger"
        )
    if temperature > cfg.max_temperature_c:
        return (
            f"ReFlex SF servo {servo} is at {temperature} °C (limit {cfg.max_temperature_c}): "
            "let it cool; a finger pressing for long heats its servo"
        )
    k = cfg.motor_ids.index(servo)
    travel, m = cfg.motor_travel_rad[k], cfg.plausible_margin_rad
    if not (0 < raw <= RAW_MAX) or not -m <= joint <= travel + m:
        zero = cfg.motor_zero_points[k]
        return (
            f"ReFlex SF servo {servo} reads raw {raw} ({joint:+.2f} rad from its zero point "
            f"{zero} rad, travel 0..{travel}): the servo has not answered properly, or "
            "hand.motor_zero_points is not this hand's (motor radians, reflex-ros-pkg's "
            "zero_point) or a finger slipped a turn; open the hand by hand and run "
            "`activetouch calibrate fingers`"
        )
    return None


@dataclass(frozen=True)
class ServoReading:
    seq: int
    mono: float
    wall: float
    raw_position: np.ndarray  # (4,)
    motor: np.ndarray  # (4,) joint-side spool angles and preshape, rad
    load: np.ndarray  # (4,) filtered load as upstream reports it (negative tightening)

    @property
    def closing_load(self) -> np.ndarray:
        """How hard each servo pulls its tendon against something (fraction of max)."""
        return -self.load


class ReflexSFHand(Hand):
    """`check_travel=False` (finger calibration only): readings are not checked against the
    travel window of zero points that may be wrong; alarms, temperature and unanswered servos
    still are."""

    def __init__(self, cfg: ReflexSFConfig, check_travel: bool = True) -> None:
        self.cfg = cfg
        self.check_travel = check_travel
        self.ids = [int(i) for i in cfg.motor_ids]
        self.gear = np.asarray(cfg.gear_ratio, dtype=np.float64)
        self.inverted = np.asarray(cfg.motor_inverted, dtype=np.float64)
        self.zero = np.asarray(cfg.motor_zero_points, dtype=np.float64)
        self.travel = np.asarray(cfg.motor_travel_rad, dtype=np.float64)
        self._load = np.zeros(4)  # EMA of the upstream-convention load
        self._armed = False  # torque on, after a hold goal (first motion command)
        self._fault: str | None = None
        self._closing = False
        self.stop_latch = StopLatch()
        self.warn = RateLimitedWarning(log, cfg.warn_interval_s)
        self.last_close_reasons: tuple[str, ...] = ()
        self._port: Any = None
        self._ph: Any = None
        self._bus = threading.Lock()
        self._cond = threading.Condition()
        self._latest: ServoReading | None = None
        self._last_ok = 0.0
        self._stale = True
        self._running = False
        self._thread: threading.Thread | None = None
        self._preshape_target: float | None = None

    # -- bus ------------------------------------------------------------------------------

    def connect(self) -> None:
        # deferred: the Dynamixel SDK only for the SF hand
        import dynamixel_sdk as dxl

        if self._port is not None:
            return
        port = dxl.PortHandler(self.cfg.port)
        try:
            ok = port.openPort() and port.setBaudRate(self.cfg.baud)
        except Exception as e:  # pyserial raises SerialException (an OSError) or ValueError
            raise ConfigError(f"hand.port {self.cfg.port}: cannot open ({e})") from None
        if not ok:
            raise ConfigError(f"hand.port {self.cfg.port}: cannot open at {self.cfg.baud} bps")
        self._port, self._ph = port, dxl.PacketHandler(1.0)
        try:
            deadline = time.monotonic() + self.cfg.connect_timeout_s
            r = self._read_all()
            while r is None and time.monotonic() < deadline:
                time.sleep(0.02)
                r = self._read_all()
            if r is None:
                raise StreamLostError(
                    f"ReFlex SF: servos {self.ids} do not answer on {self.cfg.port} within "
                    f"{self.cfg.connect_timeout_s:g} s (power, cabling, hand.baud?)"
                )
            bad = self._check(r)
            if bad is not None:
                raise ServoFaultError(bad)  # nothing has been written
            self._publish(r)
            # The servos' speed, as upstream sets it at start; no goal, no torque: nothing moves.
            for i in self.ids:
                self._write(2, i, ADDR_MOVING_SPEED, self.cfg.moving_speed)
            self._running = True
            self._thread = threading.Thread(target=self._poll, name="reflex-sf", daemon=True)
            self._thread.start()
        except BaseException:
            self.disconnect()
            raise

    def disconnect(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        if self._port is not None and self._armed:
            self._torque_off()  # as upstream leaves the hand: limp, not holding
        if self._port is not None:
            with self._bus:
                self._port.closePort()
            self._port = None
        with self._cond:
            self._stale = True
            self._cond.notify_all()

    @property
    def stale(self) -> bool:
        return self._stale

    def stats(self) -> dict[str, int]:
        return dict(self.warn.counts)

    def _write(self, size: int, dxl_id: int, addr: int, value: int) -> None:
        fn = self._ph.write1ByteTxRx if size == 1 else self._ph.write2ByteTxRx
        # Register writes are idempotent: a reply lost on the bus is worth another try.
        for _ in range(max(1, self.cfg.write_tries)):
            with self._bus:
                res, _err = fn(self._port, dxl_id, addr, int(value))
            if res == 0:
                break
        if res != 0:
            self.warn("write_failed", f"ReFlex SF: write to servo {dxl_id} failed ({res})")
            with self._cond:  # a servo that does not answer is a lost stream
                self._stale = True
                self._cond.notify_all()
            raise StreamLostError(f"ReFlex SF: servo {dxl_id} did not take a write ({res})")

    def _read_all(self) -> tuple[np.ndarray, ...] | None:
        """(raw positions, raw loads, temperatures, status errors) of the 4 servos, or None if
        one does not answer."""
        pos, load = np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int64)
        temp, err = np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int64)
        for k, i in enumerate(self.ids):
            with self._bus:
                data, res, e = self._ph.readTxRx(self._port, i, ADDR_PRESENT_POSITION, 8)
            if res != 0 or len(data) != 8:
                self.warn("read_failed", f"ReFlex SF: servo {i} did not answer a read ({res})")
                return None
            pos[k] = data[0] | data[1] << 8
            load[k] = data[4] | data[5] << 8
            temp[k], err[k] = data[7], int(e)
        return pos, load, temp, err

    def _check(self, r: tuple[np.ndarray, ...]) -> str | None:
        joint = joint_angles(r[0], self.zero, self.gear, self.inverted)
        if not self.check_travel:
            joint = np.zeros(4)  # calibrating: the zero points are what is being found
        for k, i in enumerate(self.ids):
            bad = implausible(
                self.cfg, i, int(r[0][k]), float(joint[k]), int(r[2][k]), int(r[3][k])
            )
            if bad is not None:
                return bad
        return None

    def _torque_off(self) -> None:
        for i in self.ids:
            with contextlib.suppress(StreamLostError, OSError):
                self._write(1, i, ADDR_TORQUE_ENABLE, 0)
        self._armed = False

    def _fail(self, reason: str) -> None:
        """An implausible reading while running: torque off, and every command refused."""
        log.error("%s; torque off", reason)
        self._fault = reason
        self._torque_off()
        with self._cond:
            self._stale = True
            self._cond.notify_all()

    def _arm(self, r: ServoReading) -> None:
        """Torque on for the first motion, after a hold goal at the (checked) position read."""
        if self._armed:
            return
        self._write_goals(r.raw_position, motion=False)
        for i in self.ids:
            self._write(1, i, ADDR_TORQUE_ENABLE, 1)
        self._armed = True

    def _publish(self, r: tuple[np.ndarray, ...]) -> None:
        now = time.monotonic()
        a = self.cfg.load_filter
        first = self._latest is None
        new = upstream_load(r[1], self.inverted)
        self._load = new if first else a * new + (1 - a) * self._load
        with self._cond:
            seq = self._latest.seq + 1 if self._latest is not None else 0
            self._latest = ServoReading(
                seq,
                now,
                time.time(),
                r[0],
                joint_angles(r[0], self.zero, self.gear, self.inverted),
                self._load.copy(),
            )
            self._last_ok, self._stale = now, False
            self._cond.notify_all()

    def _loosen_if_overloaded(self, r: ServoReading) -> None:
        """Upstream's overload rule, on every reading: a servo loaded past its threshold is
        loosened 0.05 motor rad. During a guarded close the close itself stops that finger."""
        if not self._armed or self._closing:
            return
        over = np.abs(r.load) > np.asarray(self.cfg.contact_load)
        if not over.any():
            return
        raw = r.raw_position.copy()
        for k in np.flatnonzero(over).tolist():
            log.warning("ReFlex SF: servo %d overloaded at %.2f, loosening", self.ids[k], r.load[k])
            raw[k] -= round(float(self.inverted[k]) * 0.05 / MX28_SCALE)
        with contextlib.suppress(StreamLostError, ValueError):
            self._write_goals(raw, motion=False)

    def _poll(self) -> None:
        period = 1.0 / self.cfg.control_hz
        next_t = time.monotonic()
        while self._running:
            try:
                r = self._read_all()
            except Exception:  # a broken port must not kill the thread silently
                log.exception("ReFlex SF: read failed")
                r = None
            if r is not None and self._fault is None:
                bad = self._check(r)
                if bad is not None:
                    self._fail(bad)
                else:
                    self._publish(r)
                    if self._latest is not None:
                        self._loosen_if_overloaded(self._latest)
            elif (
                r is None
                and not self._stale
                and time.monotonic() - self._last_ok > self.cfg.stream_timeout_s
            ):
                self._lost()
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))

    def _lost(self) -> None:
        """Mark the hand stale (once per loss) and command the servos to hold."""
        with self._cond:
            if self._stale:
                return
            self._stale = True
            self._cond.notify_all()
        self.warn("stream_lost", "ReFlex SF: servos stopped answering; holding")
        latest = self._latest
        if latest is not None and self._armed:
            with contextlib.suppress(StreamLostError, OSError):
                self._write_goals(latest.raw_position, motion=False)

    def _write_goals(self, raw: np.ndarray, motion: bool = True) -> None:
        """Goal positions of all four servos in one SYNC_WRITE; motion writes are refused once
        stopped (checked under the bus lock `stop()` also takes)."""
        # deferred: the Dynamixel SDK only for the SF hand
        import dynamixel_sdk as dxl

        raw = np.asarray(raw, dtype=np.int64)
        for i, v in zip(self.ids, raw.tolist(), strict=True):
            if not 0 <= v <= RAW_MAX:  # never clamp: a clamped goal is a turn or more away
                raise ValueError(f"ReFlex SF: goal {v} for servo {i} is outside 0..{RAW_MAX}")
        sw = dxl.GroupSyncWrite(self._port, self._ph, ADDR_GOAL_POSITION, 2)
        for i, v in zip(self.ids, raw.tolist(), strict=True):
            sw.addParam(i, [int(v) & 0xFF, int(v) >> 8])
        with self._bus:
            if motion:
                self.stop_latch.check("ReFlex SF command")
            res = sw.txPacket()
        if res != 0:
            raise StreamLostError(f"ReFlex SF: goal write failed ({res})")

    def _goals(self, angles: np.ndarray) -> np.ndarray:
        """Raw goals for joint-side angles, checked against each joint's travel from its zero
        (refused beyond it by more than the margin, bounded to it otherwise, as upstream)."""
        a = np.asarray(angles, dtype=np.float64)
        m = self.cfg.plausible_margin_rad
        for k, i in enumerate(self.ids):
            if not (np.isfinite(a[k]) and -m <= a[k] <= self.travel[k] + m):
                raise ValueError(
                    f"ReFlex SF: goal {a[k]:.2f} rad for servo {i} is outside its travel "
                    f"0..{self.travel[k]} rad"
                )
        return raw_goals(np.clip(a, 0.0, self.travel), self.zero, self.gear, self.inverted)

    def _wait(self, after_seq: int, check_stop: bool = True) -> ServoReading:
        deadline = time.monotonic() + self.cfg.stream_timeout_s
        if self._fault is not None:
            raise ServoFaultError(self._fault)
        with self._cond:
            while True:
                if self._fault is not None:
                    raise ServoFaultError(self._fault)
                if check_stop and self.stop_latch.is_set:
                    raise StoppedError("ReFlex SF: stopped")
                r = self._latest
                if r is not None and r.seq > after_seq and not self._stale:
                    return r
                left = deadline - time.monotonic()
                if left <= 0 or self._stale or not self._running:
                    if left <= 0 and self._running:
                        self._cond.release()  # _lost takes the bus lock: not under _cond
                        try:
                            self._lost()
                        finally:
                            self._cond.acquire()
                    raise StreamLostError(
                        f"ReFlex SF: no servo reading within {self.cfg.stream_timeout_s} s"
                    )
                self._cond.wait(min(left, 0.05))

    # -- Hand interface -------------------------------------------------------------------

    # -- finger calibration (activetouch.calibration.sf_fingers) --------------------------

    def motor_positions(self) -> np.ndarray:
        """The servos' present positions in motor radians (upstream's zero_point units)."""
        r = self._wait(-1, check_stop=False)
        return r.raw_position.astype(np.float64) * MX28_SCALE

    def jog(self, servo: int, delta_motor_rad: float) -> np.ndarray:
        """Turn servo `servo` (index 0-3) by `delta_motor_rad` from where it is (positive
        tightens its tendon), one small step at a time; returns the new motor positions.
        Steps are bounded: a calibration jog never moves a servo more than 0.5 rad at once."""
        if not (np.isfinite(delta_motor_rad) and abs(delta_motor_rad) <= 0.5):
            raise ValueError(f"ReFlex SF: a jog of {delta_motor_rad} rad is not a small step")
        r = self._wait(-1)
        self._arm(r)
        raw = r.raw_position.copy()
        raw[servo] += round(float(self.inverted[servo]) * delta_motor_rad / MX28_SCALE)
        self._write_goals(raw)
        deadline = time.monotonic() + self.cfg.move_timeout_s
        while time.monotonic() < deadline:
            r = self._wait(r.seq)
            if abs(int(r.raw_position[servo]) - int(raw[servo])) <= 8:
                break
        return r.raw_position.astype(np.float64) * MX28_SCALE

    def set_motor_zero_points(self, zero_points: np.ndarray) -> None:
        """Use these zero points (motor radians, per servo) from now on."""
        z = np.asarray(zero_points, dtype=np.float64)
        if z.shape != (4,) or not np.all((z > 0) & (z <= RAW_MAX * MX28_SCALE)):
            raise ValueError(f"ReFlex SF: zero points {z.tolist()} are not 4 servo positions")
        self.zero = z

    def stop(self) -> None:
        self.stop_latch.set()
        r = self._latest
        if r is not None and self._port is not None and self._armed:
            try:
                self._write_goals(r.raw_position, motion=False)
            except StreamLostError:
                log.warning("ReFlex SF: could not write the hold on stop")
        with self._cond:
            self._cond.notify_all()

    def clear_stop(self) -> None:
        self.stop_latch.clear()

    def _joints(self, spool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        prox = np.maximum(spool, 0.0) / (1.0 + self.cfg.flexure_coupling)
        return prox, kinematics.distal_approx(spool, prox)

    def state(self) -> ReflexHandState:
        r = self._latest
        z = np.zeros(N_SENSORS)
        if r is None:
            return ReflexHandState(
                pressures=z,
                contact=z.astype(bool),
                finger_angles=np.zeros(3),
                preshape=0.0,
                stamp=0.0,
                stale=True,
            )
        prox, dist = self._joints(r.motor[:N_FINGERS])
        return ReflexHandState(
            pressures=z,
            contact=z.astype(bool),
            finger_angles=prox,
            preshape=float(r.motor[3]),
            stamp=r.mono,
            stale=self._stale,
            distal=dist,
            motor=r.motor.copy(),
            load=r.load.copy(),
            wall_stamp=r.wall,
        )

    def open(self) -> None:
        r = self._wait(-1, check_stop=False)
        self._arm(r)
        target = np.zeros(4)
        target[3] = self._preshape_target if self._preshape_target is not None else r.motor[3]
        self._write_goals(self._goals(target), motion=False)
        self._arrive(target, range(N_FINGERS), "open", check_stop=False)

    def preshape(self, angle: float) -> None:
        self.stop_latch.check("preshape")
        a = float(angle)
        if not 0.0 <= a <= self.cfg.preshape_limit_rad:
            raise ValueError(f"preshape {a} rad is outside 0..{self.cfg.preshape_limit_rad}")
        r = self._wait(-1)
        self._arm(r)
        target = np.clip(r.motor.copy(), 0.0, self.travel)
        target[3] = a
        self._preshape_target = a
        self._write_goals(self._goals(target))
        self._arrive(target, [3], "preshape", check_stop=True)

    def _arrive(self, target: np.ndarray, motors, what: str, check_stop: bool) -> None:
        deadline, seq, idx = time.monotonic() + self.cfg.move_timeout_s, -1, list(motors)
        while time.monotonic() < deadline:
            r = self._wait(seq, check_stop=check_stop)
            seq = r.seq
            if np.all(np.abs(r.motor[idx] - target[idx]) <= self.cfg.arrival_tolerance_rad):
                return
        log.warning("ReFlex SF: %s did not arrive within %.1f s", what, self.cfg.move_timeout_s)

    def guarded_close(self) -> Grasp:
        cfg = self.cfg
        self.stop_latch.check("guarded close")
        r = self._wait(-1)
        self._arm(r)
        preshape = r.motor[3] if self._preshape_target is None else self._preshape_target
        preshape = float(np.clip(preshape, 0.0, self.travel[3]))
        step = CloseStep(r.motor[:N_FINGERS].copy(), np.ones(N_FINGERS, bool), ("",) * N_FINGERS)
        stall = StallDetector(cfg.stall_steps, cfg.stall_tolerance_rad)
        contact_load = np.asarray(cfg.contact_load[:N_FINGERS])
        deadline = time.monotonic() + cfg.close_timeout_s
        self._closing = True
        try:
            return self._close(r, step, stall, contact_load, preshape, deadline)
        finally:
            self._closing = False

    def _close(
        self,
        r: ServoReading,
        step: CloseStep,
        stall: StallDetector,
        contact_load: np.ndarray,
        preshape: float,
        deadline: float,
    ) -> Grasp:
        cfg = self.cfg
        while step.active.any():
            if time.monotonic() > deadline:
                self._write_goals(r.raw_position)
                raise TimeoutError(f"ReFlex SF: guarded close took over {cfg.close_timeout_s} s")
            # Pulling the tendon against something is contact.
            touching = r.closing_load[:N_FINGERS] >= contact_load
            step = close_step(
                r.motor,
                step.target,
                step.active,
                step.reasons,
                touching,
                np.zeros(N_FINGERS, bool),
                stall(r.motor),
                cfg.spool_step_rad,
                cfg.spool_limit_rad,
                cfg.backoff_rad,
            )
            self._write_goals(self._goals(np.append(step.target, preshape)))
            r = self._wait(r.seq)
        self.last_close_reasons = step.reasons
        r = self._wait(r.seq)
        touched = [f for f in range(N_FINGERS) if step.reasons[f] == "contact"]
        prox, dist = self._joints(r.motor[:N_FINGERS])
        ids = np.array([f * SENSORS_PER_FINGER + cfg.contact_site for f in touched], dtype=int)
        sites = sensor_positions(DEFAULT_GEOMETRY, float(r.motor[3]), prox, dist)
        return Grasp(
            sensor_ids=ids,
            xyz=sites[ids].reshape(-1, 3),
            pressures=np.abs(r.load[touched]) * 1024.0,  # load units stand in for pressure
            finger_angles=prox,
            preshape=float(r.motor[3]),
        )
