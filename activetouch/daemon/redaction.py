"""Local paths in texts sent to clients, replaced by placeholders (the log keeps them): a
client has no business knowing the robot PC's directories."""

from __future__ import annotations

from pathlib import Path

# Longest path first, each with its placeholder; set once by the daemon (issue 16, finding 10).
_REDACT: list[tuple[str, str]] = []


def set_redactions(data: Path | None) -> None:
    """Hide `data` (as "<data>") and the home directory (as "~") in replies."""
    pairs = []
    if data is not None:
        pairs.append((str(Path(data).resolve()), "<data>"))
        pairs.append((str(data), "<data>"))
    home = str(Path.home())
    if home not in ("/", ""):
        pairs.append((home, "~"))
    _REDACT[:] = sorted(set(pairs), key=lambda p: -len(p[0]))  # longest first


def redact(text: str | None) -> str | None:
    if not text:
        return text
    for path, mark in _REDACT:
        text = text.replace(path, mark)
    return text
