"""Waiting on a condition in tests (never on a wall-clock window): poll until it holds or a
generous deadline passes, checking once more at the deadline."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


def wait_for(cond: Callable[[], object], timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return bool(cond())


def started_catching(
    fn: Callable[[], object], error: type[BaseException]
) -> tuple[threading.Thread, dict[str, BaseException]]:
    """`fn()` started in a thread; an `error` it raises is kept as `result["err"]` for the
    test to check after joining (any other exception fails the thread as usual)."""
    result: dict[str, BaseException] = {}

    def run() -> None:
        try:
            fn()
        except error as e:
            result["err"] = e

    t = threading.Thread(target=run)
    t.start()
    return t, result
