"""What counts as a contact in a recognition: the hand's readings at rest (rest levels,
stuck and dead sensors, the calibration's flags that mask a sensor), contact thresholds from
the measured noise, and a grasp's contacts decided again after the close (confirmed by the
next readings, or on their mean). Pure functions on readings; the session (`session/loop.py`)
reads the hand and applies them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from activetouch.interfaces import N_SENSORS, Grasp


def without_sensors(grasp: Grasp, sensor_ids: np.ndarray) -> Grasp:
    """`grasp` without the contacts of `sensor_ids`."""
    return grasp.only(~np.isin(grasp.sensor_ids, sensor_ids))


def above_thresholds(grasp: Grasp, thresholds: np.ndarray) -> Grasp:
    """`grasp` without the contacts at or under their sensor's threshold (38 values)."""
    keep = grasp.pressures > thresholds[grasp.sensor_ids]
    if keep.all():
        return grasp
    return without_sensors(grasp, grasp.sensor_ids[~keep])


def confirmed(
    grasp: Grasp, pressures: np.ndarray, contact: np.ndarray, thresholds: np.ndarray | None
) -> Grasp:
    """`grasp` without the contacts that did not last: those whose sensor is not in contact
    in every one of the (n, sensors) readings taken after the close, the fingers still on the
    object (over `thresholds` where the session set them, else the hand's own flags). A spike
    does not outlast its packet; a touch does. No readings: `grasp` as it is."""
    p = np.asarray(pressures, dtype=np.float64)
    if p.ndim != 2 or len(p) == 0 or not len(grasp.sensor_ids):
        return grasp
    held = (p > thresholds).all(axis=0) if thresholds is not None else contact.all(axis=0)
    ids = grasp.sensor_ids
    inside = ids < len(held)
    lasted = np.zeros(len(ids), dtype=bool)
    lasted[inside] = held[ids[inside]]
    return grasp if lasted.all() else without_sensors(grasp, ids[~lasted])


@dataclass(frozen=True)
class RestLevels:
    """What the sensors read with the hand open: per-sensor mean and standard deviation of
    the pressures, and the fraction of readings in contact."""

    mean: np.ndarray  # (38,)
    std: np.ndarray  # (38,)
    contact: np.ndarray  # (38,) in 0..1
    readings: int


def rest_levels(pressures: np.ndarray, contact: np.ndarray) -> RestLevels:
    """From (n, 38) pressures and contact flags read at rest."""
    p = np.asarray(pressures, dtype=np.float64)
    c = np.asarray(contact, dtype=bool)
    std = p.std(axis=0, ddof=1) if len(p) > 1 else np.zeros(p.shape[1])
    return RestLevels(p.mean(axis=0), std, c.mean(axis=0), len(p))


def dead_at_rest(rest: RestLevels) -> np.ndarray:
    """Sensors that read exactly the same value in every rest reading while most sensors
    show their noise: dead (a hand whose readings are all flat, like a fake one, has none)."""
    if rest.readings < 5 or np.mean(rest.std > 0) < 0.75:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero((rest.std == 0) & (rest.contact == 0)).astype(np.int64)


# The tactile calibration's flags that mask a sensor in recognition ("drifting" sensors keep
# working: their threshold already carries the drift).
MASKING_FLAGS = ("dead", "saturated", "noisy")


def mask_reasons(
    flags: dict[int, str], rest: RestLevels, n_sensors: int = N_SENSORS
) -> dict[int, str]:
    """Sensor id -> why it is ignored this recognition, in ascending id order."""
    why = {int(i): f"{f} (tactile calibration)" for i, f in flags.items() if f in MASKING_FLAGS}
    for i in np.flatnonzero(rest.contact > 0.5):
        why.setdefault(int(i), "in contact with the hand open")
    for i in dead_at_rest(rest):
        why.setdefault(int(i), "reads nothing at rest (dead)")
    return {i: why[i] for i in sorted(why) if 0 <= i < n_sensors}


def noise_sigma(rest: RestLevels) -> np.ndarray:
    """Each sensor's noise sigma at rest, at least the median over the sensors, so a few
    readings that happen to agree do not give one sensor a hair trigger."""
    return np.maximum(rest.std, float(np.median(rest.std)))


def noise_thresholds(rest: RestLevels, k: float) -> np.ndarray:
    """Per-sensor contact thresholds: the rest level plus `k` sigma (`noise_sigma`)."""
    return rest.mean + float(k) * noise_sigma(rest)


# A sensor's rest level has walked when the mean of new readings at rest is further from the
# start's than this many standard errors.
WALK_SE = 3.0


def zero_walk(rest: RestLevels, pressures: np.ndarray, touched: np.ndarray) -> np.ndarray:
    """(n,) how far each sensor's zero has walked since `rest` was read: the mean of the new
    rest readings `pressures` (k, n) against `rest.mean`, where beyond `WALK_SE` standard
    errors of that mean (else 0: a hand that has not drifted keeps its thresholds exactly);
    0 for the sensors `touched` (in contact: no zero to read)."""
    walk = pressures.mean(axis=0) - rest.mean
    walk[touched] = 0.0
    walk[np.abs(walk) <= WALK_SE * noise_sigma(rest) / np.sqrt(len(pressures))] = 0.0
    return walk


def mean_thresholds(rest: RestLevels, k: float, n: int, own: np.ndarray) -> np.ndarray:
    """Per-sensor thresholds for the mean of `n` readings: `noise_thresholds` with the mean's
    sigma (a reading's over sqrt(n)), never under the hand's own threshold `own`."""
    return np.maximum(noise_thresholds(rest, float(k) / np.sqrt(max(1, int(n)))), own)


def mean_contacts(
    grasp: Grasp, pressures: np.ndarray, thresholds: np.ndarray, sites: np.ndarray
) -> Grasp:
    """`grasp` with its contacts decided on the mean of the (n, sensors) `pressures` read
    after the close: the sensors whose mean is over `thresholds`, at `sites` (sensors, 3),
    with their mean pressures; the finger angles and preshape stay the close's."""
    mean = np.asarray(pressures, dtype=np.float64).mean(axis=0)
    ids = np.flatnonzero(mean > thresholds).astype(np.int64)
    return Grasp(
        sensor_ids=ids,
        xyz=np.asarray(sites, dtype=np.float64)[ids].reshape(-1, 3),
        pressures=mean[ids],
        finger_angles=grasp.finger_angles,
        preshape=grasp.preshape,
    )
