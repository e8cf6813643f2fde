"""The recordings under ``<data>/recordings/``: names, listing, and the size and age limits.

A recording is ``<UTC time>-<session id>.mcap`` (e.g. ``20261202T161500Z-demo-7.mcap``); its
id is the name without ``.mcap``. `prune` deletes the oldest recordings (by the time in their
name, then the file's modification time) until the directory holds at most
``recording.max_total_mb`` and none is older than ``recording.max_age_days`` (0: no limit).
"""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass
from pathlib import Path

from activetouch import paths
from activetouch.config import RecordingConfig
from activetouch.errors import DataError

log = logging.getLogger(__name__)

SUFFIX = ".mcap"
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def recording_name(session_id: str, started: float | None = None) -> str:
    """The file name for a recognition started at `started` (Unix seconds, default now)."""
    stamp = time.strftime(
        "%Y%m%dT%H%M%SZ", time.gmtime(time.time() if started is None else started)
    )
    sid = _UNSAFE.sub("_", session_id).strip("._")[:64] or "session"
    return f"{stamp}-{sid}{SUFFIX}"


def new_recording_path(root: Path, session_id: str, started: float | None = None) -> Path:
    d = paths.recordings_dir(root)
    path = d / recording_name(session_id, started)
    n = 1
    while path.exists():  # the same session id twice in one second
        n += 1
        path = d / recording_name(f"{session_id}-{n}", started)
    return path


@dataclass(frozen=True)
class StoredRecording:
    id: str
    path: Path
    size: int
    mtime: float


def list_recordings(root: Path) -> list[StoredRecording]:
    """Oldest first."""
    d = paths.recordings_dir(root)
    if not d.is_dir():
        return []
    out = []
    for p in d.glob(f"*{SUFFIX}"):
        try:
            st = p.stat()
        except OSError:
            continue  # deleted meanwhile
        out.append(StoredRecording(p.name[: -len(SUFFIX)], p, st.st_size, st.st_mtime))
    return sorted(out, key=lambda r: (r.id[:16], r.mtime, r.id))


def find_recording(root: Path, ref: str) -> Path:
    """A recording by id, unique id prefix, unique session-id suffix, or path."""
    p = Path(ref)
    if p.suffix == SUFFIX and p.is_file():
        return p
    recs = list_recordings(root)
    for match in (
        [r for r in recs if r.id == ref],
        [r for r in recs if r.id.startswith(ref)],
        [r for r in recs if r.id.endswith(f"-{ref}") or ref in r.id],
    ):
        if len(match) == 1:
            return match[0].path
        if len(match) > 1:
            names = ", ".join(r.id for r in match[:5])
            raise DataError(
                f"recording {ref!r} is ambiguous: {names}{' ...' if len(match) > 5 else ''}"
            )
    where = paths.recordings_dir(root)
    raise DataError(f"no recording {ref!r} in {where} (`activetouch recordings list` shows them)")


def check_recording_config(cfg: RecordingConfig) -> None:
    cfg.check()


def prune(
    root: Path, cfg: RecordingConfig, now: float | None = None, keep: Path | None = None
) -> list[Path]:
    """Delete the oldest recordings beyond the limits; returns what was deleted. `keep` (the
    recording just written) is never deleted."""
    check_recording_config(cfg)
    now = time.time() if now is None else now
    recs = list_recordings(root)
    deleted: list[Path] = []

    def drop(r: StoredRecording) -> None:
        try:
            r.path.unlink()
        except FileNotFoundError:
            pass
        except OSError as e:
            log.warning("cannot delete recording %s: %s", r.path, e)
            return
        deleted.append(r.path)

    left = []
    for r in recs:
        if keep is not None and r.path == keep:
            left.append(r)
        elif cfg.max_age_days > 0 and now - r.mtime > cfg.max_age_days * 86400.0:
            drop(r)
        else:
            left.append(r)
    if cfg.max_total_mb > 0:
        limit = cfg.max_total_mb * 1e6
        total = sum(r.size for r in left)
        for r in list(left):
            if total <= limit:
                break
            if keep is not None and r.path == keep:
                continue
            drop(r)
            total -= r.size
    if deleted:
        log.info("recordings: deleted %d oldest beyond the limits", len(deleted))
    return deleted
