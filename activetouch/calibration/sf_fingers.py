"""Finger zero points of a ReFlex SF, as reflex-ros-pkg finds them: the SF has no finger
encoders, so the operator jogs each servo until its finger is open with the tendon just taut,
and the servo's position then (motor radians) is its zero point (``hand.motor_zero_points``,
upstream's ``zero_point``). The record is stored per device and the SF driver loads it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from activetouch.calibration.store import CalibrationRecord
from activetouch.errors import ActiveTouchError

SERVOS = ("finger 1", "finger 2", "finger 3", "preshape")
JOG_STEPS = {"t": 0.05, "T": 0.25, "l": -0.05, "L": -0.25}  # motor rad; + tightens
MAX_JOGS = 400  # per servo: a stuck key or a runaway script ends here


@runtime_checkable
class ZeroPointJoggable(Protocol):
    """What the procedure needs from a hand driver (the SF driver has it)."""

    def motor_positions(self) -> np.ndarray: ...

    def jog(self, servo: int, delta_motor_rad: float) -> np.ndarray: ...

    def set_motor_zero_points(self, zero_points: np.ndarray) -> None: ...


def find_zero_points(
    hand: ZeroPointJoggable, ask: Callable[[int, str, float], str]
) -> tuple[np.ndarray, list[int]]:
    """Jog each servo as `ask(servo, name, position)` says ("t"/"T" tighten, "l"/"L" loosen,
    "" accept) and take its position then; returns the zero points and jogs per servo."""
    zero = np.zeros(len(SERVOS))
    jogs = []
    for k, name in enumerate(SERVOS):
        pos = hand.motor_positions()
        n = 0
        while True:
            key = ask(k, name, float(pos[k])).strip()
            if key == "":
                break
            if key not in JOG_STEPS:
                continue  # the prompt says which keys there are
            n += 1
            if n > MAX_JOGS:
                raise ActiveTouchError(f"fingers: {name}: more than {MAX_JOGS} jogs; stopped")
            pos = hand.jog(k, JOG_STEPS[key])
        zero[k] = pos[k]
        jogs.append(n)
    return zero, jogs


def calibrate_sf_fingers(
    hand: object, device: str, ask: Callable[[int, str, float], str]
) -> CalibrationRecord:
    if not isinstance(hand, ZeroPointJoggable):
        raise ActiveTouchError(
            f"SF finger calibration needs a ReFlex SF driver; this hand is a {type(hand).__name__}"
        )
    before = hand.motor_positions()
    zero, jogs = find_zero_points(hand, ask)
    hand.set_motor_zero_points(zero)
    return CalibrationRecord(
        kind="fingers",
        device=device,
        values={"motor_zero_points": [round(float(v), 6) for v in zero]},
        quality={
            "jogs": jogs,
            "moved_motor_rad": [round(float(v), 4) for v in zero - before],
        },
        method={
            "procedure": "fingers (ReFlex SF)",
            "zero": "each servo jogged by the operator until its finger is open with the "
            "tendon just taut (the preshape: fingers parallel); its position then, in motor "
            "radians, as reflex-ros-pkg's zero_point",
            "servo_order": "ids 1, 2, 3 (fingers), 4 (preshape)",
        },
    )
