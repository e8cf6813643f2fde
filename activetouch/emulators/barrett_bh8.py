"""A byte-level stand-in for a BarrettHand BH8-280/282 on a CAN bus: the four hand pucks (F1,
F2, F3 on nodes 11-13, the spread on 14), each with its tactile pad (the spread puck carries the
palm's), on a python-can bus (``interface="virtual"`` in tests). Written from protocol facts C
(libbarrett, pyHand), importing nothing from the drivers: it packs and parses bytes with its own
code, so a symmetric bug cannot hide in a shared codec.

What the pucks do here:
- they start asleep (STAT 0): only VERS, ROLE and STAT are answered until a SET STAT = 2 wakes
  them; the encoder counts from power-up, so a hand reads 0 wherever its fingers are until it
  is initialised (CMD HI = 13), which drives each motor to its open stop and zeroes it there;
- GETs are answered to feedback group 6 (``0x80|id, 0, value LE``, 6 bytes), GET P to group 3
  (22-bit primary, plus the secondary "breakaway" encoder when fitted), GET TACT in full mode
  and SET TACT = 2 with five full-format frames to group 9; SET TACT = 3 tares the pad;
- MODE 0 idles (the worm-geared fingers hold where they are), 3 holds, 4 runs at V counts/ms,
  5 moves to E; CMD 18 / 20 close / open, CMD 19 moves to E;
- what the fingers meet is a `BH8FingerModel`: by default a `FingerObject` (each inner link
  meets the object at `contact_angle`; the TorqueSwitch then breaks away and the motor keeps
  closing only the outer link, whose pad meets the object `tip_gap` rad later, presses (cells
  rise, the strain gauge rises) and stalls the motor `press_limit` rad further on); or the
  twin's hand in contact with a placed object (`rigs/bh8_twin_fingers.py`).

Faults on demand (`Faults`): lost frames (a fraction of everything the pucks send), silent
pucks, stuck tactile cells (full scale), bus-off (nothing sent or taken).
"""

from __future__ import annotations

import argparse
import logging
import math
import random
import signal
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

from activetouch.emulators.threaded import ThreadedEmulator

log = logging.getLogger(__name__)

# Emulator-side copies of the facts (deliberately not imported from the driver).
NODES = (11, 12, 13, 14)
SPREAD_NODE = 14
# Motor-puck property ids of firmware >= 145 (libbarrett property_list.cpp, pyHand).
PROPS = {
    "VERS": 0,
    "ROLE": 1,
    "SN": 2,
    "ID": 3,
    "STAT": 5,
    "MODE": 8,
    "SG": 25,
    "CMD": 29,
    "T": 42,
    "V": 44,
    "P": 48,
    "E": 52,
    "MT": 43,
    "CTS": 68,
    "HOLD": 77,
    "TSTOP": 78,
    "TACT": 106,
    "TACTID": 107,
}
ASLEEP_ANSWERS = ("VERS", "ROLE", "STAT")
GROUP_POSITION, GROUP_PROPERTY, GROUP_TACT_FULL = 3, 6, 9
MAX_FINGER = 195000
MAX_SPREAD = 36000
INNER_RATIO, OUTER_RATIO, SECONDARY_RATIO, SPREAD_RATIO = 125.0, 375.0, 50.0, 17.5


class BH8FingerModel(Protocol):
    """What the fingers meet. The emulator tells it the motors after every tick (`update`,
    motor radians from each finger's open stop, and the spread), then asks."""

    def update(self, motors: list[float], spread: float) -> None: ...

    def joints(self, finger: int, motor: float) -> tuple[float, float, float]:
        """(inner, outer, press) of finger 0-2 at this motor angle."""
        ...

    def stall_motor(self, finger: int) -> float:
        """The motor angle the finger cannot close past now (inf: none)."""
        ...

    def cells(self, pad: int) -> list[float]:
        """24 cell loads of pad 0-3 (F1-F3, palm) above the baseline, cell units."""
        ...

    def strain(self, finger: int) -> float:
        """SG units above the baseline."""
        ...


