"""The recognition service's jobs: an admitted request, the one that runs, and the planner's
time budget (a plan that runs past it returns the best path found so far)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import zenoh

from activetouch.daemon.interlock import Interlock
from activetouch.planning.policies import Plan, PlanningState, Policy
from activetouch.transport.messages import (
    RecognizeRequest,
)

log = logging.getLogger("activetouch.daemon")


EXPIRY_SWEEP_S = 0.5  # how often the control thread drops queued requests past their timeout


class BudgetTimer(Protocol):
    def start(self) -> None: ...
    def cancel(self) -> None: ...


def daemon_timer(interval: float, fn: Callable[[], None]) -> BudgetTimer:
    """A `threading.Timer` on a daemon thread (a plan's budget must not keep the process up)."""
    timer = threading.Timer(interval, fn)
    timer.daemon = True
    return timer


class TimedPolicy(Policy):
    """A policy that keeps the planning time since it was last asked (per-move figures), ends
    a plan that runs past `budget_s` with the best path it has, and can be interrupted for
    good (cancel, e-stop, shutdown) from another thread.

    `timer(interval, fn)` starts the budget's countdown and `clock` measures the planning time;
    tests inject both (the budget expires when they say, not when a loaded machine gets to it)."""

    def __init__(
        self,
        inner: Policy,
        budget_s: float | None = None,
        *,
        timer: Callable[[float, Callable[[], None]], BudgetTimer] = daemon_timer,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.inner = inner
        self.name = inner.name
        self.budget_s = budget_s
        self._timer, self._clock = timer, clock
        self._pending = 0.0
        self._ended = False  # interrupted for good: no plan runs any more
        self._lock = threading.Lock()
        self._plans = 0  # plans started; the running one's number while it runs, else None
        self._running: int | None = None

    def plan(self, state: PlanningState, rng: np.random.Generator) -> Plan:
        t = self._clock()
        with self._lock:
            self._plans += 1
            self._running = mine = self._plans
        timer = None
        if self.budget_s:
            timer = self._timer(self.budget_s, lambda: self._over_budget(mine))
            timer.start()
        try:
            return self.inner.plan(state, rng)
        finally:
            if timer is not None:
                timer.cancel()  # does not stop a callback already under way: see _over_budget
            with self._lock:
                self._running = None
                if not self._ended:
                    self.inner.clear_interrupt()  # the budget applies to one plan
            self._pending += self._clock() - t

    def _over_budget(self, plan: int) -> None:
        with self._lock:
            if self._running != plan:
                return  # that plan ended as its budget ran out: the next one keeps its own
            log.info("plan over its time budget: taking its best path so far")
            self.inner.interrupt()

    def interrupt(self) -> None:
        with self._lock:
            self._ended = True
            self.inner.interrupt()

    def take(self) -> float:
        v, self._pending = self._pending, 0.0
        return v


@dataclass
class Job:
    query: zenoh.Query
    request: RecognizeRequest
    session_id: str
    seed: int
    arrived: float  # monotonic
    budget: float | None  # the caller's timeout, from the selector


@dataclass
class Running:
    job: Job
    cancel: threading.Event
    interlock: Interlock
    started: float  # wall clock
    move: int = 0
    policy: Policy | None = None  # interrupted by cancel / e-stop / shutdown
    place_s: float = 0.0  # for the log
    session_s: float = 0.0
