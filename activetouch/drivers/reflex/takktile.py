"""ReFlex TakkTile / Beta hand over UDP (``hand.type = "reflex-takktile"``).

A receive thread decodes every state packet (40 Hz) into a reading; commands go out as
datagrams from the same socket. The guarded close runs one control step per state packet:
each finger's spool advances `spool_step_rad` until that finger's own pads report contact,
it reaches its travel limit, stalls, or is overloaded (backs off), each finger on its own.

Safety: `stop()` commands every motor to hold at its measured position at once and wakes a
waiting close, which raises `StoppedError` without sending anything more; no state packet
for `stream_timeout_s` marks the hand stale, commands the motors to hold and makes every
waiting command raise `StreamLostError` (nothing waits longer than that).

The calibration records it is handed: `takktile_calibration`. First power-on (issue 23):
connecting moves nothing (goals at the measured positions, then upstream's VELOCITY ->
speeds -> POSITION, once; again only after a board restart); a reading
that cannot be true (a servo at 0, outside the window, an alarm, too hot) stops the hand with
an error naming the servo and is never used for a hold; IDLE at disconnect. Without a tactile
calibration (handed in by `make()`) the hand reports no contacts and refuses to grasp.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from activetouch.calibration.tactile import (
    TactileSettings,
    fit_tactile,
    flags_by_sensor,
    rec_flags,
)
from activetouch.device_types import HandConfig
from activetouch.drivers.reflex import codec, kinematics
from activetouch.drivers.reflex.common import (
    CloseStep,
    RateLimitedWarning,
    ReflexHandState,
    ServoFaultError,
    StallDetector,
    StreamLostError,
    close_step,
    parse_address,
)
from activetouch.drivers.reflex.takktile_calibration import (
    DEFAULT_MOTOR_ZERO_POINTS,
    FingerZero,
    TactileZero,
    stored_calibration,
)
from activetouch.drivers.reflex.udp import open_socket
from activetouch.errors import ActiveTouchError, ConfigError, StoppedError
from activetouch.interfaces import N_FINGERS, N_SENSORS, SENSORS_PER_FINGER, Grasp, Hand, StopLatch
from activetouch.models.reflex import DEFAULT_GEOMETRY, sensor_positions

if TYPE_CHECKING:
    import socket

    from activetouch.devices import DeviceContext


log = logging.getLogger(__name__)


CALIBRATE_TACTILE = "activetouch calibrate tactile"


class TactileCalibrationError(ActiveTouchError):
    """The hand has no valid tactile calibration: a grasp would report contact everywhere."""


@dataclass
class ReflexTakktileConfig(HandConfig):
    """Settings of a ReFlex TakkTile hand (docs/protocols/reflex.md says what each means)."""

    # Where the driver receives state packets. The wildcard (or the group) joins the multicast
    # group; a unicast address (127.0.0.1 in tests) never joins.
    state_listen: str = "0.0.0.0:11333"
    # Where command packets go: the board takes commands only on its multicast group.
    command_to: str = "224.0.0.124:11333"
    multicast_group: str = "224.0.0.124"  # empty: unicast only
    interface: str = ""  # name (eth0) or IPv4 address of the hand's interface; empty: default
    stream_timeout_s: float = 0.2  # no state packet for this long: stale, motors told to hold
    connect_timeout_s: float = 2.0  # a first plausible packet must arrive within this
    # Tactile calibration: pressure = raw - offset, contact = pressure > threshold. The stored
    # calibration (`activetouch calibrate tactile`) replaces these; empty zero_offsets and no
    # stored record: the hand is uncalibrated (unloaded sensors read 56-306 counts, far above
    # the threshold), reports no contacts and refuses to grasp.
    contact_threshold: float = 20.0
    zero_offsets: list[float] = field(default_factory=list)
    thresholds: list[float] = field(default_factory=list)
    # Without a stored tactile calibration: zero the pads at connect (the hand must be open
    # and untouched then).
    zero_on_connect: bool = False
    zero_samples: int = 40  # packets averaged by zero_on_connect (1 s at 40 Hz)
    open_tolerance_rad: float = 0.15  # "open": every proximal within this of 0
    # Servo and encoder conversion (motor order: finger 0, 1, 2, preshape).
    gear_ratio: list[float] = field(default_factory=lambda: [1.42, 1.42, 1.42, 1.5])
    motor_inverted: list[int] = field(default_factory=lambda: [1, -1, 1, -1])
    # Servo-side motor radians (raw * 4*2pi/4095) of each servo at spool 0 (upstream's
    # zero point times the gear ratio). Empty: the stored finger calibration, else the public
    # reflex-ros-pkg file's values.
    motor_zero_points: list[float] = field(default_factory=list)
    encoder_zero_rad: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    encoder_sign: float = -1.0  # reflex-ros-pkg HEAD: proximal = zero - counts * scale
    # Servo speeds set at start (reflex_takktile.yaml default_motor_speed), joint rad/s.
    motor_speed_rad_s: list[float] = field(default_factory=lambda: [3.0, 3.0, 3.0, 2.0])
    mode_switch_sleep_s: float = 0.035  # after each mode switch ("prevents board freezing")
    # Plausible raw servo positions: the firmware's multi-turn offset puts them near 13000
    # (it wraps outside 13000-14024 on a mode switch); 0 means the servo never answered.
    servo_window: list[int] = field(default_factory=lambda: [13000 - 4096, 14024 + 4096])
    servo_max_temperature_c: float = 70.0
    load_filter: float = 0.25  # EMA weight of the newest load (upstream)
    # Guarded close.
    spool_step_rad: float = 0.05
    spool_limit_rad: float = 3.5
    preshape_limit_rad: float = 1.6
    overload: list[float] = field(default_factory=lambda: [350.0, 350.0, 350.0, 400.0])
    backoff_rad: float = 0.05  # loosening on overload (every packet, holding included)
    stall_packets: int = 15
    stall_tolerance_rad: float = 0.01
    close_timeout_s: float = 15.0
    # open / preshape: wait until within tolerance, at most this long (a warning, not an error).
    arrival_tolerance_rad: float = 0.05
    move_timeout_s: float = 3.0
    warn_interval_s: float = 5.0
    # "twin": no hardware; an in-process byte-level emulator on loopback UDP, backed by the
    # shared twin world the arm moves in (rigs/reflex_emulated.py). Empty: a real hand.
    emulate: str = ""
    # Name of this hand's calibration records (<data>/calibration/<serial>/...; `activetouch
    # calibrate tactile|fingers --device <serial>`); make() loads them and hands them to the
    # driver. "": the type's name. Not used when emulating.
    serial: str = ""
    load_calibration: bool = True
    emulate_loss: float = 0.0  # emulate = "twin": fraction of state packets the board drops

    @property
    def simulated(self) -> bool:  # type: ignore[override]
        # An emulated hand stands in for the robot: recognitions place the object (sim/place).
        return self.emulate == "twin"

    def check(self) -> None:
        if self.emulate not in ("", "twin"):
            raise ConfigError(f"hand.emulate: {self.emulate!r} is not one of '', 'twin'")
        if not 0.0 <= self.emulate_loss < 1.0:
            raise ConfigError("hand.emulate_loss: must be in [0, 1)")
        for name in ("state_listen", "command_to"):
            try:
                parse_address(getattr(self, name), f"hand.{name}")
            except ValueError as e:
                raise ConfigError(str(e)) from None
        lengths = {
            "gear_ratio": 4,
            "motor_inverted": 4,
            "encoder_zero_rad": 3,
            "overload": 4,
            "motor_speed_rad_s": 4,
            "servo_window": 2,
        }
        for name, n in lengths.items():
            if len(getattr(self, name)) != n:
                raise ConfigError(f"hand.{name}: expected {n} values")
        if len(self.motor_zero_points) not in (0, 4):
            raise ConfigError("hand.motor_zero_points: expected 4 values (motor rad) or none")
        for name in ("zero_offsets", "thresholds"):
            if len(getattr(self, name)) not in (0, N_SENSORS):
                raise ConfigError(f"hand.{name}: expected {N_SENSORS} values or none")
        if any(v not in (1, -1) or isinstance(v, bool) for v in self.motor_inverted):
            raise ConfigError("hand.motor_inverted: each value must be 1 or -1")
        if self.encoder_sign not in (1.0, -1.0):
            raise ConfigError("hand.encoder_sign: must be 1 or -1")
        if any(g <= 0 for g in self.gear_ratio):
            raise ConfigError("hand.gear_ratio: must be positive")
        lo, hi = self.servo_window
        if not 0 < lo < hi <= 0xFFFF:
            raise ConfigError("hand.servo_window: expected [low, high] with 0 < low < high")
        if not 0.0 < self.load_filter <= 1.0:
            raise ConfigError("hand.load_filter: must be in (0, 1]")
        positive = (
            "stream_timeout_s",
            "connect_timeout_s",
            "spool_step_rad",
            "spool_limit_rad",
            "close_timeout_s",
            "move_timeout_s",
            "zero_samples",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"hand.{name}: must be > 0")
        if any(v <= 0 for v in self.motor_speed_rad_s):
            raise ConfigError("hand.motor_speed_rad_s: must be > 0")

    def make(self, ctx: DeviceContext) -> Hand:
        self.check()
        if self.emulate:  # the rig's config class (activetouch.rigs) makes that one
            raise ConfigError(f"hand.emulate = {self.emulate!r}: made through the device registry")
        tactile, fingers, device = None, None, self.serial or self.type
        if self.load_calibration:
            tactile, fingers = stored_calibration(device, ctx.data)
        return ReflexTakktileHand(self, tactile=tactile, fingers=fingers, device=device)


@dataclass(frozen=True)
class Reading:
    """A decoded, converted state packet."""

    seq: int  # count of accepted packets
    packet: codec.StatePacket
    mono: float
    wall: float
    pressures: np.ndarray  # (38,) raw - offset
    contact: np.ndarray  # (38,) bool (False for every sensor while uncalibrated or masked)
    motor: np.ndarray  # (4,) spool angles (0-2) and preshape (3), rad
    proximal: np.ndarray  # (3,)
    distal: np.ndarray  # (3,)
    load: np.ndarray  # (4,) signed, EMA-filtered
    faults: tuple[str, ...] = ()  # servo fields that cannot be true (empty: plausible)


class ReflexTakktileHand(Hand):
    """The `Hand` of a ReFlex TakkTile on its UDP link. Its calibration is handed to it
    (`make()` loads it from the store); it also satisfies the finger-calibration link
    (`read_motors`, `command_motors`, `set_finger_zeros`) and `set_tactile_calibration`."""

    def __init__(
        self,
        cfg: ReflexTakktileConfig,
        tactile: TactileZero | None = None,
        fingers: FingerZero | None = None,
        device: str = "",
    ) -> None:

        self.cfg = cfg
        self.device = device or cfg.serial or cfg.type
        self.listen = parse_address(cfg.state_listen, "hand.state_listen")
        self.command_to = parse_address(cfg.command_to, "hand.command_to")
        self.gear = np.asarray(cfg.gear_ratio, dtype=np.float64)
        self.inverted = np.asarray(cfg.motor_inverted, dtype=np.float64)
        self.encoder_sign = float(cfg.encoder_sign)
        if cfg.motor_zero_points:
            points = np.asarray(cfg.motor_zero_points, dtype=np.float64)
        elif fingers is not None:
            points = np.asarray(fingers.motor_zero_points, dtype=np.float64)
        else:
            points = np.asarray(DEFAULT_MOTOR_ZERO_POINTS, dtype=np.float64)
        # Joint-side zero (raw * scale / gear), the form the conversions use.
        self.motor_zero = points / self.gear
        enc = (
            fingers.encoder_zero_rad
            if fingers is not None and not any(cfg.encoder_zero_rad)
            else cfg.encoder_zero_rad
        )
        self.encoder_zero = np.asarray(enc, dtype=np.float64)
        self.thresholds = np.asarray(
            cfg.thresholds or [cfg.contact_threshold] * N_SENSORS, dtype=np.float64
        )
        self.offsets = np.asarray(cfg.zero_offsets or [0.0] * N_SENSORS, dtype=np.float64)
        self.tactile_calibrated = bool(cfg.zero_offsets)
        self.tactile_source = "hand.zero_offsets" if cfg.zero_offsets else ""
        self.flags: dict[int, str] = {}  # the tactile calibration's flags (`sensor_flags`)
        if tactile is not None:
            self.flags = dict(tactile.flags)
            self.offsets = np.asarray(tactile.zero, dtype=np.float64).copy()
            self.thresholds = np.asarray(tactile.threshold, dtype=np.float64).copy()
            self.tactile_calibrated, self.tactile_source = True, tactile.source
            log.info("calibration: tactile from %s", tactile.source)
        if fingers is not None:
            log.info("calibration: fingers from %s", fingers.source)
        self.masked = np.zeros(N_SENSORS, dtype=bool)  # in contact at rest: not reported
        self._recognition_mask = np.zeros(N_SENSORS, dtype=bool)  # `mask_sensors`
        self.stop_latch = StopLatch()
        self.warn = RateLimitedWarning(log, cfg.warn_interval_s)
        self.counts: dict[str, int] = {
            "received": 0,
            "accepted": 0,
            "duplicate_or_old": 0,
            "board_restarts": 0,
            "position_switches": 0,
            "overload_loosened": 0,
        }
        self.last_close_reasons: tuple[str, ...] = ()
        self.fault: ServoFaultError | None = None
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._cond = threading.Condition()
        self._tx_lock = threading.Lock()
        self._latest: Reading | None = None
        self._stale = True
        self._armed = False  # speeds set and POSITION mode on since the board last started
        self._rearming = False
        self._unwrap = kinematics.EncoderUnwrapper()
        self._last_systime: int | None = None
        self._link_armed = False  # armed since this link was opened (a restart re-arms then)
        self._load = np.zeros(4)
        self._goal = np.zeros(4)  # last commanded spool / preshape targets
        self._preshape_target: float | None = None
        self._listeners: list[Callable[[ReflexHandState], None]] = []

    def add_state_listener(self, fn: Callable[[ReflexHandState], None]) -> None:
        """Call `fn(state)` from the receive thread for every accepted packet (the packet
        rate, 40 Hz) and once when the stream goes stale, so `hand/state` can be published
        at the rate the hand measures, beside a running command. `fn` must be quick and
        must not call commands (it runs on the thread that feeds them)."""
        self._listeners.append(fn)

    def _notify(self) -> None:
        if not self._listeners:
            return
        state = self.state()
        for fn in list(self._listeners):
            try:
                fn(state)
            except Exception:  # a listener must not end the receive thread
                log.exception("ReFlex: state listener failed")

    # -- link -----------------------------------------------------------------------------

    def connect(self) -> None:
        """Open the link, wait for a plausible state packet, then arm the servos without
        moving them: goals at the measured positions, speeds, POSITION mode (once). An
        implausible reading raises `ServoFaultError` naming the servo, with nothing sent."""

        if self._sock is not None:
            return
        try:
            self._sock = open_socket(
                self.listen, self.cfg.multicast_group, self.cfg.interface, self.command_to
            )
        except OSError as e:
            raise ConfigError(
                f"hand.state_listen {self.cfg.state_listen}: cannot open ({e})"
            ) from None
        self._sock.settimeout(min(0.05, self.cfg.stream_timeout_s / 4))
        self._running = True
        self._thread = threading.Thread(target=self._rx_loop, name="reflex-rx", daemon=True)
        self._thread.start()
        try:
            r = self._wait_plausible(self.cfg.connect_timeout_s)
            self._arm(r)
            self._settle_tactile()
        except BaseException:
            self.disconnect(idle=False)
            raise

    def _wait_plausible(self, timeout: float) -> Reading:
        """The first reading whose servo fields are plausible; `ServoFaultError` naming the
        servo if none comes within `timeout` (the servos' state is zero until they answer)."""
        deadline = time.monotonic() + timeout
        seq = -1
        while True:
            left = deadline - time.monotonic()
            try:
                r = self._wait_reading(
                    seq, max(left, 1e-3), check_stop=False, wait_stale=True, check_fault=False
                )
            except StreamLostError:
                if self._latest is not None and self._latest.faults:
                    break
                raise
            if not r.faults:
                return r
            seq = r.seq
            if time.monotonic() >= deadline:
                break
        faults = self._latest.faults if self._latest is not None else ()
        raise ServoFaultError("ReFlex TakkTile: " + "; ".join(faults))

    def _arm(self, r: Reading) -> None:
        """Upstream's start: goals where the servos are (no motion when torque comes on),
        VELOCITY mode, speed targets, POSITION mode, each switch followed by a short sleep.
        The firmware rewrites the angle limits on every POSITION switch: only here."""
        cfg = self.cfg
        hold = r.motor.copy()
        speeds = [
            kinematics.speed_raw(v, float(g), int(i))
            for v, g, i in zip(cfg.motor_speed_rad_s, self.gear, self.inverted, strict=True)
        ]
        self._send(codec.encode_set_targets(self._raw_targets(hold)), motion=False)
        self._send(codec.encode_set_mode([codec.MODE_VELOCITY] * 4), motion=False)
        time.sleep(cfg.mode_switch_sleep_s)
        self._send(codec.encode_set_targets(speeds), motion=False)
        time.sleep(cfg.mode_switch_sleep_s)
        self._send(codec.encode_set_mode([codec.MODE_POSITION] * 4), motion=False)
        time.sleep(cfg.mode_switch_sleep_s)
        with self._cond:
            self._goal = hold
            self._armed = self._link_armed = True
            self.counts["position_switches"] += 1
            self._cond.notify_all()

    def _rearm_after_restart(self) -> None:
        try:
            r = self._wait_plausible(self.cfg.connect_timeout_s)
            self._arm(r)
            log.warning("ReFlex: board restarted; servos re-armed (POSITION mode, speeds)")
        except (ServoFaultError, StreamLostError, OSError) as e:
            self._set_fault(ServoFaultError(f"ReFlex TakkTile after a board restart: {e}"))
        finally:
            self._rearming = False

    def _settle_tactile(self) -> None:
        """Without a calibration, zero the pads now if `zero_on_connect` (hand open); with
        one, mask sensors reading contact while the hand is open (they cannot be touched)."""
        cfg = self.cfg
        r = self._wait_reading(-1, cfg.stream_timeout_s, check_stop=False, wait_stale=True)
        is_open = bool(np.all(np.abs(r.proximal) <= cfg.open_tolerance_rad))
        if not self.tactile_calibrated and cfg.zero_on_connect:
            if not is_open:
                log.warning(
                    "ReFlex: hand.zero_on_connect: the fingers are not open (%s rad): not "
                    "zeroed; open the hand and reconnect, or run `%s`",
                    np.round(r.proximal, 2).tolist(),
                    CALIBRATE_TACTILE,
                )
                return
            self._zero_now(r)
            return
        if not self.tactile_calibrated:
            log.warning(
                "ReFlex: no tactile calibration for %s: contacts are not reported and "
                "guarded_close is refused; run `%s` with the hand open (or set "
                "hand.zero_on_connect = true)",
                self.device,
                CALIBRATE_TACTILE,
            )
            return
        if is_open:
            over = (r.pressures > self.thresholds) & ~self.masked
            if over.any():
                with self._cond:
                    self.masked |= over
                log.warning(
                    "ReFlex: sensors %s read contact with the hand open at connect: masked "
                    "(never reported) until `%s` is run again",
                    np.flatnonzero(over).tolist(),
                    CALIBRATE_TACTILE,
                )

    def _zero_now(self, r: Reading) -> None:

        rows, ts, seq = [], [], r.seq
        for _ in range(self.cfg.zero_samples):
            r = self._wait_reading(seq, self.cfg.stream_timeout_s, check_stop=False)
            seq = r.seq
            rows.append(r.packet.pressures.astype(np.float64))
            ts.append(r.mono)
        st = TactileSettings(
            min_samples=min(30, self.cfg.zero_samples), min_threshold=self.cfg.contact_threshold
        )
        fit = fit_tactile(np.asarray(ts), np.stack(rows), st)
        self.set_tactile_calibration(
            fit.zero,
            fit.threshold,
            source="hand.zero_on_connect",
            flags=flags_by_sensor(rec_flags(fit)),
        )
        log.info("ReFlex: tactile zeroed at connect (hand.zero_on_connect), %d packets", len(rows))

    def disconnect(self, idle: bool = True) -> None:
        """Torque off (IDLE, as upstream on exit), then close the link."""
        if idle and self._sock is not None:
            with contextlib.suppress(OSError, StreamLostError):
                self._send(codec.encode_set_mode([codec.MODE_IDLE] * 4), motion=False)
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        with self._cond:
            self._stale = True
            self._armed = self._link_armed = False
            # A reconnection starts afresh: the board may have rebooted meanwhile, which is
            # not a restart under a live link (connect arms it once).
            self._last_systime = None
            self._cond.notify_all()

    @property
    def stale(self) -> bool:
        return self._stale

    def stats(self) -> dict[str, int]:
        """Packet counters: received, accepted, duplicate_or_old, board restarts, POSITION
        switches, overload loosenings, and one per refusal reason."""
        with self._cond:
            return {**self.counts, **self.warn.counts}

    def _rx_loop(self) -> None:
        sock = self._sock
        assert sock is not None
        while self._running:
            try:
                data = sock.recv(4096)
            except TimeoutError:
                data = None
            except OSError:
                if not self._running:
                    return
                data = None
            now = time.monotonic()
            if data is not None:
                try:
                    self._on_datagram(data, now)
                except Exception:  # never let one datagram end the receive thread
                    log.exception("state packet handling failed")
            latest = self._latest
            quiet = latest is None or now - latest.mono > self.cfg.stream_timeout_s
            if not self._stale and quiet:
                self._on_stream_lost(now)
                self._notify()  # listeners see the hand go stale

    def _on_datagram(self, data: bytes, now: float) -> None:
        with self._cond:
            self.counts["received"] += 1
        try:
            p = codec.decode_state(data)
        except codec.PacketError as e:
            with self._cond:
                self.warn(f"refused_{e.reason}", f"ReFlex: refused a datagram: {e}")
            return
        rearm = False
        with self._cond:
            if not codec.is_newer(p.systime_us, self._last_systime):
                self.counts["duplicate_or_old"] += 1
                return
            restarted = codec.is_restart(p.systime_us, self._last_systime)
            self._last_systime = p.systime_us
            if restarted:
                # The board comes back in IDLE with zero-initialised servo state.
                self.counts["board_restarts"] += 1
                log.warning("ReFlex: the hand's board restarted (its clock went back)")
                self._armed = False
                self._load = np.zeros(4)
            r = self._convert(p, now)
            self.counts["accepted"] += 1
            self._latest = r
            if self._stale and self._running:
                log.info("ReFlex: state stream up")
            self._stale = False
            if self._was_armed_once() and not self._armed and not self._rearming:
                self._rearming = rearm = True
            self._cond.notify_all()
        if r.faults and self._armed:
            self._set_fault(ServoFaultError("ReFlex TakkTile: " + "; ".join(r.faults)))
        elif self._armed and self.fault is None:
            self._loosen_if_overloaded(r)
        if rearm:
            threading.Thread(
                target=self._rearm_after_restart, name="reflex-rearm", daemon=True
            ).start()
        self._notify()

    def _was_armed_once(self) -> bool:
        return self._link_armed and self._running

    def _set_fault(self, err: ServoFaultError) -> None:
        """Latch a servo fault: stop, wake waiting commands; nothing is commanded from the
        reading (the servos keep their last goals)."""
        with self._cond:
            first = self.fault is None
            self.fault = err
            self.stop_latch.set()
            self._cond.notify_all()
        if first:
            log.error("%s", err)

    def _loosen_if_overloaded(self, r: Reading) -> None:
        """Upstream's _loosen_if_overloaded on every state packet, holding included: a motor
        whose filtered load passes its threshold is sent `backoff_rad` back from where it is."""
        over = np.abs(r.load) > np.abs(np.asarray(self.cfg.overload, dtype=np.float64))
        if not over.any():
            return
        goal = self._goal.copy()
        goal[over] = np.maximum(0.0, r.motor[over] - self.cfg.backoff_rad)
        with contextlib.suppress(OSError, StreamLostError, ValueError):
            self._send_goal(goal, motion=False)
            with self._cond:
                self.counts["overload_loosened"] += 1
            self.warn(
                "overload",
                f"ReFlex: motors {np.flatnonzero(over).tolist()} overloaded "
                f"({np.round(r.load, 0).tolist()}): loosened",
            )

    def _convert(self, p: codec.StatePacket, now: float) -> Reading:
        pressures = p.pressures.astype(np.float64) - self.offsets
        motor = kinematics.motor_angle(p.dxl_position, self.gear, self.inverted, self.motor_zero)
        prox = kinematics.proximal_angle(
            self._unwrap(p.encoders), self.encoder_zero, self.cfg.encoder_sign
        )
        faults = tuple(
            codec.servo_faults(p, self.cfg.servo_window, self.cfg.servo_max_temperature_c)
        )
        if not faults:
            a = self.cfg.load_filter
            self._load = (
                a * kinematics.load_from_raw(p.dxl_load, self.inverted) + (1 - a) * self._load
            )
        contact = (pressures > self.thresholds) & ~self.masked
        if not self.tactile_calibrated:
            contact[:] = False  # unloaded raw counts are far above any threshold
        seq = self._latest.seq + 1 if self._latest is not None else 0
        return Reading(
            seq=seq,
            packet=p,
            mono=now,
            wall=time.time(),
            pressures=pressures,
            contact=contact,
            motor=motor,
            proximal=prox,
            distal=kinematics.distal_approx(motor[:N_FINGERS], prox),
            load=self._load.copy(),
            faults=faults,
        )

    def _on_stream_lost(self, now: float) -> None:
        with self._cond:
            self._stale = True
            self._cond.notify_all()
        latest = self._latest
        age = "no packet yet" if latest is None else f"{now - latest.mono:.3f} s"
        self.warn("stream_lost", f"ReFlex: state stream lost ({age}); motors told to hold")
        if latest is not None and not latest.faults and self._armed:
            with contextlib.suppress(OSError, StreamLostError, ValueError):
                self._send_goal(latest.motor, motion=False)

    def _wait_reading(
        self,
        after_seq: int,
        timeout: float,
        check_stop: bool = True,
        wait_stale: bool = False,
        check_fault: bool = True,
    ) -> Reading:
        """The first reading newer than `after_seq`. StoppedError on a stop (if `check_stop`);
        the latched `ServoFaultError`; StreamLostError if none comes within `timeout`, or at
        once if the stream is stale (unless `wait_stale`)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                if check_fault and self.fault is not None:
                    raise self.fault
                if check_stop and self.stop_latch.is_set:
                    raise StoppedError("ReFlex: stopped")
                r = self._latest
                if r is not None and r.seq > after_seq and not self._stale:
                    return r
                left = deadline - time.monotonic()
                lost = self._stale and r is not None and not wait_stale
                if left <= 0 or lost or not self._running:
                    raise StreamLostError(
                        f"ReFlex: no state packet on {self.cfg.state_listen} within "
                        f"{self.cfg.stream_timeout_s if lost else timeout:.3g} s "
                        "(is the hand on and the address right?)"
                    )
                self._cond.wait(min(left, 0.05))

    def _send(self, data: bytes, motion: bool = True) -> None:
        """Send a command. Motion commands are refused once stopped; the check and the send
        share a lock with `stop()`, so nothing moves a finger after the hold is sent."""
        with self._tx_lock:
            if motion:
                if self.fault is not None:
                    raise self.fault
                self.stop_latch.check("ReFlex command")
            if self._sock is None:
                raise StreamLostError("ReFlex: not connected")
            self._sock.sendto(data, self.command_to)

    def _raw_targets(self, motor: np.ndarray) -> list[int]:
        """Raw goals for spool / preshape angles; ValueError (nothing sent) for a goal outside
        the servo's plausible window."""
        raw = kinematics.motor_raw(motor, self.gear, self.inverted, self.motor_zero)
        lo, hi = self.cfg.servo_window
        bad = [i for i in range(4) if not lo <= int(raw[i]) <= hi]
        if bad:
            i = bad[0]
            raise ValueError(
                f"ReFlex: goal {int(raw[i])} for the {codec.SERVO_NAMES[i]} is outside its window "
                f"{lo}..{hi} (hand.motor_zero_points wrong? run `activetouch calibrate fingers`)"
            )
        return raw.tolist()

    def _send_goal(self, goal: np.ndarray, motion: bool = True) -> None:
        goal = np.asarray(goal, dtype=np.float64)
        self._send(codec.encode_set_targets(self._raw_targets(goal)), motion=motion)
        self._goal = goal.copy()

    def _ensure_armed(self) -> None:
        """Commands wait (a bounded time) for the servos to be re-armed after a restart."""
        deadline = time.monotonic() + self.cfg.connect_timeout_s
        with self._cond:
            while not self._armed:
                if self.fault is not None:
                    raise self.fault
                left = deadline - time.monotonic()
                if left <= 0 or not self._running:
                    raise StreamLostError("ReFlex: servos not armed (board restarting?)")
                self._cond.wait(min(left, 0.05))

    def _latest_or_wait(self) -> Reading:
        self._ensure_armed()
        r = self._latest
        if r is None or self._stale:
            r = self._wait_reading(-1, self.cfg.stream_timeout_s, check_stop=False, wait_stale=True)
        if self.fault is not None:
            raise self.fault
        return r

    # -- the calibration links (public; calibration/ uses only these) ---------------------

    def read_motors(self, after_seq: int, timeout_s: float) -> Reading:
        """The first reading newer than `after_seq` (seq, motor, proximal, load, ...)."""
        return self._wait_reading(after_seq, timeout_s)

    def command_motors(self, targets: np.ndarray) -> None:
        """Send spool / preshape goals (rad, range-checked)."""
        self._ensure_armed()
        self._send_goal(np.asarray(targets, dtype=np.float64))

    def set_finger_zeros(self, motor_zero: np.ndarray, encoder_zero: np.ndarray) -> None:
        """Use new joint-side motor zeros (raw * scale / gear) and encoder zeros."""
        self.motor_zero = np.asarray(motor_zero, dtype=np.float64).copy()
        self.encoder_zero = np.asarray(encoder_zero, dtype=np.float64).copy()

    def set_tactile_calibration(
        self,
        zero: np.ndarray,
        threshold: np.ndarray,
        source: str = "",
        flags: dict[int, str] | None = None,
    ) -> None:
        """Use this tactile zero and thresholds from the next packet on; clears the mask.
        `flags`: sensor id -> the calibration's flag (`sensor_flags`)."""
        with self._cond:
            self.flags = dict(flags or {})
            self.offsets = np.asarray(zero, dtype=np.float64).copy()
            self.thresholds = np.asarray(threshold, dtype=np.float64).copy()
            self.masked = np.zeros(N_SENSORS, dtype=bool)
            self._recognition_mask = np.zeros(N_SENSORS, dtype=bool)
            self.tactile_calibrated, self.tactile_source = True, source

    # -- Hand interface -------------------------------------------------------------------

    def sensor_flags(self) -> dict[int, str]:
        with self._cond:
            return dict(self.flags)

    def mask_sensors(self, sensor_ids: Sequence[int]) -> bool:
        """The caller's mask (one recognition's), beside the sensors masked at connect."""
        ids = np.asarray(list(sensor_ids), dtype=np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= N_SENSORS):
            raise ValueError(f"sensor ids must be 0..{N_SENSORS - 1}, got {ids.tolist()}")
        new = np.zeros(N_SENSORS, dtype=bool)
        new[ids] = True
        with self._cond:
            self.masked = (self.masked & ~self._recognition_mask) | new
            self._recognition_mask = new
        return True

    def stop(self) -> None:
        self.stop_latch.set()
        r = self._latest
        # Hold where the motors are, never from a reading that cannot be true.
        if r is not None and not r.faults and self._armed and self._sock is not None:
            try:
                self._send_goal(r.motor, motion=False)
            except (OSError, StreamLostError, ValueError):
                log.warning("ReFlex: could not send the hold command on stop", exc_info=True)
        with self._cond:
            self._cond.notify_all()

    def clear_stop(self) -> None:
        self.stop_latch.clear()

    def own_contact_thresholds(self) -> np.ndarray:
        return self.thresholds.copy()

    def sensor_sites(self) -> np.ndarray | None:
        r = self._latest
        return None if r is None else self._sites(r)

    @staticmethod
    def _sites(r: Reading) -> np.ndarray:
        """(38, 3) the sensors' hand-frame positions at reading `r`'s joint angles."""
        return sensor_positions(DEFAULT_GEOMETRY, float(r.motor[3]), r.proximal, r.distal)

    def state(self) -> ReflexHandState:
        r = self._latest
        if r is None:
            z3 = np.zeros(N_FINGERS)
            return ReflexHandState(
                pressures=np.zeros(N_SENSORS),
                contact=np.zeros(N_SENSORS, dtype=bool),
                finger_angles=z3,
                preshape=0.0,
                stamp=0.0,
                stale=True,
            )
        return ReflexHandState(
            pressures=r.pressures.copy(),
            contact=r.contact & ~self.masked,
            finger_angles=r.proximal.copy(),
            preshape=float(r.motor[3]),
            stamp=r.mono,
            stale=self._stale,
            distal=r.distal.copy(),
            motor=r.motor.copy(),
            load=r.load.copy(),
            wall_stamp=r.wall,
            systime_us=r.packet.systime_us,
        )

    def open(self) -> None:
        """Spools to 0, preshape unchanged; allowed while stopped (releasing follows a stop)."""
        if self.fault is not None:
            raise self.fault
        r = self._latest_or_wait()
        target = np.zeros(4)
        target[3] = self._preshape_target if self._preshape_target is not None else r.motor[3]
        self._send_goal(target, motion=False)
        self._wait_arrival(target, range(N_FINGERS), "open", check_stop=False)

    def preshape(self, angle: float) -> None:
        if self.fault is not None:
            raise self.fault
        self.stop_latch.check("preshape")
        a = float(angle)
        if not 0.0 <= a <= self.cfg.preshape_limit_rad:
            raise ValueError(f"preshape {a} rad is outside 0..{self.cfg.preshape_limit_rad}")
        r = self._latest_or_wait()
        target = r.motor.copy()
        target[3] = a
        self._send_goal(target)
        self._preshape_target = a
        self._wait_arrival(target, [3], "preshape", check_stop=True)

    def _wait_arrival(self, target: np.ndarray, motors, what: str, check_stop: bool) -> None:
        deadline = time.monotonic() + self.cfg.move_timeout_s
        seq = -1
        idx = list(motors)
        while time.monotonic() < deadline:
            r = self._wait_reading(seq, self.cfg.stream_timeout_s, check_stop=check_stop)
            seq = r.seq
            if np.all(np.abs(r.motor[idx] - target[idx]) <= self.cfg.arrival_tolerance_rad):
                return
        log.warning("ReFlex: %s did not arrive within %.1f s", what, self.cfg.move_timeout_s)

    def guarded_close(self) -> Grasp:
        cfg = self.cfg
        if not self.tactile_calibrated:
            raise TactileCalibrationError(
                f"ReFlex TakkTile {self.device}: no tactile calibration (unloaded sensors read "
                f"far above the contact threshold): run `{CALIBRATE_TACTILE}` with the hand "
                "open, or set hand.zero_on_connect = true"
            )
        if self.fault is not None:
            raise self.fault
        self.stop_latch.check("guarded close")
        r = self._latest_or_wait()
        # Decide the first step from a packet that arrived after this call: the arm may have
        # stopped only just now, and a finger already touching must not move.
        r = self._wait_reading(r.seq, cfg.stream_timeout_s)
        preshape_target = r.motor[3] if self._preshape_target is None else self._preshape_target
        active = np.ones(N_FINGERS, dtype=bool)
        step = CloseStep(r.motor[:N_FINGERS].copy(), active, ("",) * N_FINGERS)
        stall = StallDetector(cfg.stall_packets, cfg.stall_tolerance_rad)
        overload = np.abs(np.asarray(cfg.overload, dtype=np.float64))
        deadline = time.monotonic() + cfg.close_timeout_s
        while step.active.any():
            if time.monotonic() > deadline:
                self._send_goal(r.motor)
                raise TimeoutError(f"ReFlex: guarded close took over {cfg.close_timeout_s} s")
            touching = self._finger_contact(r.contact & ~self.masked)
            step = close_step(
                r.motor,
                step.target,
                step.active,
                step.reasons,
                touching,
                np.abs(r.load[:N_FINGERS]) > overload[:N_FINGERS],
                stall(r.motor),
                cfg.spool_step_rad,
                cfg.spool_limit_rad,
                cfg.backoff_rad,
            )
            self._send_goal(np.append(step.target, preshape_target))
            # One control step per state packet; a stop wakes this wait and raises.
            r = self._wait_reading(r.seq, cfg.stream_timeout_s)
        self.last_close_reasons = step.reasons
        r = self._wait_reading(r.seq, cfg.stream_timeout_s)  # read at the final pose
        ids = np.flatnonzero(r.contact & ~self.masked)
        sites = self._sites(r)
        return Grasp(
            sensor_ids=ids,
            xyz=sites[ids],
            pressures=r.pressures[ids],
            finger_angles=r.proximal.copy(),
            preshape=float(r.motor[3]),
        )

    @staticmethod
    def _finger_contact(contact: np.ndarray) -> np.ndarray:
        """(3,) whether any of a finger's own 9 pads is in contact."""
        return contact[: N_FINGERS * SENSORS_PER_FINGER].reshape(N_FINGERS, -1).any(axis=1)
