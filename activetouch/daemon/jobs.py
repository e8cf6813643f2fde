"""The recognition service's jobs: an admitted request, the one that runs, and the planner's
time budget (a plan that runs past it returns the best path found so far)."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from activetouch.daemon.interlock import Interlock
from activetouch.planning.policies import Plan, PlanningState, Policy
from activetouch.transport.messages import (
    RecognizeRequest,
)

log = logging.getLogger("activetouch.daemon")


EXPIRY_SWEEP_S = 0.5  # how often the control thread drops queued requests past their timeout


class TimedPolicy(Policy):
    """A policy that keeps the planning time since it was last asked (per-move figures), ends
    a plan that runs past `budget_s` with the best path it has, and can be interrupted for
    good (cancel, e-stop, shutdown) from another thread."""

    def __init__(self, inner: Policy, budget_s: float | None = None) -> None:
        self.inner = inner
        self.name = inner.name
        self.budget_s = budget_s
        self._pending = 0.0
        self._ended = False  # interrupted for good: no plan runs any more
        self._lock = threading.Lock()

    def plan(self, state: PlanningState, rng: np.random.Generator) -> Plan:
        t = time.perf_counter()
        timer = None
        if self.budget_s:
            timer = threading.Timer(self.budget_s, self._over_budget)
            timer.daemon = True
            timer.start()
        try:
            return self.inner.plan(state, rng)
        finally:
            if timer is not None:
                timer.cancel()
            with self._lock:
                if not self._ended:
                    self.inner.clear_interrupt()  # the budget applies to one plan
            self._pending += time.perf_counter() - t

    def _over_budget(self) -> None:
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
