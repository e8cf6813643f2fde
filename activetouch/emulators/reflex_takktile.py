"""A byte-level stand-in for the ReFlex TakkTile board: state packets at 40 Hz over UDP, command
packets obeyed, faults on demand.

It packs and parses bytes with its own code written from the published layout (offsets below,
from reflex-ros-pkg ``firmware/reflex-takktile/state.h``), never with the driver's codec, so a
symmetric bug in one cannot hide in both.

What moves the fingers is a `FingerModel`: `KinematicFingers` (here; each finger meets the
object at a given spool angle, after which its proximal link holds and its pads press in) or an
adapter to the PyBullet twin (`twin_fingers`), both answering "at these spool angles and this
preshape, what are the joint angles and the 38 forces in sensor units".
"""

from __future__ import annotations

import logging
import math
import random
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

log = logging.getLogger(__name__)

# Byte offsets of the 202-byte state packet (little-endian).
OFF_HEADER, OFF_SYSTIME, OFF_PRESSURE, OFF_TEMPERATURE = 0, 4, 8, 84
OFF_ENCODER, OFF_DXL_ERROR, OFF_DXL_POS, OFF_DXL_SPEED = 160, 166, 170, 178
OFF_DXL_LOAD, OFF_DXL_VOLT, OFF_DXL_TEMP, PACKET_LEN = 186, 194, 198, 202

# The board's tactile ports in wire order: pointer (finger 0), thumb (finger 2), middle
# (finger 1), then the palm. Emulator-side copy of the fact, deliberately not imported.
WIRE_PORT_FINGER = (0, 2, 1)

POS_TICK = 4 * 2 * math.pi / 4095  # rad per servo tick with resolution divider 4
ENC_TICK = 2 * math.pi / 16383


class FingerModel(Protocol):
    def joints(self, spool: np.ndarray, preshape: float) -> tuple[np.ndarray, np.ndarray]:
        """(proximal (3,), distal (3,)) for spool angles (3,)."""

    def forces(self, spool: np.ndarray, preshape: float) -> np.ndarray:
        """(38,) sensor readings above zero (by package sensor id) at these spools."""

    def stall_spool(self) -> np.ndarray:
        """(3,) spool beyond which a finger's servo cannot turn (object or limit)."""


@dataclass
class KinematicFingers:
    """Fingers closing on an object each meets at `contact_spool[f]` (inf: nothing there).
    A free finger bends proximal = spool / (1 + k), distal = k * proximal; past contact the
    proximal holds, the distal takes the rest, and the pads `contact_sensors[f]` press with
    `gain` units per rad until the servo stalls `press_rad` beyond contact."""

    contact_spool: list[float] = field(default_factory=lambda: [math.inf] * 3)
    contact_sensors: list[list[int]] = field(default_factory=lambda: [[2, 3], [11, 12], [20, 21]])
    gain: float = 400.0
    press_rad: float = 0.25
    coupling: float = 0.25
    spool_limit: float = 3.6

    def joints(self, spool: np.ndarray, preshape: float) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.contact_spool, dtype=np.float64)
        held = np.minimum(spool, c)
        prox = held / (1 + self.coupling)
        return prox, spool - prox

    def forces(self, spool: np.ndarray, preshape: float) -> np.ndarray:
        out = np.zeros(38)
        for f in range(3):
            press = spool[f] - self.contact_spool[f]
            if press > 0:
                out[self.contact_sensors[f]] = self.gain * press
        return out

    def stall_spool(self) -> np.ndarray:
        c = np.asarray(self.contact_spool, dtype=np.float64)
        return np.minimum(c + self.press_rad, self.spool_limit)


@dataclass
class Faults:
    """Faults applied to outgoing state packets (fractions are per packet)."""

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0  # hold a packet back and send it after the next one
    corrupt: float = 0.0  # flip a random bit
    truncate: float = 0.0  # cut to a random shorter length
    delay_s: float = 0.0  # added latency of every packet
    stalled: bool = False  # send nothing (the stream stops)
    stuck_zero: list[int] = field(default_factory=list)  # sensor ids reading raw 0
    stuck_saturated: list[int] = field(default_factory=list)  # sensor ids reading 65535


@dataclass
class EmulatorConfig:
    state_to: str = "127.0.0.1:11333"  # where state packets go (the driver's state_listen)
    command_listen: str = "127.0.0.1:11334"  # where commands are taken (driver's command_to)
    rate_hz: float = 40.0
    seed: int = 0
    # The hand's own calibration, as the driver must be configured to match.
    gear_ratio: tuple[float, ...] = (1.42, 1.42, 1.42, 1.5)
    motor_inverted: tuple[int, ...] = (1, -1, 1, -1)
    # Servo zeros near raw 13000 (the firmware's multi-turn offset) keep raw values positive.
    motor_zero_rad: tuple[float, ...] = (56.0, 57.0, 55.5, 53.0)
    encoder_zero_rad: tuple[float, ...] = (0.0, 0.0, 0.0)
    encoder_sign: float = -1.0
    zero_offsets: list[float] = field(default_factory=list)  # by sensor id; empty: 0
    noise_std: float = 0.0  # raw units
    max_speed_rad_s: float = 6.0  # servo slew, joint side
    faults: Faults = field(default_factory=Faults)


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


