"""Waiting on a condition in tests (never on a wall-clock window): poll until it holds or a
generous deadline passes, checking once more at the deadline."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_for(cond: Callable[[], object], timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return bool(cond())
