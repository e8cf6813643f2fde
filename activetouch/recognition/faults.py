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

A run's faulty sensors are drawn from its seed, so a (seed, faults) pair repeats exactly."""

from __future__ import annotations

from dataclasses import dataclass

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

    def __post_init__(self) -> None:
        if not (np.isfinite(self.noise_std) and self.noise_std >= 0):
            raise ValueError(f"sensor noise must be >= 0, got {self.noise_std}")
        if self.dead < 0 or self.stuck < 0 or self.dead + self.stuck > N_SENSORS:
            raise ValueError(
                f"dead ({self.dead}) and stuck ({self.stuck}) sensors must be >= 0 and at most "
                f"{N_SENSORS} together"
            )
        if not (0.0 <= self.spurious <= 1.0):
            raise ValueError(f"spurious contact probability must be in 0..1, got {self.spurious}")

    @property
    def active(self) -> bool:
        return bool(self.noise_std > 0 or self.dead or self.stuck or self.spurious > 0)


@dataclass(frozen=True)
class FaultySensors:
    """Which sensors are dead and stuck in one run (sensor ids, interfaces' numbering)."""

    dead: np.ndarray  # (k,) int
    stuck: np.ndarray  # (m,) int, disjoint from dead


def draw_faulty_sensors(
    faults: SensorFaults, seed: int, n_sensors: int = N_SENSORS
) -> FaultySensors:
    """The run's dead and stuck sensors, uniformly among all `n_sensors` (the ReFlex's 38,
    the BH8's 96), from `seed`."""
    if faults.dead + faults.stuck > n_sensors:
        raise ValueError(f"{faults.dead} dead and {faults.stuck} stuck of {n_sensors} sensors")
    order = np.random.default_rng([int(seed), _FAULT_TAG, 1]).permutation(n_sensors)
    return FaultySensors(
        dead=np.sort(order[: faults.dead]),
        stuck=np.sort(order[faults.dead : faults.dead + faults.stuck]),
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
) -> np.ndarray:
    """(n,) pressures as the faulty sensors read them (a new array); the extra noise is
    `faults.noise_std` x `noise_scale` (a hand in other units scales the ReFlex's)."""
    p = np.array(pressures, dtype=np.float64, copy=True).reshape(-1)
    if faults.noise_std > 0:
        p += rng.normal(0.0, faults.noise_std * noise_scale, len(p))
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
