"""Devices that come and go: a `DeviceLink` connects one device in the background and keeps it
connected.

The daemon starts without its devices. Each link tries `connect()` every `retry_s` until it
succeeds (a robot PC may boot before Baxter, a hand may be powered later), probes the device
every `check_s` while connected, and when a probe has failed for `lost_after_s` (or a command
fails with a lost device) disconnects it and starts over. Its state, connected, waiting
(never connected yet) or lost, with why and since when, goes to its listeners: the device
node declares its liveliness token only while connected and publishes the state on
``health/<node>`` for `status`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from activetouch.clock import SYSTEM_CLOCK, Clock
from activetouch.errors import ConfigError, DeviceFaultError, NodeUnavailableError
from activetouch.transport.messages import DeviceHealth

log = logging.getLogger(__name__)

CONNECTED, WAITING, LOST = "connected", "waiting", "lost"
MAX_DETAIL = 900  # DeviceHealth.detail holds at most 1000 characters


@dataclass(frozen=True)
class LinkSettings:
    retry_s: float = 2.0  # between connection attempts
    check_s: float = 0.5  # between probes while connected
    lost_after_s: float = 1.0  # a probe failing this long: the device is lost

    def check(self) -> None:
        for name in ("retry_s", "check_s", "lost_after_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"service.device_{name} must be > 0, got {getattr(self, name)}")


def is_loss(exc: BaseException) -> bool:
    """An error that says the device went away (a stream, a port, a bridge), or stopped itself
    (an implausible reading): the link reconnects rather than serving on."""
    return isinstance(exc, NodeUnavailableError | OSError | DeviceFaultError)


def _why(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}"
    return text if len(text) <= MAX_DETAIL else text[: MAX_DETAIL - 1] + "…"


def hand_probe(hand: Any) -> str | None:
    """None while the hand streams; else why not."""
    st = hand.state()
    return "its state stream stopped (stale readings)" if getattr(st, "stale", False) else None


def arm_probe(arm: Any) -> str | None:
    try:
        arm.joint_state()
    except (NodeUnavailableError, OSError) as e:
        return _why(e)
    return None


class DeviceLink:
    """One device's connection, kept up by a background thread (see the module doc)."""

    def __init__(
        self,
        node: str,
        device_type: str,
        device: Any,
        probe: Callable[[Any], str | None],
        lock: threading.Lock,
        settings: LinkSettings | None = None,
        *,
        clock: Clock = SYSTEM_CLOCK,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.node, self.device_type, self.device = node, device_type, device
        self.settings = settings or LinkSettings()
        self.settings.check()
        self._probe, self._lock, self._clock, self._wall = probe, lock, clock, wall
        self._mu = threading.Lock()
        self._state, self._detail, self._since, self._attempts = (
            WAITING,
            "not connected yet",
            wall(),
            0,
        )
        self._listeners: list[Callable[[DeviceHealth], None]] = []
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._bad_since: float | None = None
        self._thread = threading.Thread(
            target=self._loop, name=f"activetouch-{node}-link", daemon=True
        )

    # -- what others see
    @property
    def connected(self) -> bool:
        return self._state == CONNECTED

    def health(self) -> DeviceHealth:
        with self._mu:
            return DeviceHealth(
                node=self.node,
                device=self.device_type,
                state=self._state,  # type: ignore[arg-type]
                detail=self._detail,
                since=self._since,
                attempts=self._attempts,
            )

    def describe(self) -> str:
        h = self.health()
        age = max(0.0, self._wall() - h.since)
        what = {WAITING: "not connected yet", LOST: "lost"}.get(h.state, h.state)
        text = f"the {self.node} ({self.device_type}) is {what} (for {age:.0f} s)"
        if h.state != CONNECTED and h.detail:
            text += f": {h.detail}"
        return text

    def require(self) -> None:
        """NodeUnavailableError with the reason unless the device is connected."""
        if not self.connected:
            raise NodeUnavailableError(self.describe())

    def add_listener(self, fn: Callable[[DeviceHealth], None]) -> None:
        self._listeners.append(fn)

    def report(self, exc: BaseException) -> None:
        """A command failed: if the device went away, drop it now and reconnect."""
        if self.connected and is_loss(exc):
            self._lose(_why(exc))

    # -- lifecycle
    def start(self) -> None:
        self._thread.start()

    def close(self, join_timeout: float = 2.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(join_timeout)

    # -- the thread
    def _set(self, state: str, detail: str) -> None:
        with self._mu:
            changed = state != self._state
            if changed:
                self._since = self._wall()
                self._attempts = 0
            self._state, self._detail = state, detail
            if state != CONNECTED:
                self._attempts += 1
        if changed:
            level = logging.INFO if state == CONNECTED else logging.WARNING
            log.log(
                level,
                "%s %s",
                self.node,
                state,
                extra={"node": self.node, "device": self.device_type, "detail": detail},
            )
        self._notify()

    def _notify(self) -> None:
        h = self.health()
        for fn in list(self._listeners):
            try:
                fn(h)
            except Exception:
                log.debug("%s link: a listener failed", self.node, exc_info=True)

    def _lose(self, reason: str) -> None:
        self._set(LOST, reason)
        # A command may still hold the lock on a dead device: it fails on its own; do not
        # wait for it longer than a retry.
        got = self._lock.acquire(timeout=self.settings.retry_s)
        try:
            self.device.disconnect()
        except Exception:
            log.debug("%s link: disconnect of a lost device failed", self.node, exc_info=True)
        finally:
            if got:
                self._lock.release()
        self._bad_since = None

    def _try_connect(self) -> None:
        # Without the devices' lock: a connection may take seconds (Baxter waits for its first
        # joint state) and the other device's commands must not wait for it; this device's
        # commands are refused until it is connected, so none runs beside the connect.
        try:
            self.device.connect()
        except Exception as e:
            state = WAITING if self._state == WAITING else LOST
            self._set(state, _why(e))
            try:  # a half-open device (a port opened, no stream) starts the next try clean
                self.device.disconnect()
            except Exception:
                log.debug("%s link: disconnect after a failed connect", self.node, exc_info=True)
            return
        if self._stop.is_set():  # closed while connecting: leave nothing connected behind
            try:
                self.device.disconnect()
            except Exception:
                log.debug("%s link: disconnect at close", self.node, exc_info=True)
            return
        self._bad_since = None
        self._set(CONNECTED, "")

    def _check(self) -> None:
        # A running command holds the lock and reports a loss itself: skip the probe then.
        if not self._lock.acquire(blocking=False):
            return
        try:
            reason = self._probe(self.device)
        except Exception as e:
            reason = _why(e)
        finally:
            self._lock.release()
        now = self._clock.monotonic()
        if reason is None:
            self._bad_since = None
        elif self._bad_since is None:
            self._bad_since = now
        elif now - self._bad_since >= self.settings.lost_after_s:
            self._lose(reason)

    def _loop(self) -> None:
        while not self._stop.is_set():
            if self.connected:
                self._check()
                period = self.settings.check_s
            else:
                self._try_connect()
                period = 0.0 if self.connected else self.settings.retry_s
            if period:
                self._wake.wait(period)
                self._wake.clear()
