"""Tactile calibration: per-sensor zero offset, noise and contact threshold, with faults flagged.

reflex-ros-pkg's ``calibrate_tactile`` copies one packet's raw values into the offsets: no noise
estimate, and one glitch becomes the zero. Here the hand is open and untouched for
`duration_s` (80 packets at 40 Hz by default) and, per sensor:

- a straight line is fitted over time (drift) and its residuals screened robustly: samples
  further than max(6 MAD, 3 counts) from the median residual are outliers (glitched packets);
- zero = mean of the inliers (at the end of the window for a drifting sensor: what it reads
  now); sigma = their standard deviation about the line;
- threshold = max(minimum, k * sigma) (+ the drift over the window for a drifting sensor);
- flags: ``dead`` (no variation at all, or stuck at 0), ``saturated`` (at the top of the
  range), ``drifting`` (the line moves more than `drift_counts` and 5 standard errors),
  ``noisy`` (sigma over `noisy_factor` times the median of the unflagged sensors). Dead
  and saturated sensors get the disabling threshold `raw_max`, so they never report contact;
  a recognition ignores the dead, saturated and noisy ones (`Hand.sensor_flags`).

Before it stores anything it refuses when something seems to touch the hand: a sensor reading
far above its previous zero, fingers not open, or a stale stream.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from activetouch.calibration.store import CalibrationRecord
from activetouch.errors import ActiveTouchError
from activetouch.interfaces import N_SENSORS, Hand


class CalibrationRefusedError(ActiveTouchError):
    """A procedure would measure garbage (touching, blocked, moving): nothing is stored."""


@dataclass
class TactileSettings:
    duration_s: float = 2.0
    min_samples: int = 30
    k_sigma: float = 6.0
    min_threshold: float = 20.0  # the ReFlex driver's default contact threshold
    raw_max: float = 65535.0  # a uint16 reading; also the disabling threshold
    drift_counts: float = 3.0  # drift over the window must exceed this (and 5 s.e.) to flag
    noisy_factor: float = 5.0  # sigma over this many times the median sigma: noisy
    touch_counts: float = 50.0  # a sensor this far above its previous zero: touching
    touch_thresholds: float = 3.0  # ... or this many of its previous thresholds
    open_tolerance_rad: float = 0.15  # fingers must read within this of open
    poll_s: float = 0.004
    open_first: bool = True


@dataclass
class TactileFit:
    zero: np.ndarray  # (38,) raw counts, package sensor order
    sigma: np.ndarray  # (38,)
    threshold: np.ndarray  # (38,)
    drift: np.ndarray  # (38,) counts over the window
    dead: list[int] = field(default_factory=list)
    saturated: list[int] = field(default_factory=list)
    drifting: list[int] = field(default_factory=list)
    noisy: list[int] = field(default_factory=list)
    outliers: np.ndarray = field(default_factory=lambda: np.zeros(N_SENSORS, dtype=int))
    n_samples: int = 0
    window_s: float = 0.0


def _line_fit(t: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Least-squares (mean, slope) of x(t) about the centred times (t has mean 0)."""
    denom = float(np.dot(t, t))
    slope = float(np.dot(t, x - x.mean()) / denom) if denom > 0 else 0.0
    return float(x.mean()), slope


