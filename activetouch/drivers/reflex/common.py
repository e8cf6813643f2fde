"""Pieces both ReFlex drivers share: the guarded-close step rule, the extended hand state,
stream-loss errors and rate-limited warnings."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from activetouch.errors import DeviceFaultError, NodeUnavailableError
from activetouch.interfaces import HandState

STOP_CONTACT = "contact"
STOP_LIMIT = "limit"
STOP_OVERLOAD = "overload"
STOP_STALL = "stall"


class StreamLostError(NodeUnavailableError):
    """The hand stopped answering: no state packet (or servo reply) within the timeout."""


class ServoFaultError(DeviceFaultError):
    """A servo reading that cannot be true (unanswered, outside its window or travel, an alarm
    or over-temperature): the hand stopped; the message names the servo and what to check."""


@dataclass(frozen=True)
class ReflexHandState(HandState):
    """`HandState` plus what the ReFlex drivers know besides: whether the stream is stale,
    the distal estimate, spool angles and loads, and a wall-clock stamp (``stamp`` stays the
    producer's monotonic clock; ``wall_stamp`` is time.time() at the same instant, so readers
    on other machines can place it)."""

    stale: bool = False
    distal: np.ndarray = field(default_factory=lambda: np.zeros(3))
    motor: np.ndarray = field(default_factory=lambda: np.zeros(4))  # spool angles + preshape
    load: np.ndarray = field(default_factory=lambda: np.zeros(4))  # signed raw load units
    wall_stamp: float = 0.0
    systime_us: int = 0  # the board's clock (TakkTile), 0 for the SF


@dataclass(frozen=True)
class CloseStep:
    """What one control step of a guarded close decides for the fingers."""

    target: np.ndarray  # (3,) spool targets, rad
    active: np.ndarray  # (3,) bool, still closing
    reasons: tuple[str, ...]  # "" while active, else why the finger stopped


def close_step(
    motor: np.ndarray,
    target: np.ndarray,
    active: np.ndarray,
    reasons: tuple[str, ...],
    touching: np.ndarray,
    overloaded: np.ndarray,
    stalled: np.ndarray,
    step: float,
    limit: float,
    backoff: float,
) -> CloseStep:
    """One step of the guarded close for every still-active finger, each on its own (the
    ReFlex guarded_move): contact -> hold where it is; overload -> back off `backoff` and stop;
    at the travel limit or stalled -> hold; otherwise command measured spool + `step`."""
    target = np.array(target, dtype=np.float64)
    active = np.array(active, dtype=bool)
    out = list(reasons)
    for f in np.flatnonzero(active).tolist():
        m = float(motor[f])
        if touching[f]:
            target[f], active[f], out[f] = m, False, STOP_CONTACT
        elif overloaded[f]:
            target[f], active[f], out[f] = max(0.0, m - backoff), False, STOP_OVERLOAD
        elif m >= limit - 1e-9:
            target[f], active[f], out[f] = min(m, limit), False, STOP_LIMIT
        elif stalled[f]:
            target[f], active[f], out[f] = m, False, STOP_STALL
        else:
            target[f] = min(m + step, limit)
    return CloseStep(target, active, tuple(out))


class StallDetector:
    """A finger is stalled when its spool moved less than `tolerance` over the last `window`
    steps while being commanded to close."""

    def __init__(self, window: int, tolerance: float, n: int = 3) -> None:
        self.window, self.tolerance = max(1, int(window)), float(tolerance)
        self.history: list[np.ndarray] = []
        self.n = n

    def __call__(self, motor: np.ndarray) -> np.ndarray:
        self.history.append(np.asarray(motor, dtype=np.float64)[: self.n].copy())
        if len(self.history) > self.window + 1:
            self.history.pop(0)
        if len(self.history) <= self.window:
            return np.zeros(self.n, dtype=bool)
        h = np.stack(self.history)
        return (h[-1] - h[0]) < self.tolerance


class RateLimitedWarning:
    """Counts events by reason; logs at most one warning per reason per `interval` seconds,
    saying how many were not logged."""

    def __init__(self, logger: logging.Logger, interval: float = 5.0) -> None:
        self.logger, self.interval = logger, float(interval)
        self.counts: dict[str, int] = {}
        self._last: dict[str, float] = {}
        self._unlogged: dict[str, int] = {}

    def __call__(self, reason: str, message: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        now = time.monotonic()
        if now - self._last.get(reason, -1e18) >= self.interval:
            extra = self._unlogged.pop(reason, 0)
            more = f" ({extra} more since the last warning)" if extra else ""
            self.logger.warning("%s%s", message, more)
            self._last[reason] = now
        else:
            self._unlogged[reason] = self._unlogged.get(reason, 0) + 1


def parse_address(text: str, what: str) -> tuple[str, int]:
    """'host:port' -> (host, port); ValueError naming `what`."""
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise ValueError(f"{what}: expected address:port, got {text!r}")
    try:
        p = int(port)
    except ValueError:
        raise ValueError(f"{what}: port {port!r} is not a number") from None
    if not 0 <= p <= 65535:
        raise ValueError(f"{what}: port {p} out of range")
    return host.strip("[]"), p
