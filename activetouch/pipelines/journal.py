"""A journal of finished runs, so a long evaluation cut short by a crash or Ctrl-C resumes.

Each finished run is appended as one JSON line (``{"key": ..., "record": ...}``), flushed and
synced before the next is counted. Opening the journal again reads back the records whose
line is whole; a line cut by the crash is skipped (that run is made again). Keys are digests
of everything a run's outcome depends on (`evaluation.job_key`), so a record is reused only
for the same job; the caller removes the journal once the full results are written, so a
later evaluation into the same place starts afresh rather than reusing runs made by older
code.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from activetouch.errors import ConfigError


class RunJournal:
    """The finished runs at `path` (created on the first `add`)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._records: dict[str, dict[str, Any]] = {}
        if self.path.exists() and not self.path.is_file():
            raise ConfigError(f"{self.path}: exists and is not a file (the runs' journal)")
        if self.path.is_file():
            for line in self.path.read_text(errors="replace").splitlines():
                entry = _entry(line)
                if entry is not None:
                    self._records[entry[0]] = entry[1]

    def __len__(self) -> int:
        return len(self._records)

    def get(self, key: str) -> dict[str, Any] | None:
        return self._records.get(key)

    def add(self, key: str, record: dict[str, Any]) -> None:
        line = json.dumps({"key": key, "record": record}, allow_nan=True) + "\n"
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())  # counted as done only once it would survive a power cut
        self._records[key] = record

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


def _entry(line: str) -> tuple[str, dict[str, Any]] | None:
    """(key, record) of a whole journal line, None for a cut or foreign one."""
    try:
        doc = json.loads(line)
    except ValueError:
        return None
    if not isinstance(doc, dict):
        return None
    key, record = doc.get("key"), doc.get("record")
    if not isinstance(key, str) or not isinstance(record, dict):
        return None
    return key, record
