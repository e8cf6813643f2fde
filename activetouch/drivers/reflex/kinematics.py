"""Raw servo / encoder / load values to joint angles and back.

Conventions of reflex-ros-pkg's ``reflex_driver_node.cpp`` (protocol facts B.2, B.3):
- motor (spool) angle = inversion * (raw * scale / gear ratio - zero), scale = 4 * 2π / 4095
  rad per tick (the firmware sets resolution divider 4);
- proximal angle from the 14-bit finger encoder, unwrapped across 16383 -> 0; the driver at
  HEAD uses ``encoder_zero - counts * scale`` (an older one the opposite sign): `encoder_sign`;
- distal ≈ max(0, motor - proximal) (the tendon spooled beyond the proximal joint);
- load: raw > 1023 -> raw - 1023, else -raw (upstream's, not the servo's bit-10 sign), times
  the motor inversion; speeds the other way, to the MX-28's moving-speed units.

Contact sites from these joint angles are `activetouch.models.reflex.sensor_positions`, the
kinematics the twin uses, so grasps from the hardware and the twin are in one frame.
"""

from __future__ import annotations

import math

import numpy as np

DYN_POS_SCALE = 4.0 * 2.0 * math.pi / 4095.0  # rad per tick, resolution divider 4
ENC_COUNTS = 16383
ENC_SCALE = 2.0 * math.pi / ENC_COUNTS  # rad per count, 14-bit
ENC_WRAP_JUMP = 5000  # a jump larger than this between packets is a wrap (ROS driver)
MX28_SCALE = 2.0 * math.pi / 4096.0  # rad per tick, MX-28 without a resolution divider


def motor_angle(
    raw: np.ndarray,
    gear: np.ndarray,
    inverted: np.ndarray,
    zero: np.ndarray,
    scale: float = DYN_POS_SCALE,
) -> np.ndarray:
    """Joint-side spool angle, rad, of raw servo positions."""
    return np.asarray(inverted) * (np.asarray(raw, dtype=np.float64) * scale / gear - zero)


def motor_raw(
    angle: np.ndarray,
    gear: np.ndarray,
    inverted: np.ndarray,
    zero: np.ndarray,
    scale: float = DYN_POS_SCALE,
    hi: int = 0xFFFF,
) -> np.ndarray:
    """Raw servo goal positions for joint-side spool angles (rounded, clamped to 0..hi)."""
    raw = (np.asarray(inverted) * np.asarray(angle, dtype=np.float64) + zero) * gear / scale
    return np.clip(np.rint(raw), 0, hi).astype(np.int64)


def load_from_raw(raw: np.ndarray, inverted: np.ndarray) -> np.ndarray:
    """Signed load of raw present-load values, as reflex-ros-pkg: raw > 1023 -> raw - 1023,
    else -raw; times the motor inversion (before the EMA)."""
    raw = np.asarray(raw, dtype=np.float64)
    return np.asarray(inverted) * np.where(raw > 1023, raw - 1023, -raw)


DXL_SPEED_UNIT = 0.01194  # rad/s per moving-speed unit (MX-28: 0.114 rpm)


def speed_raw(rad_s: float, gear: float, inverted: int) -> int:
    """A joint speed as the MX-28 moving-speed value the firmware writes in VELOCITY mode:
    |speed| * gear / 0.01194 rad/s per unit, at most 1023, +1024 for the reverse sense, never
    0 (0 means "no limit" to the servo), as reflex-ros-pkg's speed_rad_to_raw."""
    cmd = min(1023, int(abs(rad_s) * gear / DXL_SPEED_UNIT))
    if inverted * rad_s < 0:
        cmd += 1024
    return max(1, cmd)


class EncoderUnwrapper:
    """Turns 14-bit encoder counts into continuous counts (the ROS driver's offset logic)."""

    def __init__(self, n: int = 3) -> None:
        self.offset = np.zeros(n, dtype=np.int64)
        self.last: np.ndarray | None = None

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        raw = np.asarray(raw, dtype=np.int64)
        if self.last is not None:
            jump = self.last - raw
            self.offset += np.where(jump > ENC_WRAP_JUMP, ENC_COUNTS, 0)
            self.offset -= np.where(jump < -ENC_WRAP_JUMP, ENC_COUNTS, 0)
        self.last = raw.copy()
        return raw + self.offset


def proximal_angle(counts: np.ndarray, zero: np.ndarray, sign: float = -1.0) -> np.ndarray:
    """Proximal joint angle, rad, from unwrapped encoder counts: sign * (counts*scale - zero).
    sign -1 is reflex-ros-pkg HEAD (``zero - counts*scale``), +1 its older driver."""
    return sign * (np.asarray(counts, dtype=np.float64) * ENC_SCALE - np.asarray(zero))


def distal_approx(motor: np.ndarray, proximal: np.ndarray) -> np.ndarray:
    """The driver's distal estimate: tendon spooled beyond the proximal joint, never < 0."""
    return np.maximum(0.0, np.asarray(motor) - np.asarray(proximal))
