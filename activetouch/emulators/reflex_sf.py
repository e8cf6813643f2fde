"""Four emulated Dynamixel MX-28 servos (Protocol 1.0) on a pty pair: the ReFlex SF as the
driver's serial port sees it.

It stands in for the servos, not for dynamixel-sdk: it parses instruction packets and checks
their checksums itself (``FF FF id len instr params.. ~sum``), answers with status packets, and
keeps a control table per servo. Supported: PING, READ, WRITE, SYNC_WRITE (and a checksum
error status for a bad packet addressed to one servo). Finger motion comes from a
`FingerModel` (as in the TakkTile emulator): a finger that meets the object stalls there and
its load rises, which is all the SF can feel.
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

import numpy as np

from activetouch.emulators.reflex_takktile import FingerModel, KinematicFingers

INST_PING, INST_READ, INST_WRITE, INST_SYNC_WRITE = 0x01, 0x02, 0x03, 0x83
BROADCAST = 0xFE
ERR_CHECKSUM, ERR_INSTRUCTION = 0x10, 0x40
TICK = 2 * math.pi / 4096  # MX-28, rad per tick
MX28_MODEL = 29


def checksum(body: bytes | list[int]) -> int:
    """~(id + length + instruction/error + params) & 0xFF."""
    return (~sum(body)) & 0xFF


def status_packet(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    body = bytes([dxl_id, len(params) + 2, error]) + params
    return b"\xff\xff" + body + bytes([checksum(body)])


@dataclass
class SFFaults:
    mute: list[int] = field(default_factory=list)  # servo ids that do not answer
    corrupt_replies: float = 0.0  # fraction of status packets with a wrong checksum
    reply_delay_s: float = 0.0


@dataclass
class SFEmulatorConfig:
    ids: tuple[int, ...] = (1, 2, 3, 4)
    gear_ratio: tuple[float, ...] = (1.42, 1.42, 1.42, 1.5)
    motor_inverted: tuple[int, ...] = (1, 1, -1, -1)
    # Raw 1000 at the open pose for normal servos, 3500 for inverted ones (in range 0..4095).
    motor_zero_rad: tuple[float, ...] = (
        1000 * TICK / 1.42,
        1000 * TICK / 1.42,
        3500 * TICK / 1.42,
        3500 * TICK / 1.5,
    )
    max_speed_rad_s: float = 6.0
    seed: int = 0
    faults: SFFaults = field(default_factory=SFFaults)


class SFEmulator:
    """`port` is the pty slave path the driver opens. Start/stop, or use as a context."""

    def __init__(
        self, cfg: SFEmulatorConfig | None = None, fingers: FingerModel | None = None
    ) -> None:
        self.cfg = cfg or SFEmulatorConfig()
        self.fingers = fingers or KinematicFingers()
        self.faults = self.cfg.faults
        self.rng = np.random.default_rng(self.cfg.seed)
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: bytes pass as they are
        self.port = os.ttyname(self._slave)
        self.gear = np.asarray(self.cfg.gear_ratio, dtype=np.float64)
        self.inv = np.asarray(self.cfg.motor_inverted, dtype=np.float64)
        self.zero = np.asarray(self.cfg.motor_zero_rad, dtype=np.float64)
        self.tables = {i: bytearray(74) for i in self.cfg.ids}
        self.joint = np.zeros(4)  # joint-side angles: 3 spools, preshape
        for k, i in enumerate(self.cfg.ids):
            t = self.tables[i]
            t[0], t[1], t[3], t[4] = MX28_MODEL, 0, i, 34  # model, id, baud register 34
            raw = self._raw(k, 0.0)
            t[30], t[31] = raw & 0xFF, raw >> 8  # goal = present at start
        self.counts = {"packets": 0, "checksum_errors": 0, "replies": 0}
        self.instructions: list[tuple[int, int, bytes]] = []  # (id, instruction, params)
        self._buf = bytearray()
        self._lock = threading.Lock()
        self._running = False
        self._thread: threading.Thread | None = None
        self._last = time.monotonic()
        self._update_present()

    def _raw(self, k: int, angle: float) -> int:
        v = (self.inv[k] * angle + self.zero[k]) * self.gear[k] / TICK
        return int(min(4095, max(0, round(v))))

    def _angle(self, k: int, raw: int) -> float:
        return float(self.inv[k] * (raw * TICK / self.gear[k] - self.zero[k]))

    # -- lifecycle ------------------------------------------------------------------------

    def start(self) -> SFEmulator:
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="sf-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> SFEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- servos ---------------------------------------------------------------------------

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
        if length < 2 or checksum(pkt[2:-1]) != pkt[-1]:
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
        pkt = status_packet(dxl_id, error, params)
        if self.rng.random() < self.faults.corrupt_replies:
            pkt = pkt[:-1] + bytes([pkt[-1] ^ 0x5A])
        self.counts["replies"] += 1
        return pkt

    def _write(self, dxl_id: int, addr: int, data: bytes) -> None:
        t = self.tables[dxl_id]
        if addr in (36, 37, 38, 39, 40, 41, 42, 43):  # read-only present values
            return
        t[addr : addr + len(data)] = data

    def _advance(self) -> None:
        now = time.monotonic()
        dt, self._last = now - self._last, now
        step = self.cfg.max_speed_rad_s * dt
        for k, i in enumerate(self.cfg.ids):
            t = self.tables[i]
            if not t[24]:  # torque off: the servo does not drive
                continue
            goal = self._angle(k, t[30] | t[31] << 8)
            self.joint[k] += float(np.clip(goal - self.joint[k], -step, step))
        self.joint[:3] = np.clip(self.joint[:3], 0.0, self.fingers.stall_spool())
        self.joint[3] = float(np.clip(self.joint[3], 0.0, 1.75))
        self._update_present()

    def _update_present(self) -> None:
        contact = np.asarray(getattr(self.fingers, "contact_spool", [np.inf] * 3), dtype=float)
        press = np.append(np.maximum(0.0, self.joint[:3] - contact), 0.0)
        for k, i in enumerate(self.cfg.ids):
            t = self.tables[i]
            raw = self._raw(k, float(self.joint[k]))
            t[36], t[37] = raw & 0xFF, raw >> 8
            # Load against closing: fraction 2.0 per rad pressed, capped; bit 10 gives the
            # sign that reads positive for this servo's inversion.
            mag = int(min(1023, round(press[k] * 2.0 * 1024)))
            load = mag | 0x400 if self.inv[k] > 0 else mag
            t[40], t[41] = load & 0xFF, load >> 8
            t[42], t[43] = 120, 35

    def set_object(self, contact_spool: list[float]) -> None:
        with self._lock:
            self.fingers.contact_spool = list(contact_spool)  # type: ignore[attr-defined]
