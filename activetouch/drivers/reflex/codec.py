"""ReFlex TakkTile (v1 / Beta) wire format: the 202-byte state packet and the command packets.

Layout (reflex-ros-pkg firmware ``state.h``, driver ``reflex_hand.h``; little-endian, packed):
header (version 1 + 3 pad) | uint32 µs since boot | uint16 pressures[38] | uint16
temperatures[38] | uint16 encoders[3] | uint8 dxl error[4] | uint16 dxl position[4] | uint16
speed[4] | uint16 load[4] | uint8 voltage[4] | uint8 temperature[4]. Motor order: finger 0,
finger 1, finger 2, preshape. Commands: set mode ``0x01 m0 m1 m2 m3``; set targets ``0x02``
plus four **big-endian** uint16.

Pure functions only: no sockets here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

STATE_PACKET_SIZE = 202
STATE_FORMAT_VERSION = 1
N_WIRE_SENSORS = 38
N_MOTORS = 4
N_ENCODERS = 3
_STATE = struct.Struct("<B3xI38H38H3H4B4H4H4H4B4B")
assert _STATE.size == STATE_PACKET_SIZE

CMD_SET_MODE = 0x01
CMD_SET_TARGETS = 0x02
MODE_IDLE = 0  # torque off
MODE_VELOCITY = 1  # torque off in the firmware too (dmxl.c): only a speed target
MODE_POSITION = 2

# Wire pressure index -> package sensor id (activetouch.interfaces: finger f sensor s = 9f + s).
# The board's ports are pointer, thumb, middle, palm: wire 0-8 pointer (finger 0), 9-17 thumb
# (finger 2), 18-26 middle (finger 1), 27-37 palm (reflex_driver_node.cpp TACTILE_BASE_IDX).
ID_OF_WIRE = np.concatenate(
    [np.arange(0, 9), np.arange(18, 27), np.arange(9, 18), np.arange(27, 38)]
).astype(np.int64)
WIRE_OF_ID = np.argsort(ID_OF_WIRE)


class PacketError(ValueError):
    """A datagram that is not a state packet of the known format."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason  # short counter key: "length", "version"


@dataclass(frozen=True)
class StatePacket:
    """One decoded state packet, pressures already in package sensor-id order."""

    systime_us: int
    pressures: np.ndarray  # (38,) raw sensor counts by sensor id
    temperatures: np.ndarray  # (38,) by sensor id
    encoders: np.ndarray  # (3,) raw 14-bit proximal encoder counts, finger order
    dxl_error: np.ndarray  # (4,)
    dxl_position: np.ndarray  # (4,) raw ticks
    dxl_speed: np.ndarray  # (4,)
    dxl_load: np.ndarray  # (4,) raw, bit 10 = direction
    dxl_voltage: np.ndarray  # (4,) tenths of a volt
    dxl_temperature: np.ndarray  # (4,) °C


def decode_state(data: bytes) -> StatePacket:
    """Decode a state datagram; `PacketError` for any other length or format version."""
    if len(data) != STATE_PACKET_SIZE:
        raise PacketError(
            "length", f"state packet of {len(data)} bytes (expected {STATE_PACKET_SIZE})"
        )
    if data[0] != STATE_FORMAT_VERSION:
        raise PacketError("version", f"state packet format {data[0]} (expected 1)")
    v = _STATE.unpack(data)
    # v: version, systime, 38 pressures, 38 temperatures, 3 enc, 4 err, 4 pos, 4 spd, 4 load,
    # 4 volt, 4 temp.
    a = np.asarray(v[2:], dtype=np.int64)
    i = 0

    def take(n: int) -> np.ndarray:
        nonlocal i
        out = a[i : i + n]
        i += n
        return out

    p_wire, t_wire = take(38), take(38)
    pressures = np.empty(N_WIRE_SENSORS, dtype=np.int64)
    temperatures = np.empty(N_WIRE_SENSORS, dtype=np.int64)
    pressures[ID_OF_WIRE] = p_wire
    temperatures[ID_OF_WIRE] = t_wire
    return StatePacket(
        systime_us=int(v[1]),
        pressures=pressures,
        temperatures=temperatures,
        encoders=take(3),
        dxl_error=take(4),
        dxl_position=take(4),
        dxl_speed=take(4),
        dxl_load=take(4),
        dxl_voltage=take(4),
        dxl_temperature=take(4),
    )


