"""ReFlex SF over USB serial (``hand.type = "reflex-sf"``): four Dynamixel MX-28 servos,
Protocol 1.0, through dynamixel-sdk (ids 1-3 fingers, 4 preshape).

The SF has no tactile sensors and no proximal encoders. Contact is a finger stalling under
load: during the guarded close a finger whose load passes `contact_load` stops there and is
reported as one contact at its distal link's sensor site `contact_site` from the kinematics
(free-finger coupling: proximal = spool / (1 + k), distal = k * proximal). Three fingers give
at most three contacts: one triangle per grasp, which the triangle descriptor still uses.

A poll thread reads position and load of every servo at `control_hz`; commands share the bus
lock with it. `stop()` writes hold goals at once (between two transactions) and a running close
raises at its next step; servos that stop answering for `stream_timeout_s` make the hand stale.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from activetouch.device_types import HandConfig
from activetouch.drivers.reflex import kinematics
from activetouch.drivers.reflex.common import (
    CloseStep,
    RateLimitedWarning,
    ReflexHandState,
    StallDetector,
    StreamLostError,
    close_step,
)
from activetouch.errors import ConfigError, StoppedError
from activetouch.interfaces import (
    N_FINGERS,
    N_SENSORS,
    SENSORS_PER_FINGER,
    Grasp,
    Hand,
    StopLatch,
)

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext

log = logging.getLogger(__name__)

# MX-28, Protocol 1.0 control table.
ADDR_TORQUE_ENABLE = 24
ADDR_GOAL_POSITION = 30
ADDR_MOVING_SPEED = 32
ADDR_PRESENT_POSITION = 36  # then present speed (38) and present load (40), 2 bytes each
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


@dataclass
class ReflexSFConfig(HandConfig):
    """Settings of a ReFlex SF (docs/protocols/reflex.md)."""

    # The SF's servos run at 57142 bps (register value 34); a USB adapter opened at 57600 is
    # within UART tolerance of it, and dynamixel-sdk opens only standard rates.
    port: str = "/dev/ttyUSB0"
    baud: int = 57600
    motor_ids: list[int] = field(default_factory=lambda: [1, 2, 3, 4])
    gear_ratio: list[float] = field(default_factory=lambda: [1.42, 1.42, 1.42, 1.5])
    motor_inverted: list[int] = field(default_factory=lambda: [1, 1, -1, -1])
    motor_zero_rad: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    # Load (fraction of the maximum) at which a closing finger counts as in contact; the
    # preshape's entry is its overload threshold.
    contact_load: list[float] = field(default_factory=lambda: [0.25, 0.25, 0.25, 0.55])
    contact_site: int = 6  # sensor index (5..8, on the distal link) reported as the contact
    flexure_coupling: float = 0.25  # free finger: distal = k * proximal (as the twin)
    moving_speed: int = 200  # raw MX-28 speed units (0.114 rpm each), 0 = maximum
    control_hz: float = 40.0
    stream_timeout_s: float = 0.2
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
        for name, n in (
            ("motor_ids", 4),
            ("gear_ratio", 4),
            ("motor_inverted", 4),
            ("motor_zero_rad", 4),
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
        for name in ("control_hz", "stream_timeout_s", "spool_step_rad", "close_timeout_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"hand.{name}: must be > 0")

    def make(self, ctx: DeviceContext) -> Hand:
        self.check()
        return ReflexSFHand(self)


@dataclass(frozen=True)
class ServoReading:
    seq: int
    mono: float
    wall: float
    raw_position: np.ndarray  # (4,)
    motor: np.ndarray  # (4,) spool angles and preshape, rad
    load: np.ndarray  # (4,) signed fraction of max load (positive against closing)


def load_fraction(raw: np.ndarray, inverted: np.ndarray) -> np.ndarray:
    """Signed load as a fraction of the maximum: (raw & 0x3FF) / 1024, sign from bit 10."""
    return kinematics.load_signed(raw, inverted) / 1024.0


class ReflexSFHand(Hand):
    def __init__(self, cfg: ReflexSFConfig) -> None:
        self.cfg = cfg
        self.ids = [int(i) for i in cfg.motor_ids]
        self.gear = np.asarray(cfg.gear_ratio, dtype=np.float64)
        self.inverted = np.asarray(cfg.motor_inverted, dtype=np.float64)
        self.zero = np.asarray(cfg.motor_zero_rad, dtype=np.float64)
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
            r = self._read_all()
            if r is None:
                raise StreamLostError(
                    f"ReFlex SF: servos {self.ids} do not answer on {self.cfg.port}"
                )
            self._publish(r)
            # Hold where they are, then torque on, at the configured speed.
            self._write_goals(r[0], motion=False)
            for i in self.ids:
                self._write(2, i, ADDR_MOVING_SPEED, self.cfg.moving_speed)
                self._write(1, i, ADDR_TORQUE_ENABLE, 1)
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
        with self._bus:
            res, _err = fn(self._port, dxl_id, addr, int(value))
        if res != 0:
            self.warn("write_failed", f"ReFlex SF: write to servo {dxl_id} failed ({res})")
            raise StreamLostError(f"ReFlex SF: servo {dxl_id} did not take a write ({res})")

    def _read_all(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(raw positions, raw loads) of the 4 servos, or None if one does not answer."""
        pos, load = np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int64)
        for k, i in enumerate(self.ids):
            with self._bus:
                data, res, _err = self._ph.readTxRx(self._port, i, ADDR_PRESENT_POSITION, 6)
            if res != 0 or len(data) != 6:
                self.warn("read_failed", f"ReFlex SF: servo {i} did not answer a read ({res})")
                return None
            pos[k] = data[0] | data[1] << 8
            load[k] = data[4] | data[5] << 8
        return pos, load

    def _publish(self, r: tuple[np.ndarray, np.ndarray]) -> None:
        now = time.monotonic()
        with self._cond:
            seq = self._latest.seq + 1 if self._latest is not None else 0
            self._latest = ServoReading(
                seq,
                now,
                time.time(),
                r[0],
                kinematics.motor_angle(
                    r[0], self.gear, self.inverted, self.zero, kinematics.MX28_SCALE
                ),
                load_fraction(r[1], self.inverted),
            )
            self._last_ok, self._stale = now, False
            self._cond.notify_all()

    def _poll(self) -> None:
        period = 1.0 / self.cfg.control_hz
        next_t = time.monotonic()
        while self._running:
            try:
                r = self._read_all()
            except Exception:  # a broken port must not kill the thread silently
                log.exception("ReFlex SF: read failed")
                r = None
            if r is not None:
                self._publish(r)
            elif not self._stale and time.monotonic() - self._last_ok > self.cfg.stream_timeout_s:
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
        if latest is not None:
            with contextlib.suppress(StreamLostError, OSError):
                self._write_goals(latest.raw_position, motion=False)

    def _write_goals(self, raw: np.ndarray, motion: bool = True) -> None:
        """Goal positions of all four servos in one SYNC_WRITE; motion writes are refused once
        stopped (checked under the bus lock `stop()` also takes)."""
        import dynamixel_sdk as dxl

        sw = dxl.GroupSyncWrite(self._port, self._ph, ADDR_GOAL_POSITION, 2)
        for i, v in zip(self.ids, np.clip(raw, 0, 4095).tolist(), strict=True):
            sw.addParam(i, [int(v) & 0xFF, int(v) >> 8])
        with self._bus:
            if motion:
                self.stop_latch.check("ReFlex SF command")
            res = sw.txPacket()
        if res != 0:
            raise StreamLostError(f"ReFlex SF: goal write failed ({res})")

    def _goals(self, angles: np.ndarray) -> np.ndarray:
        return kinematics.motor_raw(
            angles, self.gear, self.inverted, self.zero, kinematics.MX28_SCALE, hi=4095
        )

    def _wait(self, after_seq: int, check_stop: bool = True) -> ServoReading:
        deadline = time.monotonic() + self.cfg.stream_timeout_s
        with self._cond:
            while True:
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

    def stop(self) -> None:
        self.stop_latch.set()
        r = self._latest
        if r is not None and self._port is not None:
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
        target = r.motor.copy()
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
        preshape = r.motor[3] if self._preshape_target is None else self._preshape_target
        step = CloseStep(r.motor[:N_FINGERS].copy(), np.ones(N_FINGERS, bool), ("",) * N_FINGERS)
        stall = StallDetector(cfg.stall_steps, cfg.stall_tolerance_rad)
        contact_load = np.asarray(cfg.contact_load[:N_FINGERS])
        deadline = time.monotonic() + cfg.close_timeout_s
        while step.active.any():
            if time.monotonic() > deadline:
                self._write_goals(r.raw_position)
                raise TimeoutError(f"ReFlex SF: guarded close took over {cfg.close_timeout_s} s")
            # Closing load is positive; pressing against something is contact.
            touching = r.load[:N_FINGERS] >= contact_load
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
        sites = kinematics.contact_sites(float(r.motor[3]), prox, dist)
        return Grasp(
            sensor_ids=ids,
            xyz=sites[ids].reshape(-1, 3),
            pressures=np.abs(r.load[touched]) * 1024.0,  # load units stand in for pressure
            finger_angles=prox,
            preshape=float(r.motor[3]),
        )