def pack_state(
    systime_us: int,
    pressures_by_id: np.ndarray,
    encoders: np.ndarray,
    positions: np.ndarray,
    loads: np.ndarray,
    speeds: np.ndarray | None = None,
) -> bytes:
    """A 202-byte state packet, filled field by field at the published offsets."""
    buf = bytearray(PACKET_LEN)
    buf[OFF_HEADER] = 1  # format version; 3 pad bytes stay 0
    struct.pack_into("<I", buf, OFF_SYSTIME, systime_us & 0xFFFFFFFF)
    wire = []
    for f in WIRE_PORT_FINGER:
        wire.extend(int(v) for v in pressures_by_id[9 * f : 9 * f + 9])
    wire.extend(int(v) for v in pressures_by_id[27:38])
    for i, v in enumerate(wire):
        struct.pack_into("<H", buf, OFF_PRESSURE + 2 * i, max(0, min(0xFFFF, v)))
        struct.pack_into("<H", buf, OFF_TEMPERATURE + 2 * i, 3000)  # arbitrary counts
    for i in range(3):
        struct.pack_into("<H", buf, OFF_ENCODER + 2 * i, int(encoders[i]) % 16383)
    for i in range(4):
        struct.pack_into("<H", buf, OFF_DXL_POS + 2 * i, max(0, min(0xFFFF, int(positions[i]))))
        spd = 0 if speeds is None else int(speeds[i])
        struct.pack_into("<H", buf, OFF_DXL_SPEED + 2 * i, spd)
        struct.pack_into("<H", buf, OFF_DXL_LOAD + 2 * i, int(loads[i]))
        buf[OFF_DXL_VOLT + i] = 120  # 12.0 V
        buf[OFF_DXL_TEMP + i] = 35
    return bytes(buf)


def parse_command(data: bytes) -> tuple[str, list[int]] | None:
    """("mode", 4 modes) / ("targets", 4 values) or None for anything the firmware ignores
    (it needs >= 5 / >= 9 bytes; extra bytes are ignored, as in enet.c)."""
    if len(data) >= 5 and data[0] == 0x01:
        return "mode", list(data[1:5])
    if len(data) >= 9 and data[0] == 0x02:
        return "targets", [(data[1 + 2 * i] << 8) | data[2 + 2 * i] for i in range(4)]
    return None