def encode_state(p: StatePacket) -> bytes:
    """The inverse of `decode_state` (for round-trip tests; the emulator has its own packer)."""
    return _STATE.pack(
        STATE_FORMAT_VERSION,
        p.systime_us,
        *np.asarray(p.pressures)[ID_OF_WIRE].tolist(),
        *np.asarray(p.temperatures)[ID_OF_WIRE].tolist(),
        *np.asarray(p.encoders).tolist(),
        *np.asarray(p.dxl_error).tolist(),
        *np.asarray(p.dxl_position).tolist(),
        *np.asarray(p.dxl_speed).tolist(),
        *np.asarray(p.dxl_load).tolist(),
        *np.asarray(p.dxl_voltage).tolist(),
        *np.asarray(p.dxl_temperature).tolist(),
    )


def encode_set_mode(modes: tuple[int, int, int, int] | list[int]) -> bytes:
    """``0x01`` + one mode byte per motor (0 idle, 1 velocity, 2 position)."""
    if len(modes) != N_MOTORS or any(m not in (0, 1, 2) for m in modes):
        raise ValueError(f"need 4 modes in 0..2, got {modes!r}")
    return bytes([CMD_SET_MODE, *modes])


def encode_set_targets(targets: tuple[int, ...] | list[int]) -> bytes:
    """``0x02`` + four big-endian uint16 targets (goal position, or speed in velocity mode)."""
    if len(targets) != N_MOTORS or any(not 0 <= int(t) <= 0xFFFF for t in targets):
        raise ValueError(f"need 4 targets in 0..65535, got {targets!r}")
    return bytes([CMD_SET_TARGETS]) + struct.pack(">4H", *(int(t) for t in targets))


def is_restart(systime_us: int, last_us: int | None, restart_us: int = 1_000_000) -> bool:
    """Whether `systime_us` after `last_us` means the board restarted (its clock went back by
    more than `restart_us`): it comes back in IDLE with its servo state zero-initialised."""
    if last_us is None:
        return False
    back = (last_us - systime_us) % (1 << 32)
    return 0 < back < (1 << 31) and back > restart_us


# Dynamixel error byte bits (MX-28 status packet), lowest first.
DXL_ERROR_BITS = (
    "input voltage",
    "angle limit",
    "overheating",
    "range",
    "checksum",
    "overload",
    "instruction",
)


def dxl_error_names(err: int) -> list[str]:
    return [name for b, name in enumerate(DXL_ERROR_BITS) if int(err) & (1 << b)]


def is_newer(systime_us: int, last_us: int | None, restart_us: int = 1_000_000) -> bool:
    """Whether a packet stamped `systime_us` follows one stamped `last_us` (uint32 µs, wraps
    after 71 min). Equal is a duplicate; a small step back is a reordered packet; a step back
    by more than `restart_us` is taken as the board restarting (accepted)."""
    if last_us is None:
        return True
    delta = (systime_us - last_us) % (1 << 32)
    if delta == 0:
        return False
    if delta < (1 << 31):
        return True
    back = (1 << 32) - delta
    return back > restart_us


SERVO_NAMES = (
    "finger 0 (pointer) servo",
    "finger 1 (middle) servo",
    "finger 2 (thumb) servo",
    "preshape servo",
)


def servo_faults(p: StatePacket, window: list[int], max_temp: float) -> list[str]:
    """What cannot be true in a packet's servo fields, one sentence per servo (empty: fine)."""
    lo, hi = window
    out = []
    for i, name in enumerate(SERVO_NAMES):
        pos = int(p.dxl_position[i])
        if pos == 0:
            out.append(
                f"{name} (motor {i}) reads position 0: it has not answered the board "
                "(check its cable and power, then power-cycle the hand)"
            )
        elif not lo <= pos <= hi:
            out.append(
                f"{name} (motor {i}) reads position {pos}, outside the firmware's "
                f"window {lo}..{hi} around 13000 (check its horn and tendon, then "
                "power-cycle the hand)"
            )
        errs = dxl_error_names(int(p.dxl_error[i]))
        if errs:
            out.append(
                f"{name} (motor {i}) reports alarm {', '.join(errs)} (check its load, "
                "supply and temperature; power-cycle the hand to clear it)"
            )
        temp = float(p.dxl_temperature[i])
        if temp > max_temp:
            out.append(f"{name} (motor {i}) is at {temp:.0f} C (> {max_temp:g}): let it cool")
    return out