@dataclass
class FingerObject:
    """Where the object is for each finger (index 0 = F1 ... 2 = F3)."""

    contact_angle: list[float] = field(default_factory=lambda: [math.inf] * 3)  # inner rad
    tip_gap: list[float] = field(default_factory=lambda: [0.2] * 3)  # outer rad after breakaway
    press_limit: float = 0.15  # outer rad of pad compression at which the motor stalls
    pad_cells: list[list[int]] = field(default_factory=lambda: [[10, 13, 16]] * 3)
    pressure_gain: float = 60.0  # cell value (raw / 256) per rad of press
    strain_gain: float = 4000.0  # SG units per rad of press
    palm: dict[int, float] = field(default_factory=dict)  # palm cells under a constant load
    motors: list[float] = field(default_factory=lambda: [0.0] * 3)

    def update(self, motors: list[float], spread: float) -> None:
        self.motors = list(motors)

    def joints(self, finger: int, motor: float) -> tuple[float, float, float]:
        free_inner = motor / INNER_RATIO
        c = self.contact_angle[finger]
        if free_inner <= c:
            return free_inner, motor / OUTER_RATIO, 0.0
        outer = motor * (1 / INNER_RATIO + 1 / OUTER_RATIO) - c
        touch = c * INNER_RATIO / OUTER_RATIO + self.tip_gap[finger]
        return c, outer, max(0.0, outer - touch)

    def stall_motor(self, finger: int) -> float:
        c = self.contact_angle[finger]
        if not math.isfinite(c):
            return math.inf
        touch = c * INNER_RATIO / OUTER_RATIO + self.tip_gap[finger]
        return (touch + self.press_limit + c) / (1 / INNER_RATIO + 1 / OUTER_RATIO)

    def cells(self, pad: int) -> list[float]:
        vals = [0.0] * 24
        if pad == 3:
            for c, v in self.palm.items():
                vals[c] += v
            return vals
        press = self.joints(pad, self.motors[pad])[2]
        if press > 0:
            for c in self.pad_cells[pad]:
                vals[c] += self.pressure_gain * press
        return vals

    def strain(self, finger: int) -> float:
        return self.strain_gain * self.joints(finger, self.motors[finger])[2]


@dataclass
class Faults:
    loss: float = 0.0  # fraction of the frames the pucks send that are lost
    silent: list[int] = field(default_factory=list)  # puck ids that answer nothing
    stuck_cells: list[tuple[int, int]] = field(default_factory=list)  # (puck, cell) at 4095
    bus_off: bool = False  # nothing is taken or sent


@dataclass
class BH8EmulatorConfig:
    channel: str = "bh8-emulator"
    interface: str = "virtual"
    firmware: int = 175
    # Property name -> id this firmware answers to (None: the ids of firmware >= 145); to play
    # older pucks, e.g. firmware 143 has no TACTID.
    property_ids: dict[str, int] | None = None
    cts: int = 4096  # encoder counts per motor revolution
    secondary_encoders: bool = True
    strain: bool = True
    hold: int = 0  # HOLD: 0 -> a finished move idles
    start_counts: list[float] = field(default_factory=lambda: [30000.0, 30000.0, 30000.0, 9000.0])
    finger_speed: float = 250.0  # counts/ms of CMD moves (HI, open, close, trapezoidal)
    spread_speed: float = 60.0
    sg_baseline: list[int] = field(default_factory=lambda: [2000, 2010, 1990, 0])
    tact_baseline: float = 0.35  # cell value at rest before a tare
    tact_noise: float = 0.0  # std of cell noise, value units
    seed: int = 0
    tick_s: float = 0.002
    faults: Faults = field(default_factory=Faults)
    obj: FingerObject = field(default_factory=FingerObject)


@dataclass
class _Puck:
    node: int
    actual: float  # motor counts from the open stop
    zero: float  # actual at the encoder's zero (power-up, then the HI)
    inner_zero: float = 0.0  # inner angle at the secondary encoder's zero
    stat: int = 0
    mode: int = 0
    v: int = 0
    e: int = 0
    target: float | None = None  # trapezoidal target (actual counts)
    tact: int = 0
    tare: list[float] = field(default_factory=lambda: [0.0] * 24)
    initialized: bool = False
    initializing: bool = False
    props: dict[str, int] = field(default_factory=dict)


