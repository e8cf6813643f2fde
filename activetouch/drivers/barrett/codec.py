"""Pure functions that build and parse the BarrettHand's CAN frames (protocol facts C).

- 11-bit ids ``[G FFFFF TTTTT]``: bit 10 the group flag, bits 9-5 the sender, bits 4-0 the
  receiver (node or group); the host is node 0.
- GET: one byte, the property id (bit 7 clear). SET: six bytes, ``0x80 | id``, 0, then the
  value as 32-bit little-endian.
- Property replies (to feedback group 6): 4 or 6 bytes, ``0x80 | id``, 0, value little-endian
  sign-extended from the top bit of the last byte.
- Position replies (to group 3): 3 bytes of 22-bit two's complement (most significant first,
  top two bits of the first byte unused), or 6 bytes: primary then secondary encoder.
- Full tactile frames (to group 9): 8 bytes, ``seq = d0 >> 4`` (0..4), five 12-bit cells
  starting at cell ``5 * seq``, value = raw / 256; cell 24 (the last of seq 4) does not exist.

Every decoder raises `FrameError` (a `ValueError`) for a frame it cannot take, and nothing
else. Property ids depend on the puck's firmware version (`property_ids`), as libbarrett's
generated property list does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

HOST_ID = 0
GROUP_FLAG = 0x400
FROM_MASK = 0x3E0
TO_MASK = 0x41F
NODE_MASK = 0x1F

F1, F2, F3, SPREAD = 11, 12, 13, 14
HAND_PUCKS = (F1, F2, F3, SPREAD)
PUCK_NAMES = {
    F1: "F1 (puck 11)",
    F2: "F2 (puck 12)",
    F3: "F3 (puck 13)",
    SPREAD: "spread (puck 14)",
}
GROUP_ALL = 0x400  # broadcast to the whole bus
GROUP_HAND = 0x405  # pucks 11-14

FGRP_POSITION = 3
FGRP_PROPERTY = 6
FGRP_TACT_TOP10 = 8
FGRP_TACT_FULL = 9

# STAT values, CMD values, MODE values, TACT values.
STATUS_RESET, STATUS_READY = 0, 2
CMD_HI, CMD_CLOSE, CMD_MOVE, CMD_OPEN = 13, 18, 19, 20
MODE_IDLE, MODE_TORQUE, MODE_PID, MODE_VELOCITY, MODE_TRAPEZOIDAL = 0, 2, 3, 4, 5
TACT_NONE, TACT_TOP10, TACT_FULL, TACT_TARE = 0, 1, 2, 3

# ROLE: low 5 bits the product, option bits above.
ROLE_MASK = 0x1F
ROLE_BHAND = 5
RO_STRAIN = 0x0800
RO_TACT = 0x1000

TACT_CELLS = 24
TACT_FRAMES = 5
TACT_SCALE = 256.0
TACT_MAX = 4095 / TACT_SCALE


class FrameError(ValueError):
    """A CAN frame this codec cannot take; `reason` says why in one word."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class FirmwareError(ValueError):
    """A puck firmware version this driver has no property ids for."""


# -- ids --------------------------------------------------------------------------------


def encode_bus_id(src: int, dst: int) -> int:
    """The 11-bit id of a frame from node `src` to node or group `dst` (a group has 0x400)."""
    if not 0 <= src <= NODE_MASK:
        raise ValueError(f"sender {src} is not a node id (0..31)")
    if dst & ~TO_MASK:
        raise ValueError(f"receiver {dst:#x} is neither a node (0..31) nor a group (0x400..)")
    return ((src & NODE_MASK) << 5) | (dst & TO_MASK)


def node_id(node: int) -> int:
    """The id of a frame from the host to `node` (or to a group such as 0x405)."""
    return encode_bus_id(HOST_ID, node)


def reply_id(node: int, group: int) -> int:
    """The id of a reply from `node` to feedback group `group`."""
    return encode_bus_id(node, GROUP_FLAG | group)


@dataclass(frozen=True)
class BusId:
    src: int
    dst: int  # node id, or group number when `group`
    group: bool


