"""Structured logs of the daemon on stderr (the journal picks them up): logfmt or JSON lines.

Field values come from requests too, so they are bounded and control characters escaped: a
client must not be able to grow the log without limit or forge lines."""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any

from activetouch.errors import ConfigError

MAX_VALUE_CHARS = 500  # a longer logged value is cut, with its length noted


def _bounded(s: str) -> str:
    if len(s) > MAX_VALUE_CHARS:
        return f"{s[:MAX_VALUE_CHARS]}…({len(s)} chars)"
    return s


_RECORD_FIELDS = set(vars(logging.LogRecord("", 0, "", 0, "", (), None))) | {
    "message",
    "asctime",
    "taskName",
}


def _record_items(record: logging.LogRecord, fmt: logging.Formatter) -> dict[str, Any]:
    items: dict[str, Any] = {
        "ts": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        + f".{int(record.msecs):03d}Z",
        "level": record.levelname.lower(),
        "logger": record.name,
        "msg": record.getMessage(),
    }
    items["msg"] = _bounded(items["msg"])
    items.update({k: v for k, v in vars(record).items() if k not in _RECORD_FIELDS})
    if record.exc_info:
        items["exc"] = fmt.formatException(record.exc_info)
    return items


def _logfmt_value(v: Any) -> str:
    s = _bounded(v if isinstance(v, str) else json.dumps(v, default=str))
    # Quote (JSON-escaping every control character) anything that could break the line.
    if s == "" or any(c in ' ="\\' or ord(c) < 0x20 or ord(c) == 0x7F for c in s):
        return json.dumps(s)
    return s


class LogfmtFormatter(logging.Formatter):
    """``ts=... level=info logger=... msg="..." key=value`` (the `extra` fields of the call)."""

    def format(self, record: logging.LogRecord) -> str:
        items = _record_items(record, self)
        return " ".join(
            f"{k}={json.dumps(v) if k == 'exc' else _logfmt_value(v)}" for k, v in items.items()
        )


class JsonFormatter(logging.Formatter):
    """One JSON object per line."""

    def format(self, record: logging.LogRecord) -> str:
        items = {
            k: _bounded(v) if isinstance(v, str) and k != "exc" else v
            for k, v in _record_items(record, self).items()
        }
        return json.dumps(items, default=str)


def setup_logging(fmt: str = "logfmt", level: str = "info") -> None:
    """Structured logs on stderr (the journal picks them up under systemd)."""
    if fmt not in ("logfmt", "json"):
        raise ConfigError(f"log format {fmt!r} is invalid: use logfmt or json")
    lvl = logging.getLevelName(level.upper())
    if not isinstance(lvl, int):
        raise ConfigError(f"log level {level!r} is invalid: use debug, info, warning or error")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(LogfmtFormatter() if fmt == "logfmt" else JsonFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(lvl)