class BH8Emulator(ThreadedEmulator):
    """The four hand pucks on one python-can bus. Use as a context manager or start()/stop()."""

    def __init__(
        self, cfg: BH8EmulatorConfig | None = None, fingers: BH8FingerModel | None = None
    ) -> None:
        self.cfg = cfg or BH8EmulatorConfig()
        self.faults = self.cfg.faults
        self.fingers: BH8FingerModel = fingers if fingers is not None else self.cfg.obj
        self.cpr = self.cfg.cts / (2 * math.pi)
        self.props = dict(PROPS if self.cfg.property_ids is None else self.cfg.property_ids)
        self.pucks = {
            n: _Puck(node=n, actual=float(self.cfg.start_counts[i]), zero=0.0)
            for i, n in enumerate(NODES)
        }
        for p in self.pucks.values():
            p.zero = p.actual
            p.inner_zero = self._joints(p)[0] if p.node != SPREAD_NODE else 0.0
        self.counts = {
            "received": 0,
            "sent": 0,
            "lost": 0,
            "ignored_asleep": 0,
            "hi": 0,
            "motion_before_init": 0,
            "wakes": 0,
        }
        self._rng = random.Random(self.cfg.seed)
        self._bus: Any = None
        self._lock = threading.Lock()
        self._last = time.monotonic()

    # -- lifecycle ------------------------------------------------------------------------

    thread_name = "bh8-emulator"

    def _open(self) -> None:
        import can  # optional: only the CAN emulator needs python-can

        self._bus = can.Bus(
            interface=self.cfg.interface, channel=self.cfg.channel, receive_own_messages=False
        )
        self._last = time.monotonic()

    def _close(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def power_cycle(self) -> None:
        """The hand's power goes off and on: every puck asleep again, its encoder counting
        from where the finger now is, not initialised, idle."""
        with self._lock:
            for p in self.pucks.values():
                p.stat, p.mode, p.target, p.tact = 0, 0, None, 0
                p.initialized = p.initializing = False
                p.zero = p.actual
                if p.node != SPREAD_NODE:
                    p.inner_zero = self._joints(p)[0]
            self.counts["power_cycles"] = self.counts.get("power_cycles", 0) + 1

    # -- what tests look at -----------------------------------------------------------------

    def joints(self) -> dict[str, list[float]]:
        """Inner and outer angles of F1-F3 and the spread angle, rad (the true pose)."""
        with self._lock:
            inner, outer = [], []
            for n in NODES[:3]:
                i, o, _ = self._joints(self.pucks[n])
                inner.append(i)
                outer.append(o)
            spread = self.pucks[SPREAD_NODE].actual / self.cpr / SPREAD_RATIO
        return {"inner": inner, "outer": outer, "spread": [spread]}

    def moving(self) -> bool:
        with self._lock:
            return any(p.mode in (4, 5) for p in self.pucks.values())

    def initialized(self) -> bool:
        return all(p.initialized for p in self.pucks.values())

    # -- the finger model -----------------------------------------------------------------

    def _joints(self, p: _Puck) -> tuple[float, float, float]:
        """(inner, outer, press) of a finger puck at its motor counts."""
        return self.fingers.joints(NODES.index(p.node), p.actual / self.cpr)

    def _stall_counts(self, p: _Puck) -> float:
        if p.node == SPREAD_NODE:
            return MAX_SPREAD
        return min(float(MAX_FINGER), self.fingers.stall_motor(NODES.index(p.node)) * self.cpr)

    def _update_fingers(self) -> None:
        motors = [self.pucks[n].actual / self.cpr for n in NODES[:3]]
        self.fingers.update(motors, self.pucks[SPREAD_NODE].actual / self.cpr / SPREAD_RATIO)
        for n in NODES[:3]:  # a finger that stalled during this tick is where it stalled
            p = self.pucks[n]
            p.actual = min(p.actual, self._stall_counts(p))

    def _advance(self, dt_ms: float) -> None:
        for p in self.pucks.values():
            hi = self._stall_counts(p)
            speed = self.cfg.spread_speed if p.node == SPREAD_NODE else self.cfg.finger_speed
            if p.mode == 4:
                p.actual = min(hi, max(0.0, p.actual + p.v * dt_ms))
            elif p.mode == 5 and p.target is not None:
                goal = min(hi, max(0.0, p.target))
                step = speed * dt_ms
                if abs(goal - p.actual) <= step:
                    p.actual = goal
                    self._arrived(p)
                elif goal > p.actual:
                    p.actual = min(hi, p.actual + step)
                    if p.actual >= hi:
                        self._arrived(p)  # stalled on the object or at the stop
                else:
                    p.actual -= step

    def _arrived(self, p: _Puck) -> None:
        if p.initializing:
            p.initializing, p.initialized = False, True
            p.zero = p.actual
            if p.node != SPREAD_NODE:
                p.inner_zero = self._joints(p)[0]
        p.target = None
        p.mode = 3 if self.cfg.hold else 0

    # -- the bus --------------------------------------------------------------------------

    def _loop(self) -> None:
        while self._running:
            bus = self._bus
            if bus is None:
                return
            try:
                msg = bus.recv(timeout=self.cfg.tick_s)
            except Exception:  # a closed bus while stopping
                if not self._running:
                    return
                raise
            now = time.monotonic()
            with self._lock:
                self._advance((now - self._last) * 1000.0)
                self._update_fingers()
                self._last = now
                if msg is not None and not self.faults.bus_off:
                    self.counts["received"] += 1
                    try:
                        self._handle(msg.arbitration_id, bytes(msg.data))
                    except Exception:
                        log.exception("BH8 emulator: frame %s not handled", msg)

    def _send(self, node: int, group: int, data: bytes) -> None:
        if self.faults.bus_off or node in self.faults.silent:
            return
        if self.faults.loss and self._rng.random() < self.faults.loss:
            self.counts["lost"] += 1
            return
        # deferred: python-can only for the CAN hand
        import can

        arb = 0x400 | (node << 5) | group
        self._bus.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))
        self.counts["sent"] += 1

    def _handle(self, arb: int, data: bytes) -> None:
        if arb > 0x7FF or (arb >> 5) & 0x1F != 0 or not data:
            return  # only frames from the host (node 0)
        to = arb & 0x41F
        if to & 0x400:
            if to & 0x1F not in (0, 5):
                return
            targets = list(NODES)
        elif to in self.pucks:
            targets = [to]
        else:
            return
        for n in targets:
            if n in self.faults.silent:
                continue
            p = self.pucks[n]
            if data[0] & 0x80:
                if len(data) not in (4, 6):
                    continue
                raw = int.from_bytes(data[2:], "little")
                bits = 8 * (len(data) - 2)
                if raw & (1 << (bits - 1)):
                    raw -= 1 << bits
                self._set(p, data[0] & 0x7F, raw)
            else:
                self._get(p, data[0] & 0x7F)

    def _name(self, prop: int) -> str | None:
        for k, v in self.props.items():
            if v == prop:
                return k
        return None

    def _value(self, p: _Puck, name: str) -> int:
        f = NODES.index(p.node)
        if name == "VERS":
            return self.cfg.firmware
        if name == "ROLE":
            role = 5 | 0x1000  # BHAND with a tactile pad (the palm's on the spread puck)
            if self.cfg.strain and p.node != SPREAD_NODE:
                role |= 0x0800
            return role
        if name == "STAT":
            return p.stat
        if name == "ID":
            return p.node
        if name == "MODE":
            return p.mode
        if name == "CTS":
            return self.cfg.cts
        if name == "HOLD":
            return self.cfg.hold
        if name == "TACT":
            return p.tact
        if name == "TACTID":
            return 1
        if name == "SG":
            load = 0.0 if p.node == SPREAD_NODE else self.fingers.strain(f)
            return int(self.cfg.sg_baseline[f] + load)
        if name == "P":
            return round(p.actual - p.zero)
        if name == "E":
            return p.e
        if name == "V":
            return p.v
        return p.props.get(name, 0)

    def _get(self, p: _Puck, prop: int) -> None:
        name = self._name(prop)
        if name is None:
            return
        if p.stat != 2 and name not in ASLEEP_ANSWERS:
            self.counts["ignored_asleep"] += 1
            return
        if name == "P":
            self._send_position(p)
        elif name == "TACT" and p.tact == 2:
            self._send_tactile(p)
        else:
            v = self._value(p, name) & 0xFFFFFFFF
            self._send(p.node, GROUP_PROPERTY, bytes([0x80 | prop, 0]) + v.to_bytes(4, "little"))

    @staticmethod
    def _22(v: int) -> bytes:
        v &= 0x3FFFFF
        return bytes([(v >> 16) & 0x3F, (v >> 8) & 0xFF, v & 0xFF])

    def _send_position(self, p: _Puck) -> None:
        primary = round(p.actual - p.zero)
        data = self._22(primary)
        if self.cfg.secondary_encoders and p.node != SPREAD_NODE:
            inner = self._joints(p)[0]
            data += self._22(round((inner - p.inner_zero) * SECONDARY_RATIO * self.cpr))
        self._send(p.node, GROUP_POSITION, data)

    def _cells(self, p: _Puck) -> list[float]:
        loads = self.fingers.cells(NODES.index(p.node))
        vals = [self.cfg.tact_baseline + v for v in loads]
        if self.cfg.tact_noise:
            vals = [v + self._rng.gauss(0.0, self.cfg.tact_noise) for v in vals]
        return vals

    def _send_tactile(self, p: _Puck) -> None:
        vals = self._cells(p)
        raw = [max(0, min(4095, round((v - t) * 256))) for v, t in zip(vals, p.tare, strict=True)]
        for puck, cell in self.faults.stuck_cells:
            if puck == p.node:
                raw[cell] = 4095
        raw.append(0)  # the 25th slot of the last frame
        for s in range(5):
            c = raw[5 * s : 5 * s + 5]
            frame = bytes(
                [
                    (s << 4) | (c[0] >> 8),
                    c[0] & 0xFF,
                    c[1] >> 4,
                    ((c[1] & 0x0F) << 4) | (c[2] >> 8),
                    c[2] & 0xFF,
                    c[3] >> 4,
                    ((c[3] & 0x0F) << 4) | (c[4] >> 8),
                    c[4] & 0xFF,
                ]
            )
            self._send(p.node, GROUP_TACT_FULL, frame)

    def _set(self, p: _Puck, prop: int, value: int) -> None:
        name = self._name(prop)
        if name is None:
            return
        if p.stat != 2:
            if name == "STAT" and value == 2:
                p.stat = 2
                self.counts["wakes"] += 1
            else:
                self.counts["ignored_asleep"] += 1
            return
        if name == "STAT":
            p.stat = value
        elif name == "CMD":
            self._command(p, value)
        elif name == "MODE":
            self._mode(p, value)
        elif name == "E":
            p.e = value
        elif name == "V":
            p.v = value
        elif name == "TACT":
            if value == 3:
                p.tare = self._cells(p)
                p.tact = 0
            else:
                p.tact = value
                if value == 2:
                    self._send_tactile(p)
        else:
            p.props[name] = value

    def _motion(self, p: _Puck) -> None:
        if not p.initialized and not p.initializing:
            self.counts["motion_before_init"] += 1

    def _command(self, p: _Puck, cmd: int) -> None:
        if cmd == 13:  # HI: to the open stop, zero the encoder there
            self.counts["hi"] += 1
            p.initializing = True
            p.target, p.mode = 0.0, 5
        elif cmd == 18:  # close
            self._motion(p)
            p.target, p.mode = float(MAX_FINGER if p.node != SPREAD_NODE else MAX_SPREAD), 5
        elif cmd == 20:  # open
            self._motion(p)
            p.target, p.mode = p.zero, 5
        elif cmd == 19:  # move to E
            self._motion(p)
            p.target, p.mode = p.zero + p.e, 5

    def _mode(self, p: _Puck, mode: int) -> None:
        if mode in (4, 5):
            self._motion(p)
        if mode == 5:
            p.target = p.zero + p.e
        if mode in (0, 3):
            p.target = None
        p.mode = mode


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="activetouch emulate barrett-bh8",
        description="BH8 pucks on a CAN bus. A virtual bus lives in one process only: across "
        "processes use the kernel's vcan (ip link add dev vcan0 type vcan; ip link set vcan0 up).",
    )
    p.add_argument("--interface", default="socketcan", help="python-can interface")
    p.add_argument("--channel", default="vcan0", help="CAN channel (never the hand's can0)")
    p.add_argument(
        "--contact-angle",
        type=float,
        nargs=3,
        default=[math.inf] * 3,
        metavar=("F1", "F2", "F3"),
        help="inner-link angle, rad, where each finger meets the object (inf: nothing)",
    )
    p.add_argument("--tip-gap", type=float, default=0.2, help="outer rad from breakaway to touch")
    p.add_argument("--firmware", type=int, default=175)
    p.add_argument("--loss", type=float, default=0.0, help="fault: fraction of frames lost")
    p.add_argument("--silent", type=int, nargs="*", default=[], help="fault: pucks that are mute")
    p.add_argument("--no-secondary-encoders", action="store_true")
    return p


def config_from_args(a: argparse.Namespace) -> BH8EmulatorConfig:
    return BH8EmulatorConfig(
        interface=a.interface,
        channel=a.channel,
        firmware=a.firmware,
        secondary_encoders=not a.no_secondary_encoders,
        faults=Faults(loss=a.loss, silent=list(a.silent)),
        obj=FingerObject(contact_angle=list(a.contact_angle), tip_gap=[a.tip_gap] * 3),
    )


def main(argv: list[str] | None = None, done: threading.Event | None = None) -> int:
    """Run until SIGINT / SIGTERM (or `done`, for tests)."""
    a = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    if done is None:
        done = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: done.set())
    with BH8Emulator(config_from_args(a)):
        print(f"barrett-bh8 emulator on {a.interface} {a.channel}", flush=True)
        done.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