def decode_bus_id(arbitration_id: int) -> BusId:
    if not 0 <= arbitration_id <= 0x7FF:
        raise FrameError("id", f"CAN id {arbitration_id:#x} is not 11-bit")
    return BusId(
        src=(arbitration_id & FROM_MASK) >> 5,
        dst=arbitration_id & NODE_MASK,
        group=bool(arbitration_id & GROUP_FLAG),
    )


# -- property frames --------------------------------------------------------------------


def encode_get(prop: int) -> bytes:
    if not 0 <= prop <= 0x7F:
        raise ValueError(f"property id {prop} out of 0..127")
    return bytes([prop])


def encode_set(prop: int, value: int) -> bytes:
    """A 32-bit SET: ``[0x80|prop, 0, b0, b1, b2, b3]`` (value little-endian)."""
    if not 0 <= prop <= 0x7F:
        raise ValueError(f"property id {prop} out of 0..127")
    v = int(value)
    if not -(2**31) <= v < 2**32:
        raise ValueError(f"value {v} does not fit 32 bits")
    return bytes([0x80 | prop, 0]) + (v & 0xFFFFFFFF).to_bytes(4, "little")


def decode_property(data: bytes) -> tuple[int, int]:
    """(property id, value) of a property reply (or of a SET frame)."""
    n = len(data)
    if n not in (4, 6):
        raise FrameError("length", f"property reply of {n} bytes (expected 4 or 6)")
    if not data[0] & 0x80:
        raise FrameError("not_set", "property reply without the SET bit")
    if data[1] != 0:
        raise FrameError("byte1", f"property reply's second byte is {data[1]} (expected 0)")
    raw = int.from_bytes(bytes(data[2:]), "little")
    bits = 8 * (n - 2)
    if raw & (1 << (bits - 1)):
        raw -= 1 << bits
    return data[0] & 0x7F, raw


def _twenty_two(b0: int, b1: int, b2: int) -> int:
    v = ((b0 & 0x3F) << 16) | (b1 << 8) | b2
    return v - (1 << 22) if v & 0x200000 else v


def decode_position(data: bytes) -> tuple[int, int | None]:
    """(primary counts, secondary counts or None) of a position reply (group 3)."""
    n = len(data)
    if n == 3:
        return _twenty_two(data[0], data[1], data[2]), None
    if n == 6:
        return _twenty_two(data[0], data[1], data[2]), _twenty_two(data[3], data[4], data[5])
    raise FrameError("length", f"position reply of {n} bytes (expected 3 or 6)")


def decode_tactile(data: bytes) -> tuple[int, np.ndarray]:
    """(seq, raw 12-bit cells (5,) as int) of one full-format tactile frame."""
    if len(data) != 8:
        raise FrameError("length", f"tactile frame of {len(data)} bytes (expected 8)")
    seq = data[0] >> 4
    if seq >= TACT_FRAMES:
        raise FrameError("seq", f"tactile frame sequence {seq} (expected 0..4)")
    d = data
    cells = np.array(
        [
            ((d[0] & 0x0F) << 8) | d[1],
            (d[2] << 4) | (d[3] >> 4),
            ((d[3] & 0x0F) << 8) | d[4],
            (d[5] << 4) | (d[6] >> 4),
            ((d[6] & 0x0F) << 8) | d[7],
        ],
        dtype=np.int64,
    )
    return seq, cells


class TactileAssembler:
    """Joins one puck's five full-format frames into its 24 cells (value = raw / 256). A
    set is complete when all five sequence numbers arrived since the last complete set; a
    frame whose seq was already seen starts a new set (the old one was incomplete)."""

    def __init__(self) -> None:
        self._raw = np.zeros(TACT_FRAMES * 5, dtype=np.int64)
        self._seen: set[int] = set()
        self.incomplete = 0  # sets abandoned with frames missing

    def add(self, data: bytes) -> np.ndarray | None:
        seq, cells = decode_tactile(data)
        if seq in self._seen:
            self.incomplete += 1
            self._seen.clear()
        self._raw[5 * seq : 5 * seq + 5] = cells
        self._seen.add(seq)
        if len(self._seen) == TACT_FRAMES:
            self._seen.clear()
            return self._raw[:TACT_CELLS].astype(np.float64) / TACT_SCALE
        return None


