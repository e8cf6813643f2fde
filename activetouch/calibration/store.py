"""The calibration store: one human-readable JSON file per procedure and device.

Layout: ``<data>/calibration/<device>/<kind>.json`` where `kind` is one of `KINDS` and
`device` the hand's serial or configured name (for the mount: the arm's and the hand's names;
for the object: the workcell's). A file holds one `CalibrationRecord`: the schema version,
what was measured (``values``), when and how (``measured_at``, ``method``) and how well
(``quality``). Files are written atomically (`activetouch.storage`: temporary file in the same
directory, fsync, ``os.replace``) and never with pickle; reading checks the schema and the kind.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from activetouch.errors import DataError
from activetouch.storage import atomic_write_text

SCHEMA = "activetouch.calibration"
SCHEMA_VERSION = 1
KINDS = ("tactile", "fingers", "mount", "object")
# After this long a record still loads, but with a warning naming the command that renews it.
DEFAULT_MAX_AGE_DAYS = {"tactile": 1.0, "fingers": 30.0, "mount": 90.0, "object": 1.0}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


@dataclass
class CalibrationRecord:
    """One calibration result. ``values`` holds plain JSON numbers and lists only."""

    kind: str
    device: str
    values: dict[str, Any]
    quality: dict[str, Any] = field(default_factory=dict)
    method: dict[str, Any] = field(default_factory=dict)
    measured_at: str = ""  # ISO 8601, UTC
    schema: str = SCHEMA
    version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        check_kind(self.kind)
        check_device(self.device)
        if not self.measured_at:
            self.measured_at = now_iso()

    def age_days(self, now: _dt.datetime | None = None) -> float:
        t = _dt.datetime.fromisoformat(self.measured_at)
        now = now or _dt.datetime.now(_dt.UTC)
        return (now - t).total_seconds() / 86400.0

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=False, allow_nan=False) + "\n"

    @classmethod
    def from_json(cls, text: str, where: str = "calibration") -> CalibrationRecord:
        try:
            raw = json.loads(text)
        except json.JSONDecodeError as e:
            raise DataError(f"{where}: not JSON ({e})") from None
        if not isinstance(raw, dict) or raw.get("schema") != SCHEMA:
            raise DataError(f"{where}: not an activetouch calibration file")
        if raw.get("version") != SCHEMA_VERSION:
            raise DataError(
                f"{where}: calibration schema version {raw.get('version')!r}, this build reads "
                f"{SCHEMA_VERSION} (measure again)"
            )
        try:
            rec = cls(
                kind=str(raw["kind"]),
                device=str(raw["device"]),
                values=dict(raw["values"]),
                quality=dict(raw.get("quality", {})),
                method=dict(raw.get("method", {})),
                measured_at=str(raw["measured_at"]),
            )
            _dt.datetime.fromisoformat(rec.measured_at)
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(f"{where}: malformed calibration record ({e})") from None
        return rec


def now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise DataError(f"unknown calibration kind {kind!r} (known: {', '.join(KINDS)})")


def check_device(device: str) -> None:
    if not _NAME.match(device or ""):
        raise DataError(f"calibration device name {device!r}: letters, digits, '.', '_', '-' only")


def calibration_dir(root: Path) -> Path:
    return Path(root) / "calibration"


def record_path(root: Path, kind: str, device: str) -> Path:
    check_kind(kind)
    check_device(device)
    return calibration_dir(root) / device / f"{kind}.json"


def save(root: Path, record: CalibrationRecord) -> Path:
    path = record_path(root, record.kind, record.device)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, record.to_json())
    return path


def load(root: Path, kind: str, device: str) -> CalibrationRecord | None:
    """The stored record, or None if there is none; DataError if the file is unreadable."""
    path = record_path(root, kind, device)
    if not path.exists():
        return None
    rec = CalibrationRecord.from_json(path.read_text(encoding="utf-8"), str(path))
    if rec.kind != kind or rec.device != device:
        raise DataError(f"{path}: holds {rec.kind!r} of {rec.device!r}, not {kind!r}/{device!r}")
    return rec


def list_records(root: Path) -> list[tuple[Path, CalibrationRecord | DataError]]:
    """Every calibration file under `root` with its record (or why it does not load)."""
    out: list[tuple[Path, CalibrationRecord | DataError]] = []
    base = calibration_dir(root)
    if not base.is_dir():
        return out
    for path in sorted(base.glob("*/*.json")):
        try:
            out.append((path, CalibrationRecord.from_json(path.read_text("utf-8"), str(path))))
        except DataError as e:
            out.append((path, e))
    return out


def staleness(
    record: CalibrationRecord | None, kind: str, max_age_days: float | None = None
) -> str | None:
    """Why a calibration should be renewed (missing or old), with the command; None if fine."""
    cmd = f"`activetouch calibrate {kind}`"
    if record is None:
        return f"no {kind} calibration: run {cmd}"
    limit = DEFAULT_MAX_AGE_DAYS[kind] if max_age_days is None else max_age_days
    age = record.age_days()
    if age > limit:
        return (
            f"{kind} calibration of {record.device} is {age:.1f} days old (> {limit:g}): run {cmd}"
        )
    return None


def device_name(cfg: Any, explicit: str | None) -> str:
    """The name a hand's calibration is stored under: `explicit`, else the hand's serial or
    name setting, else its type."""
    if explicit:
        return explicit
    hand = cfg.hand
    for attr in ("serial", "name"):
        v = getattr(hand, attr, "")
        if v:
            return str(v)
    return str(hand.type or "hand")
