"""Finger zero calibration of a ReFlex TakkTile: where each tendon becomes taut.

The servos have no absolute zero (multi-turn, re-based at power-up) and the tendons may be
slack. reflex-ros-pkg's ``calibrate_fingers`` (protocol facts B.2) steps each finger's servo
6 ticks every 0.05 s until its proximal encoder has moved 0.05 rad, then takes that servo
position minus 50 ticks as the zero: the zero depends on the step size and on how far past the
taut point the encoder threshold was crossed. Here, for every finger at once:

1. the encoder baseline (fingers open, slack) is the median of a few readings: the new
   encoder zero makes that read 0;
2. each finger's servo is stepped `step_rad` (joint side) per reading, waiting until it gets
   there, recording (spool, proximal), until the proximal has moved `detect_rad`;
3. a line fitted to the moving readings meets the baseline at the taut point, which becomes
   the motor zero (spool 0 = tendon just taut), independent of the step size;
4. the servos go back to the new zero.

Refusals (the servos are sent back to where they started, nothing stored): a finger whose
servo stops following its command (blocked: something holds the finger, or the tendon is
jammed), whose load passes `overload`, whose encoder has not moved after `max_travel_rad` of
spool (disconnected encoder or broken tendon), or the whole procedure exceeding `timeout_s`.
Only the three finger servos are calibrated; the preshape servo keeps its configured zero.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from activetouch.calibration.store import CalibrationRecord
from activetouch.calibration.tactile import CalibrationRefusedError
from activetouch.errors import ActiveTouchError
from activetouch.interfaces import N_FINGERS, Hand


@dataclass
class FingerSettings:
    step_rad: float = 0.02  # spool step (joint side) per reading
    detect_rad: float = 0.06  # proximal movement that ends a finger's search
    fit_min_rad: float = 0.004  # proximal movement for a reading to count as moving
    max_travel_rad: float = 1.5  # spool travel without encoder movement: refused
    follow_tolerance_rad: float = 0.06  # servo further than this behind its command ...
    follow_readings: int = 8  # ... for this many readings: blocked
    arrive_tolerance_rad: float = 0.01
    arrive_readings: int = 4  # at most this many readings per step
    overload: float = 300.0  # |load| (raw units) that counts as blocked
    baseline_readings: int = 5
    timeout_s: float = 20.0
    reading_timeout_s: float = 0.5


class MotorReading(Protocol):
    seq: int
    motor: np.ndarray  # (4,) spool angles (fingers) and preshape, rad, driver convention
    proximal: np.ndarray  # (3,) rad
    load: np.ndarray  # (4,) signed


@runtime_checkable
class FingerCalibratable(Protocol):
    """What finger calibration needs from a hand driver (the TakkTile driver satisfies it;
    calibration imports no driver)."""

    inverted: np.ndarray  # (4,)
    gear: np.ndarray  # (4,)
    encoder_sign: float
    motor_zero: np.ndarray  # (4,) joint-side zeros (raw * scale / gear), as configured now
    encoder_zero: np.ndarray  # (3,)

    def read_motors(self, after_seq: int, timeout_s: float) -> MotorReading: ...

    def command_motors(self, targets: np.ndarray) -> None: ...

    def set_finger_zeros(self, motor_zero: np.ndarray, encoder_zero: np.ndarray) -> None: ...


class MotorLink(Protocol):
    """The link the search runs on (a `HandMotorLink`, or a test double)."""

    inverted: np.ndarray
    gear: np.ndarray
    encoder_sign: float

    @property
    def motor_zero(self) -> np.ndarray: ...

    @property
    def encoder_zero(self) -> np.ndarray: ...

    def read(self, after_seq: int, timeout_s: float) -> MotorReading: ...

    def command(self, targets: np.ndarray) -> None: ...

    def set_zero(self, motor_zero: np.ndarray, encoder_zero: np.ndarray) -> None: ...


class HandMotorLink:
    """`MotorLink` over any hand driver that is `FingerCalibratable` (public calls only)."""

    def __init__(self, hand: Hand) -> None:
        if not isinstance(hand, FingerCalibratable):
            raise ActiveTouchError(
                f"finger calibration needs a hand with proximal encoders and a motor link "
                f"(a ReFlex TakkTile); this hand is a {type(hand).__name__}"
            )
        self.hand = hand
        self.inverted = np.asarray(hand.inverted, dtype=np.float64)
        self.gear = np.asarray(hand.gear, dtype=np.float64)
        self.encoder_sign = float(hand.encoder_sign)

    @property
    def motor_zero(self) -> np.ndarray:
        return np.asarray(self.hand.motor_zero, dtype=np.float64).copy()

    @property
    def encoder_zero(self) -> np.ndarray:
        return np.asarray(self.hand.encoder_zero, dtype=np.float64).copy()

    def read(self, after_seq: int, timeout_s: float) -> MotorReading:
        return self.hand.read_motors(after_seq, timeout_s)

    def command(self, targets: np.ndarray) -> None:
        self.hand.command_motors(np.asarray(targets, dtype=np.float64))

    def set_zero(self, motor_zero: np.ndarray, encoder_zero: np.ndarray) -> None:
        self.hand.set_finger_zeros(motor_zero, encoder_zero)


@dataclass
class FingerFit:
    motor_zero: np.ndarray  # (4,) new motor zeros (preshape unchanged)
    encoder_zero: np.ndarray  # (3,)
    taut_spool: np.ndarray  # (3,) taut point in the old convention, rad
    slope: np.ndarray  # (3,) d proximal / d spool past the taut point
    fit_points: np.ndarray  # (3,) readings in each line fit
    fit_rms: np.ndarray  # (3,) rad
    travel: np.ndarray  # (3,) spool travelled before detection, rad
    duration_s: float


def taut_point(
    spool: np.ndarray, proximal: np.ndarray, baseline: float, fit_min: float
) -> tuple[float, float, int, float]:
    """Spool angle where the proximal leaves `baseline`: a line through the moving readings
    (proximal - baseline > fit_min) meeting the baseline. (taut, slope, n points, rms)."""
    spool = np.asarray(spool, dtype=np.float64)
    moved = np.asarray(proximal, dtype=np.float64) - baseline
    sel = moved > fit_min
    if sel.sum() >= 2 and np.ptp(spool[sel]) > 1e-6:
        a, b = np.polyfit(spool[sel], moved[sel], 1)
        if a > 1e-3:
            rms = float(np.sqrt(np.mean((a * spool[sel] + b - moved[sel]) ** 2)))
            return float(-b / a), float(a), int(sel.sum()), rms
    # Too few moving readings: the last still reading bounds the taut point from below.
    still = spool[~sel]
    return float(still.max() if len(still) else spool.min()), float("nan"), int(sel.sum()), 0.0


def find_finger_zeros(link: MotorLink, settings: FingerSettings) -> FingerFit:
    """Run the search (see the module) on a live link; restores the servos on a refusal."""
    st = settings
    t0 = time.monotonic()
    r = link.read(-1, st.reading_timeout_s)
    readings = [r]
    for _ in range(st.baseline_readings - 1):
        r = link.read(r.seq, st.reading_timeout_s)
        readings.append(r)
    base_prox = np.median(np.stack([x.proximal for x in readings]), axis=0)
    start = np.median(np.stack([x.motor for x in readings]), axis=0)
    targets = start.copy()
    active = np.ones(N_FINGERS, dtype=bool)
    lag = np.zeros(N_FINGERS, dtype=int)
    log_spool: list[list[float]] = [[] for _ in range(N_FINGERS)]
    log_prox: list[list[float]] = [[] for _ in range(N_FINGERS)]

    def refuse(why: str) -> None:
        try:
            link.command(start)
        finally:
            raise CalibrationRefusedError(f"finger calibration refused: {why}")

    while active.any():
        if time.monotonic() - t0 > st.timeout_s:
            refuse(f"not done within {st.timeout_s:g} s (fingers {np.flatnonzero(active)})")
        targets[:N_FINGERS] = np.where(active, targets[:N_FINGERS] + st.step_rad, targets[:3])
        link.command(targets)
        for _ in range(st.arrive_readings):
            r = link.read(r.seq, st.reading_timeout_s)
            err = np.abs(targets[:N_FINGERS] - r.motor[:N_FINGERS])
            if np.all(err[active] <= st.arrive_tolerance_rad):
                break
        for f in range(N_FINGERS):
            log_spool[f].append(float(r.motor[f]))
            log_prox[f].append(float(r.proximal[f]))
        for f in np.flatnonzero(active).tolist():
            if r.proximal[f] - base_prox[f] >= st.detect_rad:
                active[f] = False
                continue
            behind = targets[f] - r.motor[f]
            lag[f] = lag[f] + 1 if behind > st.follow_tolerance_rad else 0
            if lag[f] >= st.follow_readings:
                refuse(
                    f"finger {f} is blocked: its servo stays {behind:.2f} rad behind the "
                    "command with the encoder still (clear the fingers and open the hand)"
                )
            if abs(r.load[f]) > st.overload:
                refuse(f"finger {f} is blocked: load {r.load[f]:.0f} > {st.overload:g}")
            if r.motor[f] - start[f] > st.max_travel_rad:
                refuse(
                    f"finger {f}: the encoder did not move in {st.max_travel_rad:g} rad of "
                    "spool travel (encoder cable or tendon?)"
                )
    taut, slope = np.zeros(N_FINGERS), np.zeros(N_FINGERS)
    npts, rms, travel = np.zeros(N_FINGERS, dtype=int), np.zeros(N_FINGERS), np.zeros(N_FINGERS)
    for f in range(N_FINGERS):
        taut[f], slope[f], npts[f], rms[f] = taut_point(
            np.asarray(log_spool[f]), np.asarray(log_prox[f]), float(base_prox[f]), st.fit_min_rad
        )
        travel[f] = max(log_spool[f]) - start[f]
    motor_zero = link.motor_zero.copy()
    motor_zero[:N_FINGERS] = motor_zero[:N_FINGERS] + link.inverted[:N_FINGERS] * taut
    encoder_zero = link.encoder_zero + base_prox / link.encoder_sign
    return FingerFit(
        motor_zero=motor_zero,
        encoder_zero=encoder_zero,
        taut_spool=taut,
        slope=slope,
        fit_points=npts,
        fit_rms=rms,
        travel=travel,
        duration_s=time.monotonic() - t0,
    )


def calibrate_fingers(
    hand: Hand,
    device: str,
    settings: FingerSettings | None = None,
    link: MotorLink | None = None,
    apply: bool = True,
) -> tuple[CalibrationRecord, FingerFit]:
    """Find the finger zeros, (by default) make the driver use them and send the fingers to
    the new open position; the record to store."""
    st = settings or FingerSettings()
    link = link or HandMotorLink(hand)
    before_motor, before_enc = link.motor_zero, link.encoder_zero
    fit = find_finger_zeros(link, st)
    if apply:
        link.set_zero(fit.motor_zero, fit.encoder_zero)
        r = link.read(-1, st.reading_timeout_s)
        target = r.motor.copy()
        target[:N_FINGERS] = 0.0  # open: tendons just taut
        link.command(target)
        # Wait for the fingers to get there: the caller may disconnect next (torque off).
        end = time.monotonic() + st.timeout_s
        while time.monotonic() < end:
            r = link.read(r.seq, st.reading_timeout_s)
            if np.all(np.abs(r.motor[:N_FINGERS]) <= st.arrive_tolerance_rad):
                break
    rec = CalibrationRecord(
        kind="fingers",
        device=device,
        values={
            # Servo-side motor radians (hand.motor_zero_points); motor_zero_rad: joint side.
            "motor_zero_points": [round(float(v), 6) for v in fit.motor_zero * link.gear],
            "motor_zero_rad": [round(float(v), 6) for v in fit.motor_zero],
            "encoder_zero_rad": [round(float(v), 6) for v in fit.encoder_zero],
        },
        quality={
            "correction_motor_rad": [round(float(v), 5) for v in fit.motor_zero - before_motor],
            "correction_encoder_rad": [round(float(v), 5) for v in fit.encoder_zero - before_enc],
            "slope": [round(float(v), 4) for v in fit.slope],
            "fit_points": [int(v) for v in fit.fit_points],
            "fit_rms_rad": [round(float(v), 6) for v in fit.fit_rms],
            "travel_rad": [round(float(v), 4) for v in fit.travel],
            "duration_s": round(fit.duration_s, 2),
        },
        method={
            "procedure": "fingers",
            "motor_order": "finger 0, 1, 2, preshape (preshape zero kept)",
            "zero": "taut point: line through (spool, proximal) readings after the encoder "
            "moved, met with the open baseline; encoder zero: the open baseline reads 0",
            "settings": asdict(st),
        },
    )
    return rec, fit


def apply_fingers(hand: Hand, motor_zero: list[float], encoder_zero: list[float]) -> bool:
    """Make a live driver use stored joint-side finger zeros; False for other hands."""
    if isinstance(hand, FingerCalibratable):
        hand.set_finger_zeros(np.asarray(motor_zero, float), np.asarray(encoder_zero, float))
        return True
    return False
