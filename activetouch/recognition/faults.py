"""Tactile sensor faults a real ReFlex has, as pure array transforms of its 38 pressures.

Used by the twin to evaluate recognition under the real robot's errors (docs/benchmark.md):

- noise: extra Gaussian noise on every sensor at every reading (sensor units). Applied to the
  readings the guarded close decides on as well, so a noisy sensor can stop its finger early,
  as on the real hand (its driver stops a finger at the first reading over threshold).
- dead: sensors that always read zero (a broken barometer or wire). Fixed for a run.
- stuck: sensors that always read over threshold (a barometer stuck high, e.g. glue or a
  pinched skin). Fixed for a run; a stuck finger sensor stops that finger before it moves.
- spurious: per grasp, each quiet sensor reports a false contact with this probability (a
  transient spike in the reported reading; too brief to stop a finger, so only the reported
  grasp sees it).
- drift (calibration drift of the sensors): each sensor's zero walks away from where the
  session measured it at the start, at a rate drawn for the run within +-drift units per
  grasp (a barometer's zero moves with temperature), so late grasps read offset pressures.
- finger offset (calibration drift of the fingers): each finger's angle reads off by a fixed
  amount drawn within +-finger_offset_rad (an encoder zero that moved since calibration), so
  the contacts it reports are where that finger would be at the angle it believes.

A run's faulty sensors are drawn from its seed, so a (seed, faults) pair repeats exactly."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from activetouch.interfaces import N_SENSORS

STUCK_FACTOR = 2.0  # a stuck sensor reads this many times the contact threshold
SPURIOUS_FACTOR = 1.5  # a spurious contact's reported pressure, times the threshold
_FAULT_TAG = 0xFA17  # keeps the fault streams apart from the hand's own noise streams


@dataclass(frozen=True)
class SensorFaults:
    noise_std: float = 0.0  # sensor units, added to every reading
    dead: int = 0  # sensors reading zero
    stuck: int = 0  # sensors reading over threshold
    spurious: float = 0.0  # per grasp and quiet sensor, probability of a false contact
    drift: float = 0.0  # sensor units per grasp, the largest rate a sensor's zero walks at
    finger_offset_rad: float = 0.0  # the largest error of a finger's reported angle

    def __post_init__(self) -> None:
        if not (np.isfinite(self.noise_std) and self.noise_std >= 0):
            raise ValueError(f"sensor noise must be >= 0, got {self.noise_std}")
        if not (np.isfinite(self.drift) and self.drift >= 0):
            raise ValueError(f"sensor drift must be >= 0 units per grasp, got {self.drift}")
        if not (np.isfinite(self.finger_offset_rad) and 0 <= self.finger_offset_rad <= 0.5):
            raise ValueError(f"finger offset must be in 0..0.5 rad, got {self.finger_offset_rad}")
        if self.dead < 0 or self.stuck < 0 or self.dead + self.stuck > N_SENSORS:
            raise ValueError(
                f"dead ({self.dead}) and stuck ({self.stuck}) sensors must be >= 0 and at most "
                f"{N_SENSORS} together"
            )
        if not (0.0 <= self.spurious <= 1.0):
            raise ValueError(f"spurious contact probability must be in 0..1, got {self.spurious}")

    @property
    def active(self) -> bool:
        return bool(
            self.noise_std > 0
            or self.dead
            or self.stuck
            or self.spurious > 0
            or self.drift > 0
            or self.finger_offset_rad > 0
        )


@dataclass(frozen=True)
class FaultySensors:
    """Which sensors are dead and stuck in one run (sensor ids, interfaces' numbering)."""

    dead: np.ndarray  # (k,) int
    stuck: np.ndarray  # (m,) int, disjoint from dead
    # (n,) each sensor's zero drift, units per grasp (zeros without drift)
    drift_rate: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # (fingers,) each finger's reported-angle error, radians (zeros without an offset)
    finger_offset: np.ndarray = field(default_factory=lambda: np.zeros(0))


def draw_faulty_sensors(
    faults: SensorFaults, seed: int, n_sensors: int = N_SENSORS, n_fingers: int = 3
) -> FaultySensors:
    """The run's dead and stuck sensors, uniformly among all `n_sensors` (the ReFlex's 38,
    the BH8's 96), its sensors' drift rates and its fingers' angle offsets, from `seed`."""
    if faults.dead + faults.stuck > n_sensors:
        raise ValueError(f"{faults.dead} dead and {faults.stuck} stuck of {n_sensors} sensors")
    order = np.random.default_rng([int(seed), _FAULT_TAG, 1]).permutation(n_sensors)
    # Their own streams: adding drift to a fault set leaves its dead and stuck sensors as
    # they were, so levels pair by seed.
    rate = np.random.default_rng([int(seed), _FAULT_TAG, 3]).uniform(-1.0, 1.0, n_sensors)
    off = np.random.default_rng([int(seed), _FAULT_TAG, 4]).uniform(-1.0, 1.0, n_fingers)
    return FaultySensors(
        dead=np.sort(order[: faults.dead]),
        stuck=np.sort(order[faults.dead : faults.dead + faults.stuck]),
        drift_rate=rate * faults.drift,
        finger_offset=off * faults.finger_offset_rad,
    )


def fault_rng(seed: int) -> np.random.Generator:
    """The run's stream for fault noise and spurious contacts."""
    return np.random.default_rng([int(seed), _FAULT_TAG, 2])


def faulty_reading(
    pressures: np.ndarray,
    faults: SensorFaults,
    sensors: FaultySensors,
    threshold: float,
    rng: np.random.Generator,
    noise_scale: float = 1.0,
    grasps_done: int = 0,
) -> np.ndarray:
    """(n,) pressures as the faulty sensors read them (a new array); the extra noise is
    `faults.noise_std` x `noise_scale` (a hand in other units scales the ReFlex's, and its
    drift likewise); `grasps_done`: grasps since the session measured the zeros."""
    p = np.array(pressures, dtype=np.float64, copy=True).reshape(-1)
    if faults.noise_std > 0:
        p += rng.normal(0.0, faults.noise_std * noise_scale, len(p))
    if faults.drift > 0 and grasps_done > 0:
        p += sensors.drift_rate * (grasps_done * noise_scale)
    p[sensors.dead] = 0.0
    p[sensors.stuck] = STUCK_FACTOR * threshold
    return p


def spurious_contacts(
    in_contact: np.ndarray, faults: SensorFaults, sensors: FaultySensors, rng: np.random.Generator
) -> np.ndarray:
    """Sensor ids that report a false contact in this grasp: quiet, not dead, each with
    probability `faults.spurious`. `in_contact`: (n,) bool, the grasp's real contacts."""
    if faults.spurious <= 0:
        return np.zeros(0, dtype=np.int64)
    quiet = ~np.asarray(in_contact, dtype=bool).reshape(-1)
    quiet[sensors.dead] = False
    hit = rng.random(len(quiet)) < faults.spurious  # drawn for all: the stream stays aligned
    return np.flatnonzero(quiet & hit)
