"""The calibration records a ReFlex TakkTile / Beta hand's driver is handed
(`takktile.ReflexTakktileHand`), read from the store (`activetouch calibrate tactile|fingers`).

Without a stored finger calibration the motor zero points are the public reflex-ros-pkg
calibration's; without a tactile one the driver reports no contacts and refuses to grasp
(unloaded TakkTile sensors read far above the contact threshold).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from activetouch import paths
from activetouch.calibration import store
from activetouch.calibration.tactile import flags_by_sensor

if TYPE_CHECKING:
    pass

log = logging.getLogger(__name__)


# The public finger calibration of reflex-ros-pkg (reflex_driver/yaml/finger_calibrate.yaml,
# motor_zero_reference, in raw * scale / gear) times the gear ratios: servo-side motor radians.
# Used only when neither hand.motor_zero_points nor a stored finger calibration gives them.
UPSTREAM_MOTOR_ZERO_REFERENCE = (59.6108, 56.3347, 58.7118, 55.2246)
UPSTREAM_GEAR = (1.42, 1.42, 1.42, 1.5)
DEFAULT_MOTOR_ZERO_POINTS = tuple(
    round(z * g, 6) for z, g in zip(UPSTREAM_MOTOR_ZERO_REFERENCE, UPSTREAM_GEAR, strict=True)
)


@dataclass(frozen=True)
class TactileZero:
    """A tactile calibration handed to the driver: per-sensor zero and threshold (38,)."""

    zero: np.ndarray
    threshold: np.ndarray
    source: str = ""
    flags: dict[int, str] = field(default_factory=dict)  # sensor id -> calibration flag


@dataclass(frozen=True)
class FingerZero:
    """A finger calibration handed to the driver: servo-side motor zero points (4,) and
    encoder zeros (3,)."""

    motor_zero_points: np.ndarray
    encoder_zero_rad: np.ndarray
    source: str = ""


def stored_calibration(device: str, data: object) -> tuple[TactileZero | None, FingerZero | None]:
    """The stored tactile and finger records of `device` (None where missing; a missing or old
    one is logged with the command that makes it)."""

    root = paths.data_dir(data)  # type: ignore[arg-type]
    out: list[object] = []
    for kind in ("tactile", "fingers"):
        rec = store.load(root, kind, device)
        why = store.staleness(rec, kind)
        if why:
            log.warning("calibration: %s", why)
        if rec is None:
            out.append(None)
            continue
        src = f"{store.record_path(root, kind, device)} (measured {rec.measured_at})"
        v = rec.values
        if kind == "tactile":
            out.append(
                TactileZero(
                    np.asarray(v["zero"], float),
                    np.asarray(v["threshold"], float),
                    src,
                    flags_by_sensor(v.get("flags")),
                )
            )
        elif "motor_zero_points" in v:
            out.append(
                FingerZero(
                    np.asarray(v["motor_zero_points"], float),
                    np.asarray(v["encoder_zero_rad"], float),
                    src,
                )
            )
        else:  # records before motor_zero_points: joint-side zeros (raw * scale / gear)
            gear = np.asarray(UPSTREAM_GEAR)
            out.append(
                FingerZero(
                    np.asarray(v["motor_zero_rad"], float) * gear,
                    np.asarray(v["encoder_zero_rad"], float),
                    src,
                )
            )
    return out[0], out[1]  # type: ignore[return-value]
