"""Loading stored calibrations into a live hand: the one call a driver's connect needs."""

from __future__ import annotations

import logging
from pathlib import Path

from activetouch import paths
from activetouch.calibration import store
from activetouch.calibration.fingers import apply_fingers
from activetouch.calibration.tactile import apply_tactile
from activetouch.interfaces import Hand

log = logging.getLogger(__name__)


def load_into(
    hand: Hand,
    device: str,
    data: Path | str | None,
    kinds: tuple[str, ...] = ("tactile", "fingers"),
) -> dict[str, Path | None]:
    """Apply the stored `kinds` of `device` to `hand`; log which file each came from, and a
    warning naming the command when one is missing or stale. Returns kind -> file used."""

    root = paths.data_dir(data)
    used: dict[str, Path | None] = {}
    for kind in kinds:
        rec = store.load(root, kind, device)
        why = store.staleness(rec, kind)
        if why:
            log.warning("calibration: %s", why)
        if rec is None:
            used[kind] = None
            continue
        path = store.record_path(root, kind, device)
        if kind == "tactile":
            ok = apply_tactile(
                hand, rec.values["zero"], rec.values["threshold"], rec.values.get("flags")
            )
        elif kind == "fingers":
            ok = apply_fingers(hand, rec.values["motor_zero_rad"], rec.values["encoder_zero_rad"])
        else:
            ok = False
        used[kind] = path if ok else None
        if ok:
            log.info("calibration: %s from %s (measured %s)", kind, path, rec.measured_at)
    return used
