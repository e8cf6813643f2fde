"""Test-side packet builders written straight from the published layout (protocol facts B.1),
byte by byte with int.to_bytes, independent of both the driver's codec and the emulator."""

from __future__ import annotations

# Wire order of the tactile ports: pointer, thumb, middle, palm. Sensor id = 9 * finger + s.
WIRE_TO_ID = list(range(0, 9)) + list(range(18, 27)) + list(range(9, 18)) + list(range(27, 38))


def u16(v: int) -> bytes:
    return int(v).to_bytes(2, "little")


def state_packet(
    systime: int = 1000,
    pressures_by_id: list[int] | None = None,
    encoders: tuple[int, int, int] = (0, 0, 0),
    positions: tuple[int, int, int, int] = (0, 0, 0, 0),
    loads: tuple[int, int, int, int] = (0, 0, 0, 0),
    version: int = 1,
) -> bytes:
    p = pressures_by_id or [0] * 38
    out = bytes([version, 0, 0, 0]) + int(systime).to_bytes(4, "little")
    out += b"".join(u16(p[WIRE_TO_ID[w]]) for w in range(38))  # pressures, wire order
    out += b"".join(u16(100 + w) for w in range(38))  # temperatures
    out += b"".join(u16(e) for e in encoders)
    out += bytes([0, 0, 0, 0])  # dynamixel error
    out += b"".join(u16(v) for v in positions)
    out += b"".join(u16(7) for _ in range(4))  # speed
    out += b"".join(u16(v) for v in loads)
    out += bytes([120, 121, 122, 123])  # voltage
    out += bytes([30, 31, 32, 33])  # temperature
    assert len(out) == 202
    return out
