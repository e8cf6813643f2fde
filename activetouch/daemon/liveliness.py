"""Which nodes are alive: their liveliness tokens ``activetouch/<robot>/alive/<node>``."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from activetouch.daemon.serving import direct
from activetouch.errors import (
    NodeUnavailableError,
)
from activetouch.transport.keys import Keys
from activetouch.transport.messages import DeviceHealth, decode
from activetouch.transport.zenoh_session import undeclare_quietly

log = logging.getLogger(__name__)

LIVELINESS_CHECK_S = 1.0  # how long to ask for a key's tokens after one of them dropped


class Coalesced:
    """Runs `fn` on its own thread when requested; requests arriving while it runs make it run
    once more, not once each (a flood of dropped tokens costs one check at a time)."""

    def __init__(self, fn: Callable[[], None], name: str) -> None:
        self._fn, self._name = fn, name
        self._lock = threading.Lock()
        self._running = False
        self._again = False

    def request(self) -> None:
        with self._lock:
            if self._running:
                self._again = True
                return
            self._running = True
        threading.Thread(target=self._loop, name=self._name, daemon=True).start()

    def _loop(self) -> None:
        while True:
            try:
                self._fn()
            except Exception:
                log.debug("%s failed", self._name, exc_info=True)
            with self._lock:
                if not self._again:
                    self._running = False
                    return
                self._again = False


def tokens_left(session: zenoh.Session, key: str, timeout: float = LIVELINESS_CHECK_S) -> bool:
    """True if some session still holds a liveliness token on `key` (True also when the
    question cannot be asked: a node is never declared gone on a failed check alone)."""
    try:
        replies = session.liveliness().get(key, timeout=timeout)
        return any(r.ok is not None for r in replies)
    except Exception:
        log.debug("liveliness check of %s failed", key, exc_info=True)
        return True


class AliveNodes:
    """Which nodes of a robot are alive, from their liveliness tokens (for status reports)."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.keys = Keys(robot)
        self._cv = threading.Condition()
        self._state: dict[str, bool] = {}
        self._changed: dict[str, float] = {}
        self._session = session
        self._checks: dict[str, Coalesced] = {}
        self._sub: Any = session.liveliness().declare_subscriber(
            self.keys.alive_all, direct(self._on_sample), history=True
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        node = Keys.node_of_alive_key(str(sample.key_expr))
        if sample.kind == zenoh.SampleKind.PUT:
            self._set(node, True)
            return
        with self._cv:  # confirm off the callback, as `RemoteNode` does
            check = self._checks.get(node)
            if check is None:
                check = self._checks[node] = Coalesced(
                    lambda: self._confirm(node), f"activetouch-alive-{node}"
                )
        check.request()

    def _confirm(self, node: str) -> None:
        if not tokens_left(self._session, self.keys.alive(node)):
            self._set(node, False)

    def _set(self, node: str, alive: bool) -> None:
        with self._cv:
            if self._state.get(node) != alive:
                self._changed[node] = time.monotonic()
            self._state[node] = alive
            self._cv.notify_all()

    def snapshot(self) -> dict[str, bool]:
        """{node: alive} for every node seen so far (a dropped node stays, as False)."""
        with self._cv:
            return dict(self._state)

    def since(self, node: str) -> float | None:
        """Seconds since `node`'s token last appeared or dropped, or None if never seen."""
        t = self._changed.get(node)
        return None if t is None else time.monotonic() - t

    def wait_for(self, node: str, timeout: float, alive: bool = True) -> None:
        """Wait until `node` is alive (or, with alive=False, gone); NodeUnavailableError."""
        with self._cv:
            ok = self._cv.wait_for(lambda: self._state.get(node, False) == alive, timeout=timeout)
        if not ok:
            state = "appear" if alive else "drop"
            raise NodeUnavailableError(
                f"the {node} node's liveliness token {self.keys.alive(node)} did not {state} "
                f"within {timeout:g} s"
            )

    def close(self) -> None:
        sub, self._sub = self._sub, None
        if sub is not None:
            undeclare_quietly(sub)


class DeviceHealthWatch:
    """The device nodes' last `DeviceHealth` (``health/<node>``): why a device is waiting or
    lost, for `status` and for refusing a recognition at once. Asked once at start (a node
    that published before this daemon existed) and then followed."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:

        self.keys = Keys(robot)
        self._decode = lambda b: decode(b, DeviceHealth)
        self._mu = threading.Lock()
        self._last: dict[str, Any] = {}
        self._session = session
        self._sub: Any = session.declare_subscriber(self.keys.health_all, direct(self._on_sample))
        threading.Thread(target=self._ask, name="activetouch-health-get", daemon=True).start()

    def _store(self, payload: bytes) -> None:
        try:
            h = self._decode(payload)
        except Exception:
            log.debug("dropping a malformed health sample", exc_info=True)
            return
        with self._mu:
            self._last[h.node] = h

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self._store(bytes(sample.payload.to_bytes()))

    def _ask(self) -> None:
        try:
            for r in self._session.get(self.keys.health_all, timeout=LIVELINESS_CHECK_S):
                if r.ok is not None:
                    self._store(bytes(r.ok.payload.to_bytes()))
        except Exception:
            log.debug("asking the device nodes' health failed", exc_info=True)

    def get(self, node: str) -> Any:
        """The node's last `DeviceHealth`, or None if it never said."""
        with self._mu:
            return self._last.get(node)

    def close(self) -> None:
        sub, self._sub = self._sub, None
        if sub is not None:
            undeclare_quietly(sub)
