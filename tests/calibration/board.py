"""An independent TakkTile board for calibration tests: sends state packets built byte by byte
from the published layout (protocol facts B.1) with known per-sensor offsets, noise, drift and
faults. Uses neither the driver's codec nor the emulator."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np

# Wire order of the tactile ports: pointer (finger 0), thumb (finger 2), middle (finger 1),
# palm. Package sensor id = 9 * finger + s.
WIRE_TO_ID = list(range(0, 9)) + list(range(18, 27)) + list(range(9, 18)) + list(range(27, 38))


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def packet(systime_us: int, raw_by_id: np.ndarray, positions: tuple[int, ...]) -> bytes:
    out = bytearray([1, 0, 0, 0]) + int(systime_us & 0xFFFFFFFF).to_bytes(4, "little")
    for w in range(38):
        v = int(min(65535, max(0, round(float(raw_by_id[WIRE_TO_ID[w]])))))
        out += v.to_bytes(2, "little")
    out += b"".join((3000).to_bytes(2, "little") for _ in range(38))  # temperatures
    out += b"".join((0).to_bytes(2, "little") for _ in range(3))  # encoders
    out += bytes(4)  # dynamixel errors
    out += b"".join(int(p).to_bytes(2, "little") for p in positions)
    out += bytes(8)  # speeds
    out += bytes(8)  # loads
    out += bytes([120] * 4) + bytes([35] * 4)
    assert len(out) == 202
    return bytes(out)


class NoisyBoard:
    """Sends packets at `rate_hz` to 127.0.0.1:`state_port`: raw = offset + drift * t +
    N(0, noise) (rounded), with `dead` sensors stuck at a constant and `saturated` at 65535."""

    def __init__(
        self,
        offsets: np.ndarray,
        noise: float,
        seed: int = 0,
        drift_per_s: dict[int, float] | None = None,
        dead: dict[int, int] | None = None,
        saturated: list[int] | None = None,
        rate_hz: float = 40.0,
        positions: tuple[int, int, int, int] = (13000, 13000, 13000, 13000),
    ) -> None:
        self.offsets = np.asarray(offsets, dtype=np.float64)
        self.noise = noise
        self.rng = np.random.default_rng(seed)
        self.drift = drift_per_s or {}
        self.dead = dead or {}
        self.saturated = saturated or []
        self.rate_hz = rate_hz
        self.positions = positions
        self.state_port = free_udp_port()
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cmd.bind(("127.0.0.1", 0))
        self.tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.extra = np.zeros(38)  # added to every packet (a touch)

    @property
    def command_port(self) -> int:
        return self.cmd.getsockname()[1]

    def _run(self) -> None:
        t0 = time.monotonic()
        k = 0
        while not self._stop.is_set():
            t = time.monotonic() - t0
            raw = self.offsets + self.rng.normal(0.0, self.noise, 38) + self.extra
            for i, d in self.drift.items():
                raw[i] += d * t
            for i, v in self.dead.items():
                raw[i] = v
            for i in self.saturated:
                raw[i] = 65535
            self.tx.sendto(
                packet(1000 + k * 25_000, raw, self.positions), ("127.0.0.1", self.state_port)
            )
            k += 1
            time.sleep(1.0 / self.rate_hz)

    def __enter__(self) -> NoisyBoard:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.cmd.close()
        self.tx.close()
