"""A lab's reflex-ros-pkg calibration files brought in as calibration records
(`activetouch calibrate import`), so a hand calibrated upstream needs no new calibration.

- ``reflex_sf_motor_zero_points.yaml`` (``reflex_sf_f1: {zero_point: <motor rad>}`` ... f2,
  f3, preshape): the SF's zero points, as they are (``hand.motor_zero_points``).
- ``finger_calibrate.yaml`` (``motor_zero_reference`` [4], joint side, raw x scale / gear;
  ``encoder_zero_reference`` [3]): a TakkTile hand's finger zeros.
- ``tactile_calibrate.yaml`` (``tactile_offset_f1..f3``, 9 counts each): the finger sensors'
  zero offsets. The file has no palm: its 11 sensors are flagged ``not_imported`` and
  disabled (they never report contact) until `calibrate tactile` measures them; the
  threshold is upstream's fixed one (20 counts), not one from measured noise.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Any

import numpy as np

from activetouch.calibration.store import CalibrationRecord
from activetouch.errors import DataError

SF_KEYS = ("reflex_sf_f1", "reflex_sf_f2", "reflex_sf_f3", "reflex_sf_preshape")
TAKKTILE_GEAR = (1.42, 1.42, 1.42, 1.5)  # since 2015 (hardware facts)
UPSTREAM_THRESHOLD = 20.0
N_SENSORS, N_FINGER_SENSORS = 38, 27
RAW_MAX = 1023.0  # a disabled sensor's threshold, as calibrate tactile does it


def _read_yaml(path: Path) -> dict[str, Any]:
    # deferred: YAML only for upstream calibration files
    import yaml

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: cannot read ({e})") from None
    except yaml.YAMLError as e:
        raise DataError(f"{path}: not valid YAML ({e})") from None
    if not isinstance(data, dict):
        raise DataError(f"{path}: expected a YAML mapping of reflex-ros-pkg calibration values")
    return data


def _numbers(path: Path, key: str, value: Any, n: int) -> list[float]:
    ok = isinstance(value, list) and len(value) == n
    nums = (
        [float(v) for v in value] if ok and all(isinstance(v, int | float) for v in value) else []
    )
    if not nums or not all(np.isfinite(nums)):
        raise DataError(f"{path}: {key} must be {n} numbers, got {value!r}")
    return nums


def _method(path: Path, what: str) -> dict[str, Any]:
    return {"procedure": "import", "source": str(path), "format": what}


def _measured(path: Path) -> str:
    """When the file was written: the best guess of when it was measured (staleness)."""

    return dt.datetime.fromtimestamp(path.stat().st_mtime, dt.UTC).isoformat(timespec="seconds")


def import_file(path: Path, device: str) -> CalibrationRecord:
    """The calibration record in one reflex-ros-pkg file (DataError naming what is wrong)."""
    data = _read_yaml(path)
    if all(k in data for k in SF_KEYS):
        zero = []
        for k in SF_KEYS:
            entry = data[k]
            z = entry.get("zero_point") if isinstance(entry, dict) else None
            if not isinstance(z, int | float) or not 0 < float(z) < 2 * np.pi * 7:
                raise DataError(f"{path}: {k}.zero_point must be a servo position, got {z!r}")
            zero.append(round(float(z), 6))
        return CalibrationRecord(
            kind="fingers",
            device=device,
            values={"motor_zero_points": zero},
            method=_method(path, "reflex_sf_motor_zero_points.yaml (motor radians)"),
            measured_at=_measured(path),
        )
    if "motor_zero_reference" in data:
        motor = _numbers(path, "motor_zero_reference", data["motor_zero_reference"], 4)
        enc = _numbers(path, "encoder_zero_reference", data.get("encoder_zero_reference"), 3)
        return CalibrationRecord(
            kind="fingers",
            device=device,
            values={
                "motor_zero_points": [
                    round(z * g, 6) for z, g in zip(motor, TAKKTILE_GEAR, strict=True)
                ],
                "motor_zero_rad": [round(z, 6) for z in motor],
                "encoder_zero_rad": [round(z, 6) for z in enc],
            },
            method=_method(path, "finger_calibrate.yaml (joint-side motor zeros, gears 1.42/1.5)"),
            measured_at=_measured(path),
        )
    if any(k.startswith("tactile_offset_f") for k in data):
        zero = np.zeros(N_SENSORS)
        for f in range(3):
            key = f"tactile_offset_f{f + 1}"
            zero[9 * f : 9 * f + 9] = _numbers(path, key, data.get(key), 9)
        threshold = np.full(N_SENSORS, UPSTREAM_THRESHOLD)
        palm = list(range(N_FINGER_SENSORS, N_SENSORS))
        threshold[palm] = RAW_MAX
        return CalibrationRecord(
            kind="tactile",
            device=device,
            values={
                "zero": zero.tolist(),
                "threshold": threshold.tolist(),
                "flags": {"dead": [], "saturated": [], "drifting": [], "not_imported": palm},
            },
            method=_method(
                path,
                "tactile_calibrate.yaml (one unloaded packet per finger sensor; no palm; "
                f"threshold {UPSTREAM_THRESHOLD:g} as upstream)",
            ),
            measured_at=_measured(path),
        )
    raise DataError(
        f"{path}: not a reflex-ros-pkg calibration file this knows (reflex_sf_motor_zero_points"
        ".yaml, finger_calibrate.yaml, tactile_calibrate.yaml); its keys: "
        f"{', '.join(sorted(map(str, data))[:8])}"
    )