# -- property ids by firmware version ---------------------------------------------------


@dataclass(frozen=True)
class PropertyIds:
    """The ids of the motor-puck properties this driver uses, for one firmware range
    (-1: the firmware has no such property)."""

    VERS: int = 0
    ROLE: int = 1
    STAT: int = 5
    MODE: int = 8
    SG: int = 25
    CMD: int = 29
    V: int = 44
    P: int = 48
    E: int = 52
    CTS: int = 68
    HOLD: int = 77
    TSTOP: int = 78
    TACT: int = 106
    TACTID: int = 107


# libbarrett's generated property list (src/products/property_list.cpp, PL_Motor rows and the
# version tree of getPropertyIdNoThrow), reduced to the properties above; rows for firmware
# older than 61 have no CMD and are not supported. (first version, ids)
_FIRMWARE_ROWS: tuple[tuple[int, PropertyIds], ...] = (
    (61, PropertyIds(CTS=65, HOLD=-1, TSTOP=75, TACT=-1, TACTID=-1)),
    (64, PropertyIds(CTS=66, HOLD=-1, TSTOP=75, TACT=-1, TACTID=-1)),
    (65, PropertyIds(HOLD=94, TACT=-1, TACTID=-1)),
    (114, PropertyIds(V=106, HOLD=94, TACT=-1, TACTID=-1)),
    (119, PropertyIds(HOLD=94, TACT=-1, TACTID=-1)),
    (132, PropertyIds(TACT=-1, TACTID=-1)),
    (142, PropertyIds(TACTID=-1)),
    (145, PropertyIds()),
)
VERS_ID = 0  # the same in every row: read it first, then look the rest up
ROLE_ID = 1
STAT_ID = 5


def property_ids(vers: int) -> PropertyIds:
    """The property ids of a motor puck with firmware version `vers`."""
    if vers < _FIRMWARE_ROWS[0][0]:
        raise FirmwareError(
            f"puck firmware {vers} is older than {_FIRMWARE_ROWS[0][0]}: no CMD property "
            "(upgrade the puck firmware)"
        )
    ids = _FIRMWARE_ROWS[0][1]
    for first, row in _FIRMWARE_ROWS:
        if vers >= first:
            ids = row
    return ids


# -- conversions (hand.h ratios, protocol facts C.3) ------------------------------------

J2_RATIO = 125.0  # motor rad per inner-link rad
J2_ENCODER_RATIO = 50.0  # secondary-encoder rad per inner-link rad
J3_RATIO = 375.0  # motor rad per outer-link rad before breakaway
SPREAD_RATIO = 17.5
MAX_FINGER_COUNTS = 195000  # pyHand MAX_ENCODER_TICKS
MAX_SPREAD_COUNTS = 36000  # pyHand MAX_SPREAD_TICKS


def counts_per_rad(cts: int) -> float:
    """Motor counts per motor radian from the CTS property (counts per revolution)."""
    if cts <= 0:
        raise ValueError(f"CTS {cts} is not positive")
    return cts / (2.0 * math.pi)


def finger_joints(
    primary: int, secondary: int | None, cpr: float, use_secondary: bool = True
) -> tuple[float, float]:
    """(inner, outer) link angles, rad, of a finger from its encoders (libbarrett's
    Hand::update): with the secondary (breakaway) encoder inner = secondary / 50 and outer =
    primary (1/125 + 1/375) - inner; without it inner = primary / 125, outer = inner / 3,
    which holds only before the TorqueSwitch breaks away."""
    m = primary / cpr
    if use_secondary and secondary is not None:
        inner = secondary / cpr / J2_ENCODER_RATIO
        return inner, m * (1.0 / J2_RATIO + 1.0 / J3_RATIO) - inner
    inner = m / J2_RATIO
    return inner, inner * J2_RATIO / J3_RATIO


def spread_angle(primary: int, cpr: float) -> float:
    return primary / cpr / SPREAD_RATIO


def spread_counts(angle: float, cpr: float) -> int:
    return round(angle * SPREAD_RATIO * cpr)


def finger_counts(inner: float, cpr: float) -> int:
    """Primary counts of a free finger at this inner angle (before breakaway)."""
    return round(inner * J2_RATIO * cpr)