class TakktileEmulator:
    """Runs the board: a thread sends state at `rate_hz` to `state_to` and obeys commands on
    `command_listen`. Use as a context manager; `stop()` ends it."""

    def __init__(self, cfg: EmulatorConfig, fingers: FingerModel | None = None) -> None:
        self.cfg = cfg
        self.fingers = fingers or KinematicFingers()
        self.faults = cfg.faults
        self.rng = random.Random(cfg.seed)
        self.np_rng = np.random.default_rng(cfg.seed)
        self.gear = np.asarray(cfg.gear_ratio, dtype=np.float64)
        self.inv = np.asarray(cfg.motor_inverted, dtype=np.float64)
        self.mzero = np.asarray(cfg.motor_zero_rad, dtype=np.float64)
        self.offsets = np.asarray(cfg.zero_offsets or [0.0] * 38, dtype=np.float64)
        self.spool = np.zeros(3)  # joint-side spool angles
        self.preshape = 0.0
        self.goal = np.zeros(4)
        self.velocity = np.zeros(4)
        self.modes = [0, 0, 0, 0]
        self.commands: list[tuple[str, list[int]]] = []  # every command obeyed, in order
        self.raw_commands: list[bytes] = []
        self.ignored = 0
        self.sent = 0
        self._held: bytes | None = None
        self._delayed: list[tuple[float, bytes]] = []
        self._lock = threading.Lock()
        self._running = False
        self._thread: threading.Thread | None = None
        self._t0 = time.monotonic()
        self.state_to = _addr(cfg.state_to)
        self._rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._rx.bind(_addr(cfg.command_listen))
        self._rx.setblocking(False)
        self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    @property
    def command_port(self) -> int:
        return self._rx.getsockname()[1]

    # -- lifecycle ------------------------------------------------------------------------

    def start(self) -> TakktileEmulator:
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="takktile-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._rx.close()
        self._tx.close()

    def __enter__(self) -> TakktileEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- the board ------------------------------------------------------------------------

    def _loop(self) -> None:
        period = 1.0 / self.cfg.rate_hz
        next_t = time.monotonic()
        while self._running:
            self._read_commands()
            with self._lock:
                self._advance(period)
                packet = self._packet()
            self._emit(packet)
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))

    def _read_commands(self) -> None:
        while True:
            try:
                data = self._rx.recv(2048)
            except (BlockingIOError, OSError):
                return
            cmd = parse_command(data)
            with self._lock:
                self.raw_commands.append(bytes(data))
                if cmd is None:
                    self.ignored += 1
                    continue
                self.commands.append(cmd)
                kind, vals = cmd
                if kind == "mode":
                    self.modes = [v if v in (0, 1, 2) else 0 for v in vals]
                    continue
                for i, v in enumerate(vals):
                    if self.modes[i] == 2:
                        self.goal[i] = self.inv[i] * (v * POS_TICK / self.gear[i] - self.mzero[i])
                    elif self.modes[i] == 1:  # speed 0..1023, +1024 reverse (MX-28 units)
                        sign = -1.0 if v & 0x400 else 1.0
                        self.velocity[i] = self.inv[i] * sign * (v & 0x3FF) * 0.01194

    def _advance(self, dt: float) -> None:
        step = self.cfg.max_speed_rad_s * dt
        pos = np.append(self.spool, self.preshape)
        for i in range(4):
            if self.modes[i] == 2:
                pos[i] += float(np.clip(self.goal[i] - pos[i], -step, step))
            elif self.modes[i] == 1:
                pos[i] += float(np.clip(self.velocity[i] * dt, -step, step))
        stall = self.fingers.stall_spool()
        self.spool = np.clip(pos[:3], 0.0, stall)
        self.preshape = float(np.clip(pos[3], 0.0, 1.75))

    def _packet(self) -> bytes:
        cfg = self.cfg
        force = self.fingers.forces(self.spool, self.preshape)
        # Reading the pads may find the finger stalled short of where it was sent (it met
        # the object): the servo is where it stalled.
        self.spool = np.minimum(self.spool, self.fingers.stall_spool())
        prox, _ = self.fingers.joints(self.spool, self.preshape)
        raw = self.offsets + force
        if cfg.noise_std > 0:
            raw = raw + self.np_rng.normal(0.0, cfg.noise_std, 38)
        raw = np.clip(np.rint(raw), 0, 0xFFFF)
        raw[self.faults.stuck_zero] = 0
        raw[self.faults.stuck_saturated] = 0xFFFF
        # Encoder counts such that the driver's proximal = sign * (counts * tick - zero).
        enc = (prox / cfg.encoder_sign + np.asarray(cfg.encoder_zero_rad)) / ENC_TICK
        joint = np.append(self.spool, self.preshape)
        pos = (self.inv * joint + self.mzero) * self.gear / POS_TICK
        # Load against closing grows once a finger presses: bit 10 set = positive for inv +1.
        press = np.append(np.maximum(0.0, self.spool - self._contact()), 0.0)
        mag = np.minimum(1023, np.rint(press * 1500.0)).astype(int)
        loads = [m | 0x400 if self.inv[i] > 0 else m for i, m in enumerate(mag)]
        systime = int((time.monotonic() - self._t0) * 1e6)
        return pack_state(systime, raw, np.rint(enc), np.rint(pos), loads)

    def _contact(self) -> np.ndarray:
        c = getattr(self.fingers, "contact_spool", None)
        return np.full(3, np.inf) if c is None else np.asarray(c, dtype=np.float64)

    def _emit(self, packet: bytes) -> None:
        f, rng = self.faults, self.rng
        now = time.monotonic()
        out: list[bytes] = []
        if not f.stalled and rng.random() >= f.loss:
            if rng.random() < f.corrupt:
                b = bytearray(packet)
                bit = rng.randrange(len(b) * 8)
                b[bit // 8] ^= 1 << (bit % 8)
                packet = bytes(b)
            if rng.random() < f.truncate:
                packet = packet[: rng.randrange(len(packet))]
            if self._held is None and rng.random() < f.reorder:
                self._held = packet
            else:
                out.append(packet)
                if self._held is not None:
                    out.append(self._held)
                    self._held = None
            if out and rng.random() < f.duplicate:
                out.append(out[0])
        for p in out:
            self._delayed.append((now + f.delay_s, p))
        due = [p for t, p in self._delayed if t <= now]
        self._delayed = [(t, p) for t, p in self._delayed if t > now]
        for p in due:
            try:
                self._tx.sendto(p, self.state_to)
                self.sent += 1
            except OSError:
                pass

    # -- test / CLI helpers ---------------------------------------------------------------

    def set_object(self, contact_spool: list[float]) -> None:
        with self._lock:
            self.fingers.contact_spool = list(contact_spool)  # type: ignore[attr-defined]

    def joint_state(self) -> tuple[np.ndarray, float]:
        with self._lock:
            return self.spool.copy(), self.preshape