def fit_sensor(
    t: np.ndarray, x: np.ndarray, raw_max: float, drift_counts: float
) -> tuple[float, float, float, str, int]:
    """One sensor's (zero, sigma, drift over the window, flag, outliers) from samples x at
    times t (s). flag is "", "dead", "saturated" or "drifting"."""
    x = np.asarray(x, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    tc = t - t.mean()
    span = float(t.max() - t.min()) if len(t) > 1 else 0.0
    med = float(np.median(x))
    if med >= raw_max - 0.5:
        return med, 0.0, 0.0, "saturated", 0
    if np.ptp(x) == 0.0 or med <= 0.0:
        return med, float(np.std(x)), 0.0, "dead", 0
    # Robust line: fit, screen residuals by MAD, refit on the inliers.
    _, slope = _line_fit(tc, x)
    keep = np.ones(len(x), dtype=bool)
    for _ in range(2):
        resid = x - slope * tc
        r_med = float(np.median(resid[keep]))
        mad = 1.4826 * float(np.median(np.abs(resid[keep] - r_med)))
        keep = np.abs(resid - r_med) <= max(6.0 * mad, 3.0)
        _, slope = _line_fit(tc[keep], x[keep])
    xi, ti = x[keep], tc[keep]
    mean, slope = _line_fit(ti, xi)
    centre = float(ti.mean())
    resid = xi - (mean + slope * (ti - centre))
    dof = max(1, len(xi) - 2)
    sigma = float(np.sqrt(np.sum(resid**2) / dof))
    drift = slope * span
    denom = float(np.sum((ti - centre) ** 2))
    se = sigma * span / np.sqrt(denom) if denom > 0 else np.inf
    if abs(drift) > drift_counts and abs(drift) > 5.0 * se:
        zero = mean + slope * (float(tc.max()) - centre)  # what it reads now
        return zero, sigma, drift, "drifting", int((~keep).sum())
    # Not drifting: the zero is the plain mean of the inliers (the sampling mean).
    sigma0 = float(np.std(xi, ddof=1)) if len(xi) > 1 else 0.0
    return float(xi.mean()), sigma0, drift, "", int((~keep).sum())


def fit_tactile(t: np.ndarray, samples: np.ndarray, settings: TactileSettings) -> TactileFit:
    """Zero, sigma, threshold and flags of every sensor from raw `samples` (n, 38) at `t`."""
    samples = np.asarray(samples, dtype=np.float64)
    n, m = samples.shape
    if n < max(2, settings.min_samples):
        raise CalibrationRefusedError(
            f"tactile: only {n} samples in {settings.duration_s:g} s "
            f"(need {settings.min_samples}); is the hand streaming?"
        )
    zero, sigma, drift = np.zeros(m), np.zeros(m), np.zeros(m)
    outliers = np.zeros(m, dtype=int)
    flags: dict[str, list[int]] = {"dead": [], "saturated": [], "drifting": []}
    for i in range(m):
        z, s, d, flag, nout = fit_sensor(t, samples[:, i], settings.raw_max, settings.drift_counts)
        zero[i], sigma[i], drift[i], outliers[i] = z, s, d, nout
        if flag:
            flags[flag].append(i)
    flagged = set(flags["dead"] + flags["saturated"] + flags["drifting"])
    good = [i for i in range(m) if i not in flagged]
    typical = float(np.median(sigma[good])) if good else 0.0
    noisy = [
        i for i in good if typical > 0 and sigma[i] > settings.noisy_factor * max(typical, 0.5)
    ]
    threshold = np.maximum(settings.min_threshold, settings.k_sigma * sigma)
    threshold[flags["drifting"]] += np.abs(drift[flags["drifting"]])
    disabled = flags["dead"] + flags["saturated"]
    threshold[disabled] = settings.raw_max
    drift[disabled] = 0.0
    return TactileFit(
        zero=zero,
        sigma=sigma,
        threshold=threshold,
        drift=drift,
        dead=flags["dead"],
        saturated=flags["saturated"],
        drifting=flags["drifting"],
        noisy=noisy,
        outliers=outliers,
        n_samples=n,
        window_s=float(np.ptp(t)) if n > 1 else 0.0,
    )


def touching_reasons(
    median_raw: np.ndarray,
    finger_angles: np.ndarray,
    settings: TactileSettings,
    previous_zero: np.ndarray | None = None,
    previous_threshold: np.ndarray | None = None,
    ignore: list[int] | None = None,
) -> list[str]:
    """Why the hand seems not free (empty: it is): sensors far above their previous zero,
    fingers away from open."""
    out: list[str] = []
    if previous_zero is not None:
        prev_thr = (
            np.zeros(len(previous_zero)) if previous_threshold is None else previous_threshold
        )
        limit = np.maximum(settings.touch_counts, settings.touch_thresholds * prev_thr)
        above = np.asarray(median_raw) - np.asarray(previous_zero)
        bad = [i for i in np.flatnonzero(above > limit).tolist() if i not in (ignore or [])]
        if bad:
            worst = max(bad, key=lambda i: above[i])
            out.append(
                f"{len(bad)} sensor(s) read far above their previous zero (sensor {worst}: "
                f"+{above[worst]:.0f} counts): is something touching the hand?"
            )
    fa = np.asarray(finger_angles, dtype=np.float64)
    closed = np.flatnonzero(np.abs(fa) > settings.open_tolerance_rad).tolist()
    if closed:
        angles = ", ".join(f"{f}: {fa[f]:.2f} rad" for f in closed)
        out.append(f"fingers not open ({angles}); open the hand and clear it")
    return out


# -- talking to a hand ----------------------------------------------------------------------


def hand_offsets(hand: Hand) -> np.ndarray:
    """The zero offsets a hand subtracts from raw readings (0 for the twin)."""
    off = getattr(hand, "offsets", None)
    return np.zeros(N_SENSORS) if off is None else np.asarray(off, dtype=np.float64).copy()


def hand_thresholds(hand: Hand) -> np.ndarray | None:
    thr = getattr(hand, "thresholds", None)
    return None if thr is None else np.asarray(thr, dtype=np.float64).copy()


def sample_raw(hand: Hand, duration_s: float, poll_s: float = 0.004) -> tuple[np.ndarray, ...]:
    """Raw readings (pressure + the hand's current offset) of every new state for
    `duration_s`: (t (n,), raw (n, 38), finger_angles (3,) median). A stale stream refuses."""
    offsets = hand_offsets(hand)
    ts: list[float] = []
    rows: list[np.ndarray] = []
    angles: list[np.ndarray] = []
    last = None
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        s = hand.state()
        if getattr(s, "stale", False):
            raise CalibrationRefusedError("tactile: the hand's state stream is stale (no packets)")
        key = (s.stamp, getattr(s, "systime_us", 0))
        if key != last:
            last = key
            ts.append(float(s.stamp))
            rows.append(np.asarray(s.pressures, dtype=np.float64) + offsets)
            angles.append(np.asarray(s.finger_angles, dtype=np.float64))
        time.sleep(poll_s)
    if not rows:
        return np.zeros(0), np.zeros((0, N_SENSORS)), np.zeros(3)
    return np.asarray(ts), np.stack(rows), np.median(np.stack(angles), axis=0)


def rec_flags(fit: TactileFit) -> dict[str, list[int]]:
    """The fit's flags as stored: flag -> sensor ids."""
    return {
        "dead": fit.dead,
        "saturated": fit.saturated,
        "drifting": fit.drifting,
        "noisy": fit.noisy,
    }


def flags_by_sensor(flags: dict[str, list[int]] | None) -> dict[int, str]:
    """Stored flags (flag -> ids) as sensor id -> flag; unknown flags (a newer file's, or
    upstream's ``not_imported``) are kept under their own names."""
    out: dict[int, str] = {}
    for flag, ids in (flags or {}).items():
        for i in ids:
            out.setdefault(int(i), str(flag))
    return dict(sorted(out.items()))


def apply_tactile(
    hand: Hand,
    zero: np.ndarray,
    threshold: np.ndarray,
    flags: dict[str, list[int]] | None = None,
) -> bool:
    """Make a live driver use these offsets and thresholds (the ReFlex TakkTile driver reads
    them on every packet) and know the flagged sensors. False if the hand has no such
    settings (the twin)."""
    setter = getattr(hand, "set_tactile_calibration", None)
    if setter is not None:
        setter(
            np.asarray(zero, dtype=np.float64),
            np.asarray(threshold, dtype=np.float64),
            flags=flags_by_sensor(flags),
        )
        wait_new_states(hand, 2)  # readings decoded before now still hold the old zero
        return True
    if hasattr(hand, "offsets") and hasattr(hand, "thresholds"):
        hand.offsets = np.asarray(zero, dtype=np.float64).copy()  # type: ignore[attr-defined]
        hand.thresholds = np.asarray(threshold, dtype=np.float64).copy()  # type: ignore[attr-defined]
        wait_new_states(hand, 2)  # readings decoded before now still hold the old zero
        return True
    return False


def wait_new_states(hand: Hand, n: int, timeout_s: float = 0.5, poll_s: float = 0.003) -> None:
    """Return once `n` states newer than now have arrived (or after `timeout_s`)."""
    last = hand.state().stamp
    seen = 0
    end = time.monotonic() + timeout_s
    while seen < n and time.monotonic() < end:
        time.sleep(poll_s)
        s = hand.state().stamp
        if s != last:
            seen, last = seen + 1, s


def read_states(
    hand: Hand, n: int, timeout_s: float = 2.0, poll_s: float = 0.002
) -> tuple[np.ndarray, np.ndarray]:
    """Pressures and contact flags, (k, sensors) each, of `n` distinct hand states (new
    stamps: a real hand streams at 40 Hz, so reading it twice at once gives one packet twice);
    a hand that streams slower than asked gives what it gave within `timeout_s`."""
    n = max(1, int(n))
    pressures, contact = [], []
    last = None
    deadline = time.monotonic() + timeout_s
    while len(pressures) < n:
        st = hand.state()
        if st.stamp != last:
            last = st.stamp
            pressures.append(np.asarray(st.pressures, dtype=np.float64))
            contact.append(np.asarray(st.contact, dtype=bool))
        elif time.monotonic() > deadline:
            break
        else:
            time.sleep(poll_s)
    return np.array(pressures), np.array(contact)


def calibrate_tactile(
    hand: Hand,
    device: str,
    settings: TactileSettings | None = None,
    previous: CalibrationRecord | None = None,
) -> tuple[CalibrationRecord, TactileFit]:
    """Measure the hand's tactile zero and thresholds (see the module). Raises
    `CalibrationRefusedError` (nothing measured) when the hand seems touched or not open."""
    st = settings or TactileSettings()
    if st.open_first:
        hand.open()
    t, raw, angles = sample_raw(hand, st.duration_s, st.poll_s)
    if len(raw) == 0:
        raise CalibrationRefusedError("tactile: no state from the hand")
    if previous is not None:
        prev_zero = np.asarray(previous.values["zero"], dtype=np.float64)
        prev_thr = np.asarray(previous.values["threshold"], dtype=np.float64)
        ignore = list(previous.values.get("flags", {}).get("saturated", [])) + list(
            previous.values.get("flags", {}).get("dead", [])
        )
    else:  # the offsets the hand runs with (configured) stand in for a previous zero
        prev_zero, prev_thr, ignore = hand_offsets(hand), hand_thresholds(hand), []
        if not np.any(prev_zero):
            prev_zero = None
    reasons = touching_reasons(np.median(raw, axis=0), angles, st, prev_zero, prev_thr, ignore)
    if reasons:
        raise CalibrationRefusedError("tactile calibration refused: " + "; ".join(reasons))
    fit = fit_tactile(t, raw, st)
    rec = CalibrationRecord(
        kind="tactile",
        device=device,
        values={
            "zero": _rounded(fit.zero, 3),
            "threshold": _rounded(fit.threshold, 3),
            "sigma": _rounded(fit.sigma, 4),
            "drift": _rounded(fit.drift, 3),
            "flags": rec_flags(fit),
        },
        quality={
            "n_samples": fit.n_samples,
            "window_s": round(fit.window_s, 3),
            "sigma_median": round(float(np.median(fit.sigma)), 4),
            "sigma_max": round(float(np.max(fit.sigma)), 4),
            "zero_standard_error_max": round(
                float(np.max(fit.sigma)) / np.sqrt(max(1, fit.n_samples)), 4
            ),
            "outlier_samples": int(fit.outliers.sum()),
            "n_flagged": len(flags_by_sensor(rec_flags(fit))),
        },
        method={
            "procedure": "tactile",
            "sensor_order": "package sensor id: finger f sensor s = 9f + s, palm 27..37",
            "zero": "mean of inliers (|residual - median| <= max(6 MAD, 3 counts)) about a "
            "fitted line; drifting sensors: the line at the window's end",
            "threshold": "max(min_threshold, k_sigma * sigma) + |drift|; dead/saturated: raw_max",
            "settings": asdict(st),
        },
    )
    return rec, fit


def _rounded(a: np.ndarray, nd: int) -> list[float]:
    return [round(float(v), nd) for v in np.asarray(a).reshape(-1)]
