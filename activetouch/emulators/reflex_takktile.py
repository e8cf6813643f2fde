"""A byte-level stand-in for the ReFlex TakkTile board: state packets at 40 Hz over UDP, command
packets obeyed, faults on demand. Written from the facts (docs/protocols/reflex.md,
reflex-ros-pkg firmware ``state.h``, ``enet.c``, ``dmxl.c``), importing nothing from the drivers.

What the real board does and this one too:
- pressures at rest sit at real baselines (upstream ``tactile_calibrate.yaml``: 56-306 counts),
  each sensor with its own noise: an uncalibrated driver sees contact everywhere;
- the Dynamixel fields are zero until the servos answer (`servo_answer_delay_s` after power-up
  or a restart: the firmware's state is zero-initialised);
- commands are taken only on the multicast group: here `command_listen` stands for the group
  (a loopback address) and `unicast_listen` for the board's own address, where commands are
  counted in `dropped_unicast` and ignored; nothing leaves loopback;
- IDLE and VELOCITY turn torque off (VELOCITY targets set the moving speed), POSITION turns it
  on, the servo then drives to its goal register (at power-up: where it is), and every
  POSITION switch rewrites the angle limits (`angle_limit_writes`, per servo);
- `restart()` reboots the board: clock back to 0, IDLE, servos unanswered again.

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

from activetouch.emulators.threaded import ThreadedEmulator

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


# Unloaded raw readings of a real hand (reflex_driver/yaml/tactile_calibrate.yaml, f1 = pointer
# = sensors 0-8, f2 = middle = 9-17, f3 = thumb = 18-26); the palm is not in that file.
UPSTREAM_BASELINES = (
    [133, 121, 125, 117, 153, 153, 149, 166, 132]
    + [127, 129, 136, 130, 154, 154, 160, 91, 156]
    + [137, 111, 156, 161, 148, 306, 66, 148, 56]
    + [180] * 11
)


@dataclass
class EmulatorConfig:
    state_to: str = "127.0.0.1:11333"  # where state packets go (the driver's state_listen)
    # The board's multicast group, played by a loopback address: commands are taken here.
    command_listen: str = "127.0.0.2:11334"
    # The board's own (unicast) address: commands sent here are counted and dropped. Same port
    # as command_listen when its port is 0. Empty: no unicast socket.
    unicast_listen: str = "127.0.0.1:0"
    servo_answer_delay_s: float = 0.0  # Dynamixel fields read 0 until then (and after restart)
    mute_servos: list[int] = field(default_factory=list)  # servos that never answer
    rate_hz: float = 40.0
    seed: int = 0
    # The hand's own calibration, as the driver must be configured to match.
    gear_ratio: tuple[float, ...] = (1.42, 1.42, 1.42, 1.5)
    motor_inverted: tuple[int, ...] = (1, -1, 1, -1)
    # Servo zeros near raw 13000 (the firmware's multi-turn offset) keep raw values positive.
    motor_zero_rad: tuple[float, ...] = (56.0, 57.0, 55.5, 53.0)
    encoder_zero_rad: tuple[float, ...] = (0.0, 0.0, 0.0)
    encoder_sign: float = -1.0
    baselines: list[float] = field(default_factory=lambda: list(UPSTREAM_BASELINES))
    noise_std: float | list[float] = 1.0  # raw units, one for all or one per sensor
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
    answered: list[bool] | None = None,
    dxl_error: list[int] | None = None,
    dxl_temperature: list[int] | None = None,
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
        if answered is not None and not answered[i]:
            continue  # zero-initialised until the servo answers
        buf[OFF_DXL_ERROR + i] = 0 if dxl_error is None else int(dxl_error[i]) & 0xFF
        buf[OFF_DXL_VOLT + i] = 120  # 12.0 V
        buf[OFF_DXL_TEMP + i] = 35 if dxl_temperature is None else int(dxl_temperature[i])
    return bytes(buf)


def parse_command(data: bytes) -> tuple[str, list[int]] | None:
    """("mode", 4 modes) / ("targets", 4 values) or None for anything the firmware ignores
    (it needs >= 5 / >= 9 bytes; extra bytes are ignored, as in enet.c)."""
    if len(data) >= 5 and data[0] == 0x01:
        return "mode", list(data[1:5])
    if len(data) >= 9 and data[0] == 0x02:
        return "targets", [(data[1 + 2 * i] << 8) | data[2 + 2 * i] for i in range(4)]
    return None


class TakktileEmulator(ThreadedEmulator):
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
        self.baselines = np.asarray(cfg.baselines, dtype=np.float64)
        self.noise = np.broadcast_to(np.asarray(cfg.noise_std, dtype=np.float64), (38,)).copy()
        self.spool = np.zeros(3)  # joint-side spool angles
        self.preshape = 0.0
        self.goal: np.ndarray | None = None  # goal registers (joint side); None: unanswered
        self.velocity = np.zeros(4)
        self.speed_reg = [0, 0, 0, 0]  # moving speed registers (VELOCITY-mode targets)
        self.modes = [0, 0, 0, 0]
        self.commands: list[tuple[str, list[int]]] = []  # every command obeyed, in order
        self.raw_commands: list[bytes] = []
        self.mode_switches: dict[int, int] = {0: 0, 1: 0, 2: 0}  # set-mode packets by mode
        self.angle_limit_writes = [0, 0, 0, 0]  # per servo, one per POSITION switch
        self.dropped_unicast = 0
        self.ignored = 0
        self.sent = 0
        self.restarts = 0
        self._boot = time.monotonic()
        self.extra_load = np.zeros(4)  # added load magnitude (tests: an overloaded servo)
        self.dxl_error = [0, 0, 0, 0]
        self.dxl_temperature = [35, 35, 35, 35]
        self._held: bytes | None = None
        self._delayed: list[tuple[float, bytes]] = []
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self.state_to = _addr(cfg.state_to)
        self._rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._rx.bind(_addr(cfg.command_listen))
        self._rx.setblocking(False)
        self._uni: socket.socket | None = None
        uhost = _addr(cfg.unicast_listen)[0] if cfg.unicast_listen else ""
        if uhost and uhost != self._rx.getsockname()[0]:  # same address: no unicast socket
            host, port = _addr(cfg.unicast_listen)
            self._uni = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._uni.bind((host, port or self.command_port))
            self._uni.setblocking(False)
        self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    @property
    def command_port(self) -> int:
        return self._rx.getsockname()[1]

    @property
    def command_address(self) -> str:
        """host:port of "the group" (where a driver must send commands)."""
        host, port = self._rx.getsockname()[:2]
        return f"{host}:{port}"

    @property
    def unicast_address(self) -> str:
        if self._uni is None:
            return ""
        host, port = self._uni.getsockname()[:2]
        return f"{host}:{port}"

    def position_switches(self) -> int:
        with self._lock:
            return self.mode_switches[2]

    def restart(self) -> None:
        """Reboot the board: clock from 0, IDLE, servo fields zero until they answer again."""
        with self._lock:
            self._t0 = self._boot = time.monotonic()
            self.modes = [0, 0, 0, 0]
            self.goal = None
            self.restarts += 1

    def answered(self, i: int) -> bool:
        if i in self.cfg.mute_servos:
            return False
        return time.monotonic() - self._boot >= self.cfg.servo_answer_delay_s

    # -- lifecycle ------------------------------------------------------------------------

    thread_name = "takktile-emulator"

    def _close(self) -> None:
        self._rx.close()
        if self._uni is not None:
            self._uni.close()
        self._tx.close()

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
        while self._uni is not None:
            try:
                self._uni.recv(2048)
            except (BlockingIOError, OSError):
                break
            with self._lock:
                self.dropped_unicast += 1  # the firmware accepts only its multicast group
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
                    self._set_modes(vals)
                    continue
                for i, v in enumerate(vals):
                    if self.modes[i] == 1:  # VELOCITY: moving speed register, torque off
                        self.speed_reg[i] = v
                    elif self.goal is not None and self.answered(i):
                        # IDLE and POSITION write the goal register (torque only in POSITION).
                        self.goal[i] = self.inv[i] * (v * POS_TICK / self.gear[i] - self.mzero[i])

    def _set_modes(self, vals: list[int]) -> None:
        modes = [v if v in (0, 1, 2) else 0 for v in vals]
        for m in set(modes):
            self.mode_switches[m] += 1
        for i, m in enumerate(modes):
            if m == 2:
                self.angle_limit_writes[i] += 1  # dmxl_set_angle_limits on every switch
        self.modes = modes

    def _advance(self, dt: float) -> None:
        pos = np.append(self.spool, self.preshape)
        if self.goal is None:
            if all(self.answered(i) for i in range(4)):
                self.goal = pos.copy()  # at power-up a servo's goal is where it is
            return
        for i in range(4):
            if self.modes[i] != 2:
                continue  # torque off
            speed = self.cfg.max_speed_rad_s
            if self.speed_reg[i] & 0x3FF:  # moving speed set: 0.01194 rad/s per unit, motor side
                speed = min(speed, (self.speed_reg[i] & 0x3FF) * 0.01194 / self.gear[i])
            step = speed * dt
            pos[i] += float(np.clip(self.goal[i] - pos[i], -step, step))
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
        raw = self.baselines + force
        if np.any(self.noise > 0):
            raw = raw + self.np_rng.normal(0.0, 1.0, 38) * self.noise
        raw = np.clip(np.rint(raw), 0, 0xFFFF)
        raw[self.faults.stuck_zero] = 0
        raw[self.faults.stuck_saturated] = 0xFFFF
        # Encoder counts such that the driver's proximal = sign * (counts * tick - zero).
        enc = (prox / cfg.encoder_sign + np.asarray(cfg.encoder_zero_rad)) / ENC_TICK
        joint = np.append(self.spool, self.preshape)
        pos = (self.inv * joint + self.mzero) * self.gear / POS_TICK
        # Load grows once a finger presses. Closing load is positive on the host side, which
        # reads raw > 1023 as +(raw - 1023) and raw <= 1023 as -raw, times the inversion.
        press = np.append(np.maximum(0.0, self.spool - self._contact()), 0.0)
        mag = np.minimum(1023, np.rint(press * 1500.0) + self.extra_load).astype(int)
        loads = [int(m) + 1023 if self.inv[i] > 0 and m else int(m) for i, m in enumerate(mag)]
        answered = [self.answered(i) for i in range(4)]
        pos = np.where(answered, np.rint(pos), 0)
        loads = [v if a else 0 for v, a in zip(loads, answered, strict=True)]
        systime = int((time.monotonic() - self._t0) * 1e6)
        return pack_state(
            systime,
            raw,
            np.rint(enc),
            pos,
            loads,
            answered=answered,
            dxl_error=self.dxl_error,
            dxl_temperature=self.dxl_temperature,
        )

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
