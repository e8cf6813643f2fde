"""BarrettHand BH8-280/282 over CAN with python-can (``hand.type = "barrett-bh8"``).

Four pucks on the bus: F1, F2, F3 (nodes 11-13) and the spread (14), each with a tactile pad
(the spread puck carries the palm's). A receive thread decodes every frame; a poll thread asks
the hand group (0x405) once per control step for positions (GET P), fingertip strain (GET SG)
and a full tactile frame (SET TACT = 2), as libbarrett's ``Hand::update`` does, and publishes
one reading per step. Property ids are looked up per puck from its firmware version (VERS is
read first), as libbarrett does.

Safety (docs/drivers.md, "BarrettHand BH8"):
- connecting reads and wakes the pucks (STAT = 2, one at a time) and tares the pads; it sends
  no CMD, MODE, E, V or P: nothing moves. The hand is initialised (CMD HI, which drives every
  finger to its open stop and moves the spread) only by `initialize()`, which `connect` calls
  only with ``hand.initialize_on_connect = true``; before that every motion is refused with an
  error naming that setting;
- `stop()` idles the whole hand group in one frame (MODE 0; the worm-geared fingers hold where
  they are) from any thread, at once; a waiting close wakes and raises `StoppedError`;
- no position reply from a puck for ``hand.stream_timeout_s``: the readings are stale and every
  waiting command raises `StreamLostError` naming the puck;
- a reading that cannot be true (a position outside the puck's travel, a strain value outside
  its window, a wrong product role, a puck that will not wake) stops the hand with a
  `DeviceFaultError` naming the puck.

The guarded close runs each finger in velocity mode and idles it on its own pad's contact
(a cell above the tare by ``hand.contact_threshold``) or its strain gauge's load; the BH8's
TorqueSwitch has already stopped the inner link if it met the object first, so the finger
stops when the outer link's pad touches. Contacts are the pad cells above threshold, at the
positions `kinematics.cell_positions` gives for the measured spread, inner and outer angles.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from activetouch.device_types import HandConfig
from activetouch.drivers.barrett import codec
from activetouch.drivers.reflex.common import RateLimitedWarning, StreamLostError
from activetouch.errors import ActiveTouchError, ConfigError, DeviceFaultError, StoppedError
from activetouch.interfaces import Grasp, Hand, HandState, StopLatch
from activetouch.models import bh8 as kinematics

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext

log = logging.getLogger(__name__)

FINGERS = codec.HAND_PUCKS[:3]
INIT_SETTING = "hand.initialize_on_connect"


class NotInitializedError(ActiveTouchError):
    """A motion command before the hand was initialised (CMD HI moves every finger)."""


class PuckFaultError(DeviceFaultError):
    """A puck reading that cannot be true; the hand is idled and the message names the puck."""


@dataclass
class BarrettBH8Config(HandConfig):
    """Settings of a BarrettHand BH8-280/282 on a CAN bus (docs/drivers.md)."""

    family: ClassVar[str] = "bh8"

    can_interface: str = "socketcan"  # python-can interface; "virtual" for the emulator
    can_channel: str = "can0"
    bitrate: int = 1000000  # the BH8's bus runs at 1 Mbit/s
    # Initialisation (CMD HI) moves every finger and the spread: only when this is true.
    initialize_on_connect: bool = False
    control_period_s: float = 0.02  # one poll (positions, strain, tactile) per step
    stream_timeout_s: float = 0.3  # no position reply from a puck for this long: lost
    connect_timeout_s: float = 2.0
    reply_timeout_s: float = 0.2  # a property GET's reply ...
    reply_retries: int = 2  # ... asked again this many times before the puck counts as silent
    wake_gap_s: float = 0.01  # between STAT = 2 to each sleeping puck (libbarrett)
    wake_settle_s: float = 1.0  # after waking, before STAT is checked (libbarrett)
    done_poll_s: float = 0.05  # MODE poll while waiting for a move (libbarrett: 0.1 s)
    init_timeout_s: float = 20.0
    move_timeout_s: float = 10.0
    close_timeout_s: float = 10.0
    close_velocity: int = 100  # counts per ms in velocity mode (about 2 s for a full close)
    finger_limit_counts: int = 190000  # stop closing here (travel 195000)
    spread_limit_rad: float = 3.14
    stall_steps: int = 10  # a finger that moved < stall_counts in this many steps: stalled
    stall_counts: int = 200
    # Tactile: contact = value (raw / 256, the pad's N/cm2 as ROS drivers call it) above the
    # zero taken at connect by this much; strain: |SG - its zero| above this stops a finger.
    contact_threshold: float = 0.5
    strain_threshold: float = 150.0
    tare_readings: int = 5
    strain_window: list[int] = field(default_factory=lambda: [0, 4095])  # plausible raw SG
    position_margin_counts: int = 5000  # plausible: within travel by this margin
    open_tolerance_rad: float = 0.1  # "open": every inner link within this of 0
    use_secondary_encoders: bool = True  # the outer angle after breakaway needs them
    warn_interval_s: float = 5.0

    def check(self) -> None:
        if not self.can_interface:
            raise ConfigError("hand.can_interface: empty")
        if not self.can_channel:
            raise ConfigError("hand.can_channel: empty")
        if self.bitrate <= 0:
            raise ConfigError("hand.bitrate: must be > 0 (the BH8 uses 1000000)")
        for name in (
            "control_period_s",
            "stream_timeout_s",
            "connect_timeout_s",
            "reply_timeout_s",
            "close_timeout_s",
            "move_timeout_s",
            "init_timeout_s",
            "close_velocity",
            "tare_readings",
            "contact_threshold",
            "strain_threshold",
        ):
            if not getattr(self, name) > 0:
                raise ConfigError(f"hand.{name}: must be > 0")
        if self.stream_timeout_s <= self.control_period_s:
            raise ConfigError("hand.stream_timeout_s: must exceed hand.control_period_s")
        if len(self.strain_window) != 2 or self.strain_window[0] >= self.strain_window[1]:
            raise ConfigError("hand.strain_window: expected [low, high]")

    def make(self, ctx: DeviceContext) -> Hand:
        return BarrettBH8Hand(self)

    def default_settings(self) -> dict[str, dict[str, Any]] | None:
        return {k: dict(v) for k, v in kinematics.DEFAULT_SETTINGS.items()}


@dataclass
class Puck:
    node: int
    name: str
    vers: int = -1
    role: int = 0
    ids: codec.PropertyIds = field(default_factory=codec.PropertyIds)
    cpr: float = 4096 / (2 * np.pi)
    hold: int = 0
    strain: bool = False
    tact: bool = False


@dataclass(frozen=True)
class BH8HandState(HandState):
    """`HandState` (96 cells, inner angles, spread) plus the outer angles, raw encoder counts,
    strain above its zero, and the cells masked as stuck."""

    outer: np.ndarray = field(default_factory=lambda: np.zeros(3))
    counts: np.ndarray = field(default_factory=lambda: np.zeros(4))
    strain: np.ndarray = field(default_factory=lambda: np.zeros(3))
    masked: np.ndarray = field(default_factory=lambda: np.zeros(kinematics.N_CELLS, dtype=bool))


@dataclass
class Reading:
    seq: int
    mono: float
    counts: np.ndarray  # (4,) primary
    inner: np.ndarray  # (3,)
    outer: np.ndarray  # (3,)
    spread: float
    cells: np.ndarray  # (96,) raw / 256
    strain_raw: np.ndarray  # (3,)
    stale: tuple[str, ...]  # names of pucks whose positions are too old
    fresh: np.ndarray  # (4,) positions answered within the last two control steps


class BarrettBH8Hand(Hand):
    """The `Hand` of a BarrettHand BH8-280/282 on a CAN bus."""

    def __init__(self, cfg: BarrettBH8Config, bus: Any = None) -> None:
        self.cfg = cfg
        self.pucks = {n: Puck(n, codec.PUCK_NAMES[n]) for n in codec.HAND_PUCKS}
        self.stop_latch = StopLatch()
        self.warn = RateLimitedWarning(log, cfg.warn_interval_s)
        self.counts: dict[str, int] = {
            "received": 0,
            "accepted": 0,
            "ignored": 0,
            "refused": 0,
            "crashes": 0,
            "tactile_incomplete": 0,
            "readings": 0,
        }
        self.refused_by_reason: dict[str, int] = {}
        self.initialized = False
        self.fault: DeviceFaultError | None = None
        self.last_close_reasons: tuple[str, ...] = ()
        self.masked = np.zeros(kinematics.N_CELLS, dtype=bool)
        self._recognition_mask = np.zeros(kinematics.N_CELLS, dtype=bool)  # `mask_sensors`
        self._thresholds = np.full(kinematics.N_CELLS, float(cfg.contact_threshold))
        self.zero = np.zeros(kinematics.N_CELLS)
        self.strain_zero = np.zeros(3)
        self.tared = False
        self._bus: Any = bus
        self._own_bus = bus is None
        self._running = False
        self._rx: threading.Thread | None = None
        self._poll: threading.Thread | None = None
        self._poll_stop = threading.Event()
        self._cond = threading.Condition()
        self._tx_lock = threading.Lock()
        self._pending: dict[tuple[int, int], list[int]] = {}
        n = len(codec.HAND_PUCKS)
        self._pos = np.zeros(n, dtype=np.int64)
        self._sec: list[int | None] = [None] * n
        self._pos_t = np.full(n, -np.inf)
        self._sg = np.zeros(n)
        self._cells = np.zeros(kinematics.N_CELLS)
        self._asm = {p: codec.TactileAssembler() for p in codec.HAND_PUCKS}
        self._latest: Reading | None = None
        self._seq = 0

    @property
    def n_sensors(self) -> int:
        return kinematics.N_CELLS  # 96: sensor id = 24 * pad + cell

    # -- link -----------------------------------------------------------------------------

    def _open_bus(self) -> Any:
        try:
            # deferred: python-can only for the CAN hand
            import can
        except ImportError as e:  # pragma: no cover - a dependency
            raise ConfigError(f"hand.type barrett-bh8 needs python-can ({e})") from None
        cfg = self.cfg
        try:
            return can.Bus(
                interface=cfg.can_interface,
                channel=cfg.can_channel,
                bitrate=cfg.bitrate,
                receive_own_messages=False,
            )
        except can.exceptions.CanInterfaceNotImplementedError as e:
            raise ConfigError(
                f"hand.can_interface: {cfg.can_interface!r} is not a python-can interface ({e})"
            ) from None
        except (can.CanError, OSError, ValueError) as e:
            raise StreamLostError(
                f"BH8: cannot open CAN {cfg.can_interface} {cfg.can_channel} ({e}): is the "
                f"adapter plugged in and the link up? `ip link set {cfg.can_channel} type can "
                f"bitrate {cfg.bitrate}` then `ip link set {cfg.can_channel} up`"
            ) from None

    def connect(self) -> None:
        """Open the bus, read VERS and ROLE, wake the pucks, read CTS and HOLD, tare the pads
        and the strain gauges. Nothing moves unless ``hand.initialize_on_connect``."""
        if self._running:
            return
        if self._bus is None:
            self._bus = self._open_bus()
        with self._cond:  # nothing from an earlier connection is served as new
            self._latest = None
            self._pos_t[:] = -np.inf
            self._asm = {p: codec.TactileAssembler() for p in codec.HAND_PUCKS}
        self._running = True
        self._rx = threading.Thread(target=self._rx_loop, name="bh8-rx", daemon=True)
        self._rx.start()
        try:
            self._identify()
            self._wake()
            self._configure()
            self._poll_stop.clear()
            self._poll = threading.Thread(target=self._poll_loop, name="bh8-poll", daemon=True)
            self._poll.start()
            self._wait_reading(-1, self.cfg.connect_timeout_s, check_stop=False, wait_stale=True)
            self._tare()
            if self.cfg.initialize_on_connect:
                self.initialize()
        except BaseException:
            self.disconnect(idle=False)
            raise

    def disconnect(self, idle: bool = True) -> None:
        if idle and self._running and self.fault is None:
            with contextlib.suppress(Exception):
                self._idle_all()
        self._poll_stop.set()
        if self._poll is not None:
            self._poll.join(timeout=2.0)
            self._poll = None
        self._running = False
        if self._rx is not None:
            self._rx.join(timeout=2.0)
            self._rx = None
        if self._bus is not None and self._own_bus:
            with contextlib.suppress(Exception):
                self._bus.shutdown()
            self._bus = None
        with self._cond:
            self._cond.notify_all()

    def _identify(self) -> None:
        for p in self.pucks.values():
            p.vers = self._get(p.node, codec.VERS_ID, what="VERS")
            p.role = self._get(p.node, codec.ROLE_ID, what="ROLE")
            if p.role & codec.ROLE_MASK != codec.ROLE_BHAND:
                raise self._fault(
                    PuckFaultError(
                        f"BH8: {p.name} reports ROLE {p.role:#x}, not a BarrettHand puck "
                        "(product 5): is this the hand's bus?"
                    )
                )
            try:
                p.ids = codec.property_ids(p.vers)
            except codec.FirmwareError as e:
                raise self._fault(PuckFaultError(f"BH8: {p.name}: {e}")) from None
            p.strain = bool(p.role & codec.RO_STRAIN) and p.node in FINGERS
            p.tact = bool(p.role & codec.RO_TACT) and p.ids.TACT >= 0

    def _wake(self) -> None:
        asleep = [p for p in self.pucks.values() if self._get(p.node, codec.STAT_ID, "STAT") != 2]
        if not asleep:
            return
        if self.initialized:
            # Asleep again: the pucks were reset (a power cycle), their encoders count from
            # wherever the fingers are now. The HI zero is gone: motion is refused until the
            # hand is initialised again.
            self.initialized = False
            log.warning(
                "BH8: %s asleep at connect (reset since the last connection): the hand must "
                "be initialised again (%s or initialize())",
                ", ".join(p.name for p in asleep),
                INIT_SETTING,
            )
        for p in asleep:
            self._send(p.node, codec.encode_set(codec.STAT_ID, codec.STATUS_READY))
            time.sleep(self.cfg.wake_gap_s)
        time.sleep(self.cfg.wake_settle_s)
        for p in asleep:
            stat = self._get(p.node, codec.STAT_ID, "STAT")
            if stat != codec.STATUS_READY:
                raise self._fault(
                    PuckFaultError(f"BH8: {p.name} did not wake (STAT {stat} after STAT = 2)")
                )

    def _configure(self) -> None:
        for p in self.pucks.values():
            cts = self._get(p.node, p.ids.CTS, "CTS")
            if cts <= 0 or cts > 1 << 20:
                raise self._fault(PuckFaultError(f"BH8: {p.name} reports CTS {cts}"))
            p.cpr = codec.counts_per_rad(cts)
            p.hold = self._get(p.node, p.ids.HOLD, "HOLD") if p.ids.HOLD >= 0 else 0
            if p.tact:
                tactid = self._get(p.node, p.ids.TACTID, "TACTID") if p.ids.TACTID >= 0 else 0
                if tactid == -2:
                    log.warning("BH8: %s tactile pad reports an init error: disabled", p.name)
                    p.tact = False
                    continue
                # libbarrett's tactile set-up: TACT none, then tare on the puck.
                self._send(p.node, codec.encode_set(p.ids.TACT, codec.TACT_NONE))
                self._send(p.node, codec.encode_set(p.ids.TACT, codec.TACT_TARE))
        if not any(self.pucks[n].tact for n in FINGERS):
            log.warning("BH8: no fingertip tactile pad: fingers stop on strain only")

    def _tare(self) -> None:
        """Zero the 96 cells and the strain gauges on `tare_readings` readings; cells at full
        scale then are stuck: masked (never reported) with a warning."""
        r = self._latest
        seq = -1 if r is None else r.seq
        cells, strain = [], []
        for _ in range(self.cfg.tare_readings):
            r = self._wait_reading(seq, self.cfg.stream_timeout_s, check_stop=False)
            seq = r.seq
            cells.append(r.cells)
            strain.append(r.strain_raw)
        with self._cond:
            self.zero = np.mean(cells, axis=0)
            self.strain_zero = np.mean(strain, axis=0)
            stuck = np.max(cells, axis=0) >= codec.TACT_MAX - 1e-9
            self.masked = stuck
            self.tared = True
        if stuck.any():
            log.warning("BH8: cells %s read full scale at tare: masked", np.flatnonzero(stuck))

    # -- frames ---------------------------------------------------------------------------

    def _send(self, to: int, data: bytes, motion: bool = False) -> None:
        # deferred: python-can only for the CAN hand
        import can

        with self._tx_lock:
            if motion:
                if self.fault is not None:
                    raise self.fault
                self.stop_latch.check("BH8 command")
            if self._bus is None:
                raise StreamLostError("BH8: not connected")
            msg = can.Message(arbitration_id=codec.node_id(to), data=data, is_extended_id=False)
            try:
                self._bus.send(msg, timeout=self.cfg.reply_timeout_s)
            except can.CanError as e:
                raise StreamLostError(f"BH8: CAN send failed ({e}): bus-off?") from None

    def _get(self, node: int, prop: int, what: str) -> int:
        """A property of one puck, synchronously (its reply on group 6), asked up to
        1 + `reply_retries` times (a frame may be lost)."""
        if prop < 0:
            raise ValueError(f"BH8: {self.pucks[node].name} has no property {what}")
        for _ in range(self.cfg.reply_retries):
            with contextlib.suppress(StreamLostError):
                return self._get_once(node, prop, what)
            if not self._running:
                break
        return self._get_once(node, prop, what)

    def _get_once(self, node: int, prop: int, what: str) -> int:
        key = (node, prop)
        with self._cond:
            self._pending[key] = []
        try:
            self._send(node, codec.encode_get(prop))
            deadline = time.monotonic() + self.cfg.reply_timeout_s
            with self._cond:
                while not self._pending[key]:
                    left = deadline - time.monotonic()
                    if left <= 0 or not self._running:
                        raise StreamLostError(
                            f"BH8: no reply from {self.pucks[node].name} to GET {what} within "
                            f"{self.cfg.reply_timeout_s:.3g} s (is the puck powered, the bus "
                            "terminated?)"
                        )
                    self._cond.wait(left)
                return self._pending[key][0]
        finally:
            with self._cond:
                self._pending.pop(key, None)

    def _rx_loop(self) -> None:
        while self._running:
            bus = self._bus
            if bus is None:
                return
            try:
                msg = bus.recv(timeout=0.05)
            except Exception as e:  # the bus went away
                if self._running:
                    self.warn("rx_error", f"BH8: CAN receive failed ({e})")
                    time.sleep(0.05)
                continue
            if msg is None:
                continue
            # received and its verdict are counted under one lock so stats() never sees a
            # frame received but not yet classified
            try:
                verdict = self._on_frame(msg)
            except codec.FrameError as e:
                with self._cond:
                    self.counts["received"] += 1
                    self.counts["refused"] += 1
                    self.refused_by_reason[e.reason] = self.refused_by_reason.get(e.reason, 0) + 1
            except Exception:  # never end the receive thread on a frame
                with self._cond:
                    self.counts["received"] += 1
                    self.counts["crashes"] += 1
                log.exception("BH8: frame %s crashed the decoder", msg)
            else:
                with self._cond:
                    self.counts["received"] += 1
                    self.counts[verdict] += 1

    def _on_frame(self, msg: Any) -> str:
        """Decode one frame into the hand's state; returns "accepted" or "ignored", raises
        FrameError for a frame that cannot be right."""
        if msg.is_error_frame or msg.is_remote_frame:
            raise codec.FrameError("frame_type", "error or remote frame")
        if msg.is_extended_id:
            raise codec.FrameError("extended_id", "29-bit id on the hand's bus")
        b = codec.decode_bus_id(msg.arbitration_id)
        data = bytes(msg.data)
        if b.src not in self.pucks or not b.group:
            return "ignored"
        i = codec.HAND_PUCKS.index(b.src)
        now = time.monotonic()
        if b.dst == codec.FGRP_POSITION:
            primary, secondary = codec.decode_position(data)
            with self._cond:
                self._pos[i], self._sec[i], self._pos_t[i] = primary, secondary, now
        elif b.dst == codec.FGRP_PROPERTY:
            prop, value = codec.decode_property(data)
            with self._cond:
                p = self.pucks[b.src]
                if prop == p.ids.SG:
                    self._sg[i] = value
                key = (b.src, prop)
                if key in self._pending:
                    self._pending[key].append(value)
                    self._cond.notify_all()
        elif b.dst == codec.FGRP_TACT_FULL:
            asm = self._asm[b.src]
            before = asm.incomplete
            cells = asm.add(data)
            with self._cond:
                self.counts["tactile_incomplete"] += asm.incomplete - before
                if cells is not None:
                    self._cells[24 * i : 24 * i + 24] = cells
        else:
            return "ignored"
        return "accepted"

    def _poll_loop(self) -> None:
        period = self.cfg.control_period_s
        any_sg = [p for p in self.pucks.values() if p.strain]
        any_tact = [p for p in self.pucks.values() if p.tact]
        ids = self.pucks[codec.F1].ids
        while not self._poll_stop.is_set():
            try:
                self._send(codec.GROUP_HAND, codec.encode_get(ids.P))
                if any_sg:
                    self._send(codec.GROUP_HAND, codec.encode_get(ids.SG))
                if any_tact:
                    self._send(codec.GROUP_HAND, codec.encode_set(ids.TACT, codec.TACT_FULL))
            except StreamLostError as e:
                self.warn("tx", str(e))
            if self._poll_stop.wait(period):
                return
            try:
                self._publish()
            except Exception:  # a reading must not end the poll thread
                with self._cond:
                    self.counts["crashes"] += 1
                log.exception("BH8: reading failed")

    def _publish(self) -> None:
        now = time.monotonic()
        with self._cond:
            pos, sec = self._pos.copy(), list(self._sec)
            age = now - self._pos_t
            cells, sg = self._cells.copy(), self._sg[:3].copy()
        stale = tuple(
            self.pucks[n].name
            for k, n in enumerate(codec.HAND_PUCKS)
            if age[k] > self.cfg.stream_timeout_s
        )
        inner, outer = np.zeros(3), np.zeros(3)
        for k, n in enumerate(FINGERS):
            inner[k], outer[k] = codec.finger_joints(
                int(pos[k]), sec[k], self.pucks[n].cpr, self.cfg.use_secondary_encoders
            )
        spread = codec.spread_angle(int(pos[3]), self.pucks[codec.SPREAD].cpr)
        self._check_plausible(pos, sg, stale)
        with self._cond:
            self._seq += 1
            self._latest = Reading(
                seq=self._seq,
                mono=now,
                counts=pos,
                inner=inner,
                outer=outer,
                spread=spread,
                cells=cells,
                strain_raw=sg,
                stale=stale,
                fresh=age <= 2 * self.cfg.control_period_s + 0.01,
            )
            self.counts["readings"] += 1
            self._cond.notify_all()

    def _check_plausible(self, pos: np.ndarray, sg: np.ndarray, stale: tuple[str, ...]) -> None:
        if self.fault is not None:
            return
        m = self.cfg.position_margin_counts
        for k, n in enumerate(codec.HAND_PUCKS):
            p = self.pucks[n]
            if p.name in stale:
                continue
            travel = codec.MAX_SPREAD_COUNTS if n == codec.SPREAD else codec.MAX_FINGER_COUNTS
            lo = -m if self.initialized else -(travel + m)
            if not lo <= int(pos[k]) <= travel + m:
                self._fault(
                    PuckFaultError(
                        f"BH8: {p.name} reports position {int(pos[k])} counts, outside its "
                        f"travel {lo}..{travel + m}: hand idled (check the puck and its "
                        "encoder; re-initialise)"
                    )
                )
                return
        lo, hi = self.cfg.strain_window
        for k, n in enumerate(FINGERS):
            p = self.pucks[n]
            if p.strain and p.name not in stale and not lo <= sg[k] <= hi:
                self._fault(
                    PuckFaultError(
                        f"BH8: {p.name} strain gauge reads {int(sg[k])}, outside {lo}..{hi}: "
                        "hand idled (check the fingertip's strain gauge and its cable)"
                    )
                )
                return

    def _fault(self, err: DeviceFaultError) -> DeviceFaultError:
        with self._cond:
            first = self.fault is None
            if first:
                self.fault = err
            self.stop_latch.set()
            self._cond.notify_all()
        if first:
            log.error("%s", err)
            if self._running:
                with contextlib.suppress(Exception):
                    self._idle_all()
        return self.fault or err

    def _idle_all(self) -> None:
        self._send(codec.GROUP_HAND, codec.encode_set(self.pucks[codec.F1].ids.MODE, 0))

    def wait_fresh_reading(self) -> None:
        """Return once a whole reading asked for after this call has come in (one in flight
        may have been asked for before): StreamLostError if none does in time."""
        with self._cond:
            seq = self._latest.seq if self._latest is not None else -1
        r = self._wait_reading(seq, 2 * self.cfg.stream_timeout_s)
        self._wait_reading(r.seq, 2 * self.cfg.stream_timeout_s)

    def _wait_reading(
        self, after_seq: int, timeout: float, check_stop: bool = True, wait_stale: bool = False
    ) -> Reading:
        """The first reading newer than `after_seq`: StoppedError on a stop (if
        `check_stop`), the latched fault, StreamLostError naming the pucks whose positions are
        too old (at once, or at the deadline with `wait_stale`) or if none comes in time."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                if self.fault is not None:
                    raise self.fault
                if check_stop and self.stop_latch.is_set:
                    raise StoppedError("BH8: stopped")
                r = self._latest
                left = deadline - time.monotonic()
                if r is not None and r.seq > after_seq:
                    if r.stale and wait_stale and left > 0:
                        after_seq = r.seq
                    elif r.stale:
                        raise StreamLostError(
                            f"BH8: no position from {', '.join(r.stale)} within "
                            f"{self.cfg.stream_timeout_s:.3g} s (puck silent or bus down)"
                        )
                    else:
                        return r
                if left <= 0 or not self._running:
                    silent = f" from {', '.join(r.stale)}" if r is not None and r.stale else ""
                    raise StreamLostError(
                        f"BH8: no reading{silent} within {timeout:.3g} s on "
                        f"{self.cfg.can_channel} (puck silent or bus down)"
                    )
                self._cond.wait(min(left, 0.05))

    def stats(self) -> dict[str, int]:
        """Frame counters: received = accepted + ignored + refused (+ crashes, always 0 unless
        a bug), and refusals by reason (``refused:<reason>``)."""
        with self._cond:
            out = dict(self.counts)
            out.update({f"refused:{k}": v for k, v in self.refused_by_reason.items()})
            return out

    # -- motion helpers -------------------------------------------------------------------

    def _require_motion(self, what: str, check_stop: bool = True) -> None:
        if self.fault is not None:
            raise self.fault
        if not self._running:
            raise StreamLostError("BH8: not connected")
        if not self.initialized:
            raise NotInitializedError(
                f"BH8: {what} refused: the hand is not initialised. Initialising (CMD HI) "
                f"moves every finger and the spread: set {INIT_SETTING} = true (or call "
                "initialize()) with the hand clear of people and objects"
            )
        if check_stop:
            self.stop_latch.check(what)

    def _set(self, node: int, name: str, value: int, motion: bool = True) -> None:
        pid = getattr(self.pucks[node].ids, name)
        self._send(node, codec.encode_set(pid, value), motion=motion)

    def _done_moving(self, nodes: list[int]) -> bool:
        for n in nodes:
            mode = self._get(n, self.pucks[n].ids.MODE, "MODE")
            if mode != codec.MODE_IDLE and not (mode == codec.MODE_PID and self.pucks[n].hold):
                return False
        return True

    def _wait_done(self, nodes: list[int], timeout: float, what: str, check_stop: bool) -> None:
        deadline = time.monotonic() + timeout
        while True:
            if self.fault is not None:
                raise self.fault
            if check_stop and self.stop_latch.is_set:
                raise StoppedError(f"BH8: {what} stopped")
            if self._done_moving(nodes):
                # Readings after the move: state() and the next command see where it ended.
                latest = self._latest
                r = self._wait_reading(-1 if latest is None else latest.seq, 1.0, check_stop)
                self._wait_reading(r.seq, self.cfg.stream_timeout_s, check_stop)
                return
            if time.monotonic() > deadline:
                self._idle_all()
                raise TimeoutError(f"BH8: {what} not done within {timeout:.3g} s")
            self.stop_latch.wait(self.cfg.done_poll_s)

    # -- Hand interface -------------------------------------------------------------------

    def initialize(self) -> None:
        """CMD HI to F1-F3, wait until done, then to the spread (libbarrett's order). Moves
        every finger to its open stop and the spread: the caller makes sure that is safe."""
        if self.fault is not None:
            raise self.fault
        self.stop_latch.check("BH8 initialise")
        for n in FINGERS:
            self._set(n, "CMD", codec.CMD_HI)
        self._wait_done(list(FINGERS), self.cfg.init_timeout_s, "initialise", True)
        self._set(codec.SPREAD, "CMD", codec.CMD_HI)
        self._wait_done([codec.SPREAD], self.cfg.init_timeout_s, "initialise", True)
        # (_wait_done waited for positions read after the HI, counted from the open stops
        # now, before the tighter plausibility window of an initialised hand applies.)
        self.initialized = True
        log.info("BH8: initialised (HI); taring the pads with the hand open")
        self._tare()

    def stop(self) -> None:
        self.stop_latch.set()
        if self._running and self._bus is not None:
            try:
                self._idle_all()
            except (StreamLostError, OSError):
                log.warning("BH8: could not send the idle command on stop", exc_info=True)
        with self._cond:
            self._cond.notify_all()

    def clear_stop(self) -> None:
        self.stop_latch.clear()

    def state(self) -> BH8HandState:
        r = self._latest
        if r is None:
            return BH8HandState(
                pressures=np.zeros(kinematics.N_CELLS),
                contact=np.zeros(kinematics.N_CELLS, dtype=bool),
                finger_angles=np.zeros(3),
                preshape=0.0,
                stamp=0.0,
                stale=True,
            )
        pressures = r.cells - self.zero
        return BH8HandState(
            pressures=pressures,
            contact=self._contact(r),
            finger_angles=r.inner.copy(),
            preshape=r.spread,
            stamp=r.mono,
            stale=bool(r.stale) or time.monotonic() - r.mono > self.cfg.stream_timeout_s,
            outer=r.outer.copy(),
            counts=r.counts.astype(np.float64),
            strain=r.strain_raw - self.strain_zero,
            masked=self.masked.copy(),
        )

    def _contact(self, r: Reading) -> np.ndarray:
        if not self.tared:
            return np.zeros(kinematics.N_CELLS, dtype=bool)
        over = (r.cells - self.zero) >= self._thresholds
        return over & ~self.masked & ~self._recognition_mask

    def mask_sensors(self, sensor_ids: Sequence[int]) -> bool:
        """Ignore these cells (replacing an earlier mask): no finger stops on them and no
        grasp reports them. Cells masked as stuck stay masked."""
        ids = np.asarray(list(sensor_ids), dtype=np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= kinematics.N_CELLS):
            raise ValueError(f"cell ids must be 0..{kinematics.N_CELLS - 1}, got {ids.tolist()}")
        mask = np.zeros(kinematics.N_CELLS, dtype=bool)
        mask[ids] = True
        self._recognition_mask = mask
        return True

    def set_contact_thresholds(self, thresholds: Sequence[float]) -> bool:
        """Per-cell contact thresholds above the tare (never under `contact_threshold`)."""
        t = np.asarray(list(thresholds), dtype=np.float64)
        if t.shape != (kinematics.N_CELLS,) or not np.all(np.isfinite(t)):
            raise ValueError(f"contact thresholds must be {kinematics.N_CELLS} finite values")
        self._thresholds = np.maximum(t, self.cfg.contact_threshold)
        return True

    def own_contact_thresholds(self) -> np.ndarray:
        return np.full(kinematics.N_CELLS, float(self.cfg.contact_threshold))

    def sensor_sites(self) -> np.ndarray | None:
        r = self._latest
        return None if r is None else self._sites(r)

    @staticmethod
    def _sites(r: Reading) -> np.ndarray:
        """(96, 3) the cells' hand-frame positions at reading `r`'s joint angles."""
        return kinematics.cell_positions(r.spread, r.inner, r.outer)

    def open(self) -> None:
        """Fingers to their open stop (CMD OPEN), spread unchanged; allowed while stopped."""
        self._require_motion("open", check_stop=False)
        was_stopped = self.stop_latch.is_set
        for n in FINGERS:
            self._set(n, "CMD", codec.CMD_OPEN, motion=False)
        self._wait_done(list(FINGERS), self.cfg.move_timeout_s, "open", check_stop=False)
        if self.stop_latch.is_set and not was_stopped:
            raise StoppedError("BH8: open stopped")

    def preshape(self, angle: float) -> None:
        """Spread F1 and F2 to `angle` rad (0 .. about pi) with a trapezoidal move."""
        self._require_motion("preshape")
        a = float(angle)
        if not 0.0 <= a <= self.cfg.spread_limit_rad:
            raise ValueError(f"preshape {a} rad is outside 0..{self.cfg.spread_limit_rad}")
        p = self.pucks[codec.SPREAD]
        self._set(p.node, "E", codec.spread_counts(a, p.cpr))
        self._set(p.node, "MODE", codec.MODE_TRAPEZOIDAL)
        self._wait_done([p.node], self.cfg.move_timeout_s, "preshape", check_stop=True)

    def _mask_stuck(self, r: Reading) -> None:
        """Before a close with the fingers open: a cell at full scale is stuck (nothing can
        press it then): masked for good, with a warning."""
        if not np.all(np.abs(r.inner) <= self.cfg.open_tolerance_rad):
            return
        stuck = (r.cells >= codec.TACT_MAX - 1e-9) & ~self.masked
        if stuck.any():
            with self._cond:
                self.masked |= stuck
            self.warn(
                "stuck_cell",
                f"BH8: cells {np.flatnonzero(stuck).tolist()} read full scale with the hand "
                "open: stuck, masked (never reported)",
            )

    def guarded_close(self) -> Grasp:
        cfg = self.cfg
        self._require_motion("guarded close")
        r = self._wait_reading(
            -1 if self._latest is None else self._latest.seq, cfg.stream_timeout_s
        )
        self._mask_stuck(r)
        active = np.ones(3, dtype=bool)
        reasons = ["", "", ""]
        history: list[np.ndarray] = []
        # The first decision from a fresh reading: a finger already touching does not move.
        for k in range(3):
            why = self._finger_stop(k, r)
            if why:
                active[k], reasons[k] = False, why
        for k, n in enumerate(FINGERS):
            if active[k]:
                self._set(n, "V", int(cfg.close_velocity))
                self._set(n, "MODE", codec.MODE_VELOCITY)
        deadline = time.monotonic() + cfg.close_timeout_s
        try:
            while active.any():
                r = self._wait_reading(r.seq, cfg.stream_timeout_s)
                if not r.fresh[:3].all():
                    continue  # no stall verdict on old positions (a lost stream raises)
                history.append(r.counts[:3].copy())
                if len(history) > cfg.stall_steps + 1:
                    history.pop(0)
                stalled = (
                    (history[-1] - history[0]) < cfg.stall_counts
                    if len(history) > cfg.stall_steps
                    else np.zeros(3, dtype=bool)
                )
                for k, n in enumerate(FINGERS):
                    if not active[k]:
                        continue
                    why = self._finger_stop(k, r)
                    if not why and r.counts[k] >= cfg.finger_limit_counts:
                        why = "limit"
                    if not why and stalled[k]:
                        why = "stall"
                    if why:
                        self._set(n, "MODE", codec.MODE_IDLE, motion=False)
                        active[k], reasons[k] = False, why
                if active.any() and time.monotonic() > deadline:
                    raise TimeoutError(f"BH8: guarded close took over {cfg.close_timeout_s} s")
        except BaseException:
            with contextlib.suppress(Exception):
                self._idle_all()
            raise
        self.last_close_reasons = tuple(reasons)
        r = self._wait_reading(r.seq, cfg.stream_timeout_s)  # read at the final pose
        contact = self._contact(r)
        ids = np.flatnonzero(contact)
        sites = self._sites(r)
        return Grasp(
            sensor_ids=ids,
            xyz=sites[ids],
            pressures=(r.cells - self.zero)[ids],
            finger_angles=r.inner.copy(),
            preshape=r.spread,
        )

    def _finger_stop(self, k: int, r: Reading) -> str:
        """Why finger k stops now ("" if it goes on): its own pad's contact or its strain."""
        pad = self._contact(r)[24 * k : 24 * k + 24]
        if pad.any():
            return "contact"
        p = self.pucks[FINGERS[k]]
        if p.strain and abs(r.strain_raw[k] - self.strain_zero[k]) >= self.cfg.strain_threshold:
            return "strain"
        return ""
