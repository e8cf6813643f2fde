"""ReFlex TakkTile / Beta hand over UDP (``hand.type = "reflex-takktile"``).

A receive thread decodes every state packet (40 Hz) into a reading; commands go out as
datagrams from the same socket. The guarded close runs one control step per state packet:
each finger's spool advances `spool_step_rad` until that finger's own pads report contact,
it reaches its travel limit, stalls, or is overloaded (backs off), each finger on its own.

Safety: `stop()` commands every motor to hold at its measured position at once and wakes a
waiting close, which raises `StoppedError` without sending anything more; no state packet
for `stream_timeout_s` marks the hand stale, commands the motors to hold and makes every
waiting command raise `StreamLostError` (nothing waits longer than that).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from activetouch.device_types import HandConfig
from activetouch.drivers.reflex import codec, kinematics
from activetouch.drivers.reflex.common import (
    CloseStep,
    RateLimitedWarning,
    ReflexHandState,
    StallDetector,
    StreamLostError,
    close_step,
    parse_address,
)
from activetouch.errors import ConfigError, StoppedError
from activetouch.interfaces import N_FINGERS, N_SENSORS, SENSORS_PER_FINGER, Grasp, Hand

if TYPE_CHECKING:
    import socket

    from activetouch.devices import DeviceContext

log = logging.getLogger(__name__)


@dataclass
class ReflexTakktileConfig(HandConfig):
    """Settings of a ReFlex TakkTile hand (docs/protocols/reflex.md says what each means)."""

    # Where the driver receives state packets. The wildcard (or the group) joins the multicast
    # group; a unicast address (127.0.0.1 in tests) never joins.
    state_listen: str = "0.0.0.0:11333"
    command_to: str = "224.0.0.124:11333"  # where command packets go
    multicast_group: str = "224.0.0.124"  # empty: unicast only
    interface: str = ""  # name (eth0) or IPv4 address of the hand's interface; empty: default
    stream_timeout_s: float = 0.2  # no state packet for this long: stale, motors told to hold
    connect_timeout_s: float = 2.0  # first packet must arrive within this
    # Tactile calibration (until the calibration file exists): pressure = raw - offset,
    # contact = pressure > threshold. Empty lists: offset 0 / `contact_threshold` for all 38.
    contact_threshold: float = 20.0
    zero_offsets: list[float] = field(default_factory=list)
    thresholds: list[float] = field(default_factory=list)
    # Servo and encoder conversion (motor order: finger 0, 1, 2, preshape).
    gear_ratio: list[float] = field(default_factory=lambda: [1.42, 1.42, 1.42, 1.5])
    motor_inverted: list[int] = field(default_factory=lambda: [1, -1, 1, -1])
    motor_zero_rad: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    encoder_zero_rad: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    encoder_sign: float = -1.0  # reflex-ros-pkg HEAD: proximal = zero - counts * scale
    # Guarded close.
    spool_step_rad: float = 0.05
    spool_limit_rad: float = 3.5
    preshape_limit_rad: float = 1.6
    overload: list[float] = field(default_factory=lambda: [350.0, 350.0, 350.0, 400.0])
    backoff_rad: float = 0.05
    stall_packets: int = 15
    stall_tolerance_rad: float = 0.01
    close_timeout_s: float = 15.0
    # open / preshape: wait until within tolerance, at most this long (a warning, not an error).
    arrival_tolerance_rad: float = 0.05
    move_timeout_s: float = 3.0
    warn_interval_s: float = 5.0
    # "twin": no hardware; an in-process byte-level emulator on loopback UDP, backed by the
    # shared twin world the arm moves in (twin_emulated.py). The driver still speaks UDP and
    # its own codec. Empty: a real hand at the addresses above.
    emulate: str = ""
    # Name of this hand's calibration records (<data>/calibration/<serial>/...; `activetouch
    # calibrate tactile|fingers --device <serial>`); loaded at connect, replacing the offsets,
    # thresholds and zeros above. "": the type's name. Not used when emulating.
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
            "motor_zero_rad": 4,
            "encoder_zero_rad": 3,
            "overload": 4,
        }
        for name, n in lengths.items():
            if len(getattr(self, name)) != n:
                raise ConfigError(f"hand.{name}: expected {n} values")
        for name in ("zero_offsets", "thresholds"):
            if len(getattr(self, name)) not in (0, N_SENSORS):
                raise ConfigError(f"hand.{name}: expected {N_SENSORS} values or none")
        if any(v not in (1, -1) for v in self.motor_inverted):
            raise ConfigError("hand.motor_inverted: each value must be 1 or -1")
        if self.encoder_sign not in (1.0, -1.0):
            raise ConfigError("hand.encoder_sign: must be 1 or -1")
        if any(g <= 0 for g in self.gear_ratio):
            raise ConfigError("hand.gear_ratio: must be positive")
        positive = (
            "stream_timeout_s",
            "connect_timeout_s",
            "spool_step_rad",
            "spool_limit_rad",
            "close_timeout_s",
            "move_timeout_s",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"hand.{name}: must be > 0")

    def make(self, ctx: DeviceContext) -> Hand:
        self.check()
        if self.emulate == "twin":
            from activetouch.rigs.reflex_emulated import make_twin_emulated

            return make_twin_emulated(self, ctx)
        hand = ReflexTakktileHand(self)
        if self.load_calibration:
            hand.calibration_source = (self.serial or self.type, ctx.data)
        return hand


@dataclass(frozen=True)
class Reading:
    """A decoded, converted state packet."""

    seq: int  # count of accepted packets
    packet: codec.StatePacket
    mono: float
    wall: float
    pressures: np.ndarray  # (38,) raw - offset
    contact: np.ndarray  # (38,) bool
    motor: np.ndarray  # (4,) spool angles (0-2) and preshape (3), rad
    proximal: np.ndarray  # (3,)
    distal: np.ndarray  # (3,)
    load: np.ndarray  # (4,) signed raw


class ReflexTakktileHand(Hand):
    """The `Hand` of a ReFlex TakkTile on its UDP link."""

    def __init__(self, cfg: ReflexTakktileConfig) -> None:
        # (device name, data dir) of the stored calibration to load at connect; None: none.
        self.calibration_source: tuple[str, object] | None = None
        from activetouch.interfaces import StopLatch

        self.cfg = cfg
        self.listen = parse_address(cfg.state_listen, "hand.state_listen")
        self.command_to = parse_address(cfg.command_to, "hand.command_to")
        self.gear = np.asarray(cfg.gear_ratio, dtype=np.float64)
        self.inverted = np.asarray(cfg.motor_inverted, dtype=np.float64)
        self.motor_zero = np.asarray(cfg.motor_zero_rad, dtype=np.float64)
        self.encoder_zero = np.asarray(cfg.encoder_zero_rad, dtype=np.float64)
        self.offsets = np.asarray(cfg.zero_offsets or [0.0] * N_SENSORS, dtype=np.float64)
        self.thresholds = np.asarray(
            cfg.thresholds or [cfg.contact_threshold] * N_SENSORS, dtype=np.float64
        )
        self.stop_latch = StopLatch()
        self.warn = RateLimitedWarning(log, cfg.warn_interval_s)
        self.counts: dict[str, int] = {"received": 0, "accepted": 0, "duplicate_or_old": 0}
        self.last_close_reasons: tuple[str, ...] = ()
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._cond = threading.Condition()
        self._tx_lock = threading.Lock()
        self._latest: Reading | None = None
        self._stale = True
        self._unwrap = kinematics.EncoderUnwrapper()
        self._last_systime: int | None = None
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
        from activetouch.drivers.reflex.udp import open_socket

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
            r = self._wait_reading(
                -1, self.cfg.connect_timeout_s, check_stop=False, wait_stale=True
            )
            # Hold where the motors are before switching them to position control.
            self._send(codec.encode_set_targets(self._raw_targets(r.motor)), motion=False)
            self._send(codec.encode_set_mode([codec.MODE_POSITION] * 4), motion=False)
        except BaseException:
            self.disconnect()
            raise
        if self.calibration_source is not None:
            from activetouch.calibration.apply import load_into

            device, data = self.calibration_source
            load_into(self, device, data)  # logs the file used, or warns with the command

    def disconnect(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        with self._cond:
            self._stale = True
            self._cond.notify_all()

    @property
    def stale(self) -> bool:
        return self._stale

    def stats(self) -> dict[str, int]:
        """Packet counters: received, accepted, duplicate_or_old, and one per refusal reason."""
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
        with self._cond:
            if not codec.is_newer(p.systime_us, self._last_systime):
                self.counts["duplicate_or_old"] += 1
                return
            self._last_systime = p.systime_us
            r = self._convert(p, now)
            self.counts["accepted"] += 1
            self._latest = r
            if self._stale and self._running:
                log.info("ReFlex: state stream up")
            self._stale = False
            self._cond.notify_all()
        self._notify()

    def _convert(self, p: codec.StatePacket, now: float) -> Reading:
        pressures = p.pressures.astype(np.float64) - self.offsets
        motor = kinematics.motor_angle(p.dxl_position, self.gear, self.inverted, self.motor_zero)
        prox = kinematics.proximal_angle(
            self._unwrap(p.encoders), self.encoder_zero, self.cfg.encoder_sign
        )
        seq = self._latest.seq + 1 if self._latest is not None else 0
        return Reading(
            seq=seq,
            packet=p,
            mono=now,
            wall=time.time(),
            pressures=pressures,
            contact=pressures > self.thresholds,
            motor=motor,
            proximal=prox,
            distal=kinematics.distal_approx(motor[:N_FINGERS], prox),
            load=kinematics.load_signed(p.dxl_load, self.inverted).astype(np.float64),
        )

    def _on_stream_lost(self, now: float) -> None:
        with self._cond:
            self._stale = True
            self._cond.notify_all()
        latest = self._latest
        age = "no packet yet" if latest is None else f"{now - latest.mono:.3f} s"
        self.warn("stream_lost", f"ReFlex: state stream lost ({age}); motors told to hold")
        if latest is not None:
            with contextlib.suppress(OSError, StreamLostError):
                self._send(codec.encode_set_targets(self._raw_targets(latest.motor)), motion=False)

    def _wait_reading(
        self, after_seq: int, timeout: float, check_stop: bool = True, wait_stale: bool = False
    ) -> Reading:
        """The first reading newer than `after_seq`. StoppedError on a stop (if `check_stop`);
        StreamLostError if none comes within `timeout`, or at once if the stream is stale
        (unless `wait_stale`: then a recovering stream may still answer within `timeout`)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
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
                self.stop_latch.check("ReFlex command")
            if self._sock is None:
                raise StreamLostError("ReFlex: not connected")
            self._sock.sendto(data, self.command_to)

    def _raw_targets(self, motor: np.ndarray) -> list[int]:
        return kinematics.motor_raw(motor, self.gear, self.inverted, self.motor_zero).tolist()

    def _latest_or_wait(self) -> Reading:
        r = self._latest
        if r is None or self._stale:
            r = self._wait_reading(-1, self.cfg.stream_timeout_s, check_stop=False, wait_stale=True)
        return r

    # -- Hand interface -------------------------------------------------------------------

    def stop(self) -> None:
        self.stop_latch.set()
        r = self._latest
        if r is not None and self._sock is not None:
            try:
                self._send(codec.encode_set_targets(self._raw_targets(r.motor)), motion=False)
            except (OSError, StreamLostError):
                log.warning("ReFlex: could not send the hold command on stop", exc_info=True)
        with self._cond:
            self._cond.notify_all()

    def clear_stop(self) -> None:
        self.stop_latch.clear()

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
            contact=r.contact.copy(),
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
        r = self._latest_or_wait()
        target = np.zeros(4)
        target[3] = self._preshape_target if self._preshape_target is not None else r.motor[3]
        self._send(codec.encode_set_mode([codec.MODE_POSITION] * 4), motion=False)
        self._send(codec.encode_set_targets(self._raw_targets(target)), motion=False)
        self._wait_arrival(target, range(N_FINGERS), "open", check_stop=False)

    def preshape(self, angle: float) -> None:
        self.stop_latch.check("preshape")
        a = float(angle)
        if not 0.0 <= a <= self.cfg.preshape_limit_rad:
            raise ValueError(f"preshape {a} rad is outside 0..{self.cfg.preshape_limit_rad}")
        r = self._latest_or_wait()
        target = r.motor.copy()
        target[3] = a
        self._preshape_target = a
        self._send(codec.encode_set_targets(self._raw_targets(target)))
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
        self.stop_latch.check("guarded close")
        r = self._latest_or_wait()
        # Decide the first step from a packet that arrived after this call: the arm may have
        # stopped only just now, and a finger already touching must not move.
        r = self._wait_reading(r.seq, cfg.stream_timeout_s)
        self._send(codec.encode_set_mode([codec.MODE_POSITION] * 4))
        preshape_target = r.motor[3] if self._preshape_target is None else self._preshape_target
        active = np.ones(N_FINGERS, dtype=bool)
        step = CloseStep(r.motor[:N_FINGERS].copy(), active, ("",) * N_FINGERS)
        stall = StallDetector(cfg.stall_packets, cfg.stall_tolerance_rad)
        overload = np.abs(np.asarray(cfg.overload, dtype=np.float64))
        deadline = time.monotonic() + cfg.close_timeout_s
        while step.active.any():
            if time.monotonic() > deadline:
                self._send(codec.encode_set_targets(self._raw_targets(r.motor)))
                raise TimeoutError(f"ReFlex: guarded close took over {cfg.close_timeout_s} s")
            touching = self._finger_contact(r.contact)
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
            self._send(
                codec.encode_set_targets(self._raw_targets(np.append(step.target, preshape_target)))
            )
            # One control step per state packet; a stop wakes this wait and raises.
            r = self._wait_reading(r.seq, cfg.stream_timeout_s)
        self.last_close_reasons = step.reasons
        r = self._wait_reading(r.seq, cfg.stream_timeout_s)  # read at the final pose
        ids = np.flatnonzero(r.contact)
        sites = kinematics.contact_sites(float(r.motor[3]), r.proximal, r.distal)
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
