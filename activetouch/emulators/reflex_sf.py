"""Four emulated Dynamixel MX-28 servos (Protocol 1.0) on a pty pair: the ReFlex SF as the
driver's serial port sees it, written from the protocol and hardware facts (no driver code).

The servos are multi-turn (raw 0..28672, 2π/4096 rad per tick) and sit at the hand's open pose
at their zero points, stored like reflex-ros-pkg's ``reflex_sf_motor_zero_points.yaml`` in
motor radians (25.21, 26.17, 23.58, 23.46 rad: raw ≈ 15,400-17,100). A finger closes when its
servo turns in its tendon's spooling direction, which is +position for servos 1 and 3 and
-position for 2 and the preshape 4 (``motor_to_joint_inverted`` False/True/False/True); the
motor turns `gear` times the joint. At power-on torque is off and the goal register equals the
present position, as on the real servo.

A finger that meets the object stops there (its `FingerStops`, joint-side spool angles) and
the servo's present load rises with how far its goal is beyond; the load's bit 10 is the
direction the servo pushes (set: towards lower positions, clear: towards higher), its low ten
bits the magnitude in 1/1024 of the maximum. Supported instructions: PING, READ, WRITE,
SYNC_WRITE (a bad checksum addressed to one servo gets a checksum-error status).

For tests it counts what a driver did: goal writes per servo, torque writes, and how far each
servo has moved from where it started (`moved_rad`).
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import threading
import time
import tty
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from activetouch.emulators.threaded import ThreadedEmulator

INST_PING, INST_READ, INST_WRITE, INST_SYNC_WRITE = 0x01, 0x02, 0x03, 0x83
BROADCAST = 0xFE
ERR_CHECKSUM, ERR_INSTRUCTION = 0x10, 0x40
TICK = 2 * math.pi / 4096  # MX-28, rad per tick
RAW_MAX = 28672  # multi-turn range of the SF's servos (reflex_sf.yaml `max`)
MX28_MODEL = 29
SPEED_UNIT_RAD_S = 0.114 * 2 * math.pi / 60  # moving speed register: 0.114 rpm per unit
MAX_SPEED_RAD_S = 5.9  # register 0 means "as fast as it goes" (~55 rpm at 12 V)
# Control table addresses (MX-28, Protocol 1.0).
TORQUE_ENABLE, GOAL, SPEED, PRESENT, LOAD, VOLTAGE, TEMPERATURE = 24, 30, 32, 36, 40, 42, 43
READ_ONLY = range(36, 50)

UPSTREAM_ZERO_POINTS = (25.21, 26.17, 23.58, 23.46)  # motor rad, the hand open
SPOOL_DIRECTION = (1, -1, 1, -1)  # sign of the position change that closes, by servo
GEAR = (1.42, 1.42, 1.42, 1.5)  # motor / joint
PRESHAPE_TRAVEL = 1.75  # joint rad the preshape can turn from its zero


class FingerStops(Protocol):
    """Where each finger meets something: joint-side spool angles (inf: nothing in the way)."""

    def stall_spool(self) -> np.ndarray: ...


@dataclass
class FixedStops:
    contact_spool: list[float] = field(default_factory=lambda: [math.inf] * 3)

    def stall_spool(self) -> np.ndarray:
        return np.asarray(self.contact_spool, dtype=np.float64)


@dataclass
class SFFaults:
    mute: list[int] = field(default_factory=list)  # servo ids that do not answer
    corrupt_replies: float = 0.0  # fraction of status packets with a wrong checksum
    reply_delay_s: float = 0.0
    alarm: dict[int, int] = field(default_factory=dict)  # servo id -> status error bits
    temperature_c: dict[int, int] = field(default_factory=dict)  # servo id -> reading


@dataclass
class SFEmulatorConfig:
    ids: tuple[int, ...] = (1, 2, 3, 4)
    zero_points: tuple[float, ...] = UPSTREAM_ZERO_POINTS  # motor rad at the open pose
    start_offset_rad: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)  # motor rad from zero at start
    seed: int = 0
    faults: SFFaults = field(default_factory=SFFaults)


class SFEmulator(ThreadedEmulator):
    """`port` is the pty slave path the driver opens. Start/stop, or use as a context."""

    def __init__(
        self, cfg: SFEmulatorConfig | None = None, fingers: FingerStops | None = None
    ) -> None:
        self.cfg = cfg or SFEmulatorConfig()
        self.fingers = fingers if fingers is not None else FixedStops()
        self.faults = self.cfg.faults
        self.rng = np.random.default_rng(self.cfg.seed)
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: bytes pass as they are
        self.port = os.ttyname(self._slave)
        self.zero = np.asarray(self.cfg.zero_points, dtype=np.float64)
        self.dir = np.asarray(SPOOL_DIRECTION, dtype=np.float64)
        self.gear = np.asarray(GEAR, dtype=np.float64)
        self.pos = self.zero + np.asarray(self.cfg.start_offset_rad, dtype=np.float64)
        self.start_pos = self.pos.copy()
        self.moved_rad = np.zeros(4)  # furthest each servo got from where it started
        self.blocked = np.zeros(4, dtype=bool)  # finger held at its stop by what it touches
        self.tables = {i: bytearray(74) for i in self.cfg.ids}
        for k, i in enumerate(self.cfg.ids):
            t = self.tables[i]
            t[0], t[1], t[3], t[4] = MX28_MODEL, 0, i, 34  # model, id, baud register 34
            self._put16(t, GOAL, self._raw(self.pos[k]))  # goal = present at power-on
        self.goal_writes = {i: 0 for i in self.cfg.ids}
        self.torque_writes: list[tuple[int, int]] = []  # (id, value)
        self.counts = {"packets": 0, "checksum_errors": 0, "replies": 0}
        self.instructions: list[tuple[int, int, bytes]] = []  # (id, instruction, params)
        self._buf = bytearray()
        self._lock = threading.Lock()
        self._last = time.monotonic()
        self._update_present()

    # -- units ----------------------------------------------------------------------------

    @staticmethod
    def _raw(motor_rad: float) -> int:
        return int(min(RAW_MAX, max(0, round(motor_rad / TICK))))

    @staticmethod
    def _put16(t: bytearray, addr: int, v: int) -> None:
        t[addr], t[addr + 1] = v & 0xFF, (v >> 8) & 0xFF

    def spool(self) -> np.ndarray:
        """Joint-side angles the tendons are spooled by (3 fingers, preshape), rad."""
        return self.dir * (self.pos - self.zero) / self.gear

    def raw_positions(self) -> list[int]:
        return [self._raw(p) for p in self.pos]

    # -- lifecycle ------------------------------------------------------------------------

    thread_name = "sf-emulator"

    def _open(self) -> None:
        self._last = time.monotonic()

    def _close(self) -> None:
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    # -- bytes ----------------------------------------------------------------------------

    def _loop(self) -> None:
        while self._running:
            ready, _, _ = select.select([self.master], [], [], 0.005)
            with self._lock:
                self._advance()
            if ready:
                try:
                    data = os.read(self.master, 4096)
                except OSError:
                    data = b""
                self._buf.extend(data)
                for reply in self._parse():
                    if self.faults.reply_delay_s:
                        time.sleep(self.faults.reply_delay_s)
                    os.write(self.master, reply)

    def _parse(self) -> list[bytes]:
        """Complete instruction packets out of the buffer -> status packets to send."""
        out = []
        buf = self._buf
        while True:
            start = buf.find(b"\xff\xff")
            if start < 0:
                del buf[: max(0, len(buf) - 1)]
                return out
            del buf[:start]
            if len(buf) < 4:
                return out
            if buf[2] == 0xFF:  # a third FF: resynchronise one byte on
                del buf[:1]
                continue
            n = buf[3]
            if len(buf) < 4 + n:
                return out
            pkt = bytes(buf[: 4 + n])
            del buf[: 4 + n]
            reply = self._handle(pkt)
            if reply is not None:
                out.append(reply)

    def _handle(self, pkt: bytes) -> bytes | None:
        dxl_id, length = pkt[2], pkt[3]
        self.counts["packets"] += 1
        if length < 2 or (~sum(pkt[2:-1])) & 0xFF != pkt[-1]:
            self.counts["checksum_errors"] += 1
            return self._reply(dxl_id, ERR_CHECKSUM)
        inst, params = pkt[4], pkt[5:-1]
        with self._lock:
            self.instructions.append((dxl_id, inst, params))
            if inst == INST_SYNC_WRITE and dxl_id == BROADCAST and len(params) >= 2:
                addr, size = params[0], params[1]
                for j in range(2, len(params) - size, size + 1):
                    if params[j] in self.tables:
                        self._write(params[j], addr, params[j + 1 : j + 1 + size])
                return None
            if dxl_id not in self.tables:
                return None
            if inst == INST_PING:
                return self._reply(dxl_id, 0)
            if inst == INST_READ and len(params) == 2:
                addr, n = params
                return self._reply(dxl_id, 0, bytes(self.tables[dxl_id][addr : addr + n]))
            if inst == INST_WRITE and len(params) >= 2:
                self._write(dxl_id, params[0], params[1:])
                return self._reply(dxl_id, 0)
        return self._reply(dxl_id, ERR_INSTRUCTION)

    def _reply(self, dxl_id: int, error: int, params: bytes = b"") -> bytes | None:
        if dxl_id == BROADCAST or dxl_id not in self.tables or dxl_id in self.faults.mute:
            return None
        error |= self.faults.alarm.get(dxl_id, 0)
        body = bytes([dxl_id, len(params) + 2, error]) + params
        pkt = b"\xff\xff" + body + bytes([(~sum(body)) & 0xFF])
        if self.rng.random() < self.faults.corrupt_replies:
            pkt = pkt[:-1] + bytes([pkt[-1] ^ 0x5A])
        self.counts["replies"] += 1
        return pkt

    def _write(self, dxl_id: int, addr: int, data: bytes) -> None:
        t = self.tables[dxl_id]
        n = len(data)
        keep = bytes(t[READ_ONLY.start : READ_ONLY.stop])
        t[addr : addr + n] = data
        t[READ_ONLY.start : READ_ONLY.stop] = keep  # present values are the servo's own
        if addr <= GOAL < addr + n or addr <= GOAL + 1 < addr + n:
            self.goal_writes[dxl_id] += 1
            goal = t[GOAL] | t[GOAL + 1] << 8
            self._put16(t, GOAL, min(goal, RAW_MAX))  # the servo's own goal limit
        if addr <= TORQUE_ENABLE < addr + n:
            self.torque_writes.append((dxl_id, t[TORQUE_ENABLE]))

    # -- physics --------------------------------------------------------------------------

    def _advance(self) -> None:
        now = time.monotonic()
        dt, self._last = now - self._last, now
        stall = np.append(np.asarray(self.fingers.stall_spool(), dtype=np.float64), PRESHAPE_TRAVEL)
        for k, i in enumerate(self.cfg.ids):
            t = self.tables[i]
            if not t[TORQUE_ENABLE]:  # torque off: the servo does not drive
                continue
            speed = t[SPEED] | (t[SPEED + 1] & 0x03) << 8
            v = MAX_SPEED_RAD_S if speed == 0 else min(MAX_SPEED_RAD_S, speed * SPEED_UNIT_RAD_S)
            goal = (t[GOAL] | t[GOAL + 1] << 8) * TICK
            p = self.pos[k] + float(np.clip(goal - self.pos[k], -v * dt, v * dt))
            # Spooling past where the finger meets something is blocked: the servo stalls.
            spool = self.dir[k] * (p - self.zero[k]) / self.gear[k]
            self.blocked[k] = spool >= stall[k]
            if self.blocked[k]:
                p = self.zero[k] + self.dir[k] * stall[k] * self.gear[k]
                p = self.pos[k] if self.dir[k] * (p - self.pos[k]) < 0 else p
            self.pos[k] = p
        self.moved_rad = np.maximum(self.moved_rad, np.abs(self.pos - self.start_pos))
        self._update_present()

    def _update_present(self) -> None:
        for k, i in enumerate(self.cfg.ids):
            t = self.tables[i]
            self._put16(t, PRESENT, self._raw(self.pos[k]))
            goal = (t[GOAL] | t[GOAL + 1] << 8) * TICK
            push = goal - self.pos[k] if t[TORQUE_ENABLE] else 0.0
            # Pushing against a blocked finger loads the servo: 8 x the maximum per joint rad
            # of goal beyond the stop (a stiff object); moving freely, a little (friction).
            per_rad = 8.0 if self.blocked[k] and self.dir[k] * push > 0 else 0.05
            mag = int(min(1023, round(abs(push) / self.gear[k] * per_rad * 1024)))
            self._put16(t, LOAD, mag | (0x400 if push < 0 and mag else 0))
            t[VOLTAGE] = 120
            t[TEMPERATURE] = self.faults.temperature_c.get(i, 35)

    def set_object(self, contact_spool: list[float]) -> None:
        """Fixed stops at these joint-side spool angles (the fingers meet an object there)."""
        with self._lock:
            self.fingers = FixedStops(list(contact_spool))
