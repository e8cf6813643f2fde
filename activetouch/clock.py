"""Time as devices and nodes see it, injectable: the system's monotonic clock in service, a
manual clock in tests, so that timing is asserted in the device's own time and not by
wall-clock windows that a loaded machine breaks."""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable
from typing import Protocol


class Clock(Protocol):
    def monotonic(self) -> float:
        """Seconds on a clock that never goes back."""
        ...

    def wait(self, event: threading.Event, timeout: float) -> bool:
        """Wait up to `timeout` s for `event`; whether it is set."""
        ...


class SystemClock:
    def monotonic(self) -> float:
        return time.monotonic()

    def wait(self, event: threading.Event, timeout: float) -> bool:
        return event.wait(timeout)


SYSTEM_CLOCK = SystemClock()


class ManualClock:
    """A clock that moves only when code waits on it: a wait of `timeout` s returns at once,
    the clock `timeout` s later, after running the callbacks that fell due on the way (in
    their time order), so 'stop at 0.3 s' happens at 0.3 s of the device's time on any machine.
    For one thread of waits (the device under test) plus callbacks; not a scheduler."""

    def __init__(self, start: float = 0.0) -> None:
        self.now = float(start)
        self._due: list[tuple[float, int, Callable[[], None]]] = []
        self._n = itertools.count()
        self._lock = threading.Lock()

    def monotonic(self) -> float:
        return self.now

    def call_at(self, t: float, fn: Callable[[], None]) -> None:
        """Run `fn` once the clock reaches `t`."""
        with self._lock:
            heapq.heappush(self._due, (float(t), next(self._n), fn))

    def advance(self, dt: float) -> None:
        self._run_until(self.now + max(0.0, float(dt)), None)

    def wait(self, event: threading.Event, timeout: float) -> bool:
        if event.is_set():
            return True
        self._run_until(self.now + max(0.0, float(timeout)), event)
        return event.is_set()

    def _run_until(self, end: float, event: threading.Event | None) -> None:
        while True:
            with self._lock:
                if not self._due or self._due[0][0] > end:
                    break
                t, _, fn = heapq.heappop(self._due)
            self.now = max(self.now, t)
            fn()
            if event is not None and event.is_set():
                return  # woken at `t`: the rest of the timeout does not pass
        self.now = max(self.now, end)
