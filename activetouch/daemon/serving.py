"""The serving base of every queryable node (device nodes, calibration, recognition):
Zenoh callbacks only enqueue a query; one worker thread per node owns what it serves, runs one
command at a time in arrival order, replies, and publishes state between commands. A query may
carry ``timeout=<seconds>``: a command that waited longer than that is answered with an error
instead of run (its caller has given up)."""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import zenoh

from activetouch.clock import SYSTEM_CLOCK, Clock
from activetouch.errors import (
    ActiveTouchError,
    ConfigError,
    MessageError,
    NodeUnavailableError,
)
from activetouch.transport.keys import Keys
from activetouch.transport.messages import (
    DeviceHealth,
    Message,
    Reply,
    decode,
    encode,
)
from activetouch.transport.zenoh_session import close_at_exit, undeclare_quietly

if TYPE_CHECKING:
    from activetouch.daemon.supervision import DeviceLink

log = logging.getLogger(__name__)


JSON = zenoh.Encoding.APPLICATION_JSON


TIMEOUT_PARAM = "timeout"


_STOP = object()  # worker sentinel


MAX_STREAM_HZ = 100.0  # a streaming hand's state is published at most this often


M = TypeVar("M", bound=Message)


def direct(fn: Callable[[Any], Any], drop: Callable[[], Any] | None = None) -> Any:
    """A Zenoh callback run on Zenoh's own thread (``indirect=False``).

    Ours only enqueue or store, so this is safe and cheap. The default (indirect) mode starts
    a non-daemon Python thread per declared callback that lives until it is undeclared: a
    session left open then hangs interpreter exit (threads are joined before atexit runs)."""
    try:
        return zenoh.handlers.Callback(fn, drop, indirect=False)
    except TypeError:  # a zenoh without the (unstable) `indirect` flag
        return zenoh.handlers.Callback(fn, drop)


@dataclass
class Op:
    key: str
    request_type: type[Message]
    fn: Callable[[Any], Any]  # request -> reply result (a Message or None)
    fast: bool = False  # served on the priority thread, without the device lock
    # fn(query, arrived) takes the query itself and replies when it is done (a recognition
    # admitted now, answered later): the worker neither parses, replies nor drops it.
    owns_query: bool = False


@dataclass
class Job:
    op: str
    query: zenoh.Query
    arrived: float


def query_budget(query: zenoh.Query) -> float | None:
    try:
        raw = query.parameters.get(TIMEOUT_PARAM)
        return float(raw) if raw else None
    except (TypeError, ValueError):
        return None


class ServedNode:
    """Queryables feeding one worker thread that owns the device; periodic state publication."""

    node_name = ""

    # Called by the main worker every `idle_period` seconds (None: never), between commands.
    idle_period: float | None = None

    def __init__(
        self,
        session: zenoh.Session | None,
        robot: str,
        *,
        state_key: str,
        state_hz: float,
        lock: threading.Lock | None,
        clock: Clock = SYSTEM_CLOCK,
        link: DeviceLink | None = None,
    ) -> None:
        if not state_hz >= 0:
            raise ConfigError(f"state_hz must be >= 0, got {state_hz}")
        self.keys = Keys(robot)
        self.robot = robot
        self.clock = clock  # when a query arrived and how long it waited, and the state timer
        self._session = session
        self._lock = lock if lock is not None else threading.Lock()
        self._period = 1.0 / state_hz if state_hz > 0 else None
        self._state_key = state_key
        self._ops: dict[str, Op] = {}
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._fast_queue: queue.SimpleQueue = queue.SimpleQueue()
        self._closing = threading.Event()
        self._closed = False
        self._busy: str | None = None  # op being executed by the worker
        self._queryables: list[Any] = []
        self._publisher: Any = None
        self._token: Any = None
        # A device node's link (activetouch.daemon.supervision): commands only while its
        # device is connected, the liveliness token only then, its health on health/<node>.
        self.link = link
        self._token_lock = threading.Lock()
        self._health_pub: Any = None
        self._last_publish_error = ""
        self.published = 0  # state samples published so far
        name = f"activetouch-{self.node_name}-node"
        self._worker = threading.Thread(target=self._run, args=(self._queue, True), name=name)
        self._fast_worker = threading.Thread(
            target=self._run, args=(self._fast_queue, False), name=f"{name}-fast"
        )
        self._worker.daemon = self._fast_worker.daemon = True  # a stuck device must not block exit

    # -- subclass hooks
    def _read_state(self) -> Message:
        raise NotImplementedError

    def _on_close(self) -> None:
        """Called on close, before the workers are joined."""

    # -- lifecycle
    def _on_idle(self) -> None:
        """The main worker's periodic hook (see `idle_period`)."""

    def _failure(self, exc: BaseException) -> Reply:
        """The error reply for `exc` (a subclass may redact it)."""
        return Reply.failure(exc)

    def submit(self, key: str, query: Any) -> None:
        """Hand in a query on `key` as a Zenoh callback would (in memory, without Zenoh)."""
        for name, op in self._ops.items():
            if op.key == key:
                (self._fast_queue if op.fast else self._queue).put(
                    Job(name, query, self.clock.monotonic())
                )
                return
        raise KeyError(f"{self.node_name} node serves no {key}")

    def start(self, declare_token: bool = True) -> None:
        """Serve (the nodes made here start themselves; the daemon's node is started by its
        service, which declares the token once the device nodes are there)."""
        self._start(declare_token)

    def declare_token(self) -> None:
        self._set_token(True)

    def workers_alive(self) -> bool:
        return self._worker.is_alive() and self._fast_worker.is_alive()

    def _start(self, declare_token: bool = True) -> None:
        """Serve the ops; the liveliness token last (or later, `declare_token=False`, by
        `_set_token(True)`). Without a session (in memory) only the workers start."""
        if self._session is None:
            self._worker.start()
            self._fast_worker.start()
            return
        try:
            if self._period is not None:
                self._publisher = self._session.declare_publisher(
                    self._state_key, encoding=JSON, congestion_control=zenoh.CongestionControl.DROP
                )
            for name, op in self._ops.items():
                q = self._fast_queue if op.fast else self._queue
                self._queryables.append(
                    self._session.declare_queryable(op.key, direct(self._enqueuer(name, q)))
                )
            link = self.link
            if link is not None:
                health_key = self.keys.health(self.node_name)
                self._health_pub = self._session.declare_publisher(health_key, encoding=JSON)
                self._queryables.append(
                    self._session.declare_queryable(health_key, direct(self._answer_health))
                )
            self._worker.start()
            self._fast_worker.start()
            close_at_exit(self)  # stop the workers before the interpreter finalises
            # Last: a client that sees the token can use every queryable.
            if link is None:
                if declare_token:
                    self._set_token(True)
            else:
                link.add_listener(self._on_health)
                self._on_health(link.health())
        except Exception:
            self.close()
            raise
        log.info(
            "%s node of robot %s serving under %s", self.node_name, self.robot, self.keys.prefix
        )

    def _set_token(self, alive: bool) -> None:
        with self._token_lock:
            if self._session is None:
                return
            if alive and self._token is None and not self._closing.is_set():
                key = self.keys.alive(self.node_name)
                self._token = self._session.liveliness().declare_token(key)
            elif not alive and self._token is not None:
                undeclare_quietly(self._token)
                self._token = None

    def _on_health(self, health: DeviceHealth) -> None:
        """The link's thread: the token follows the device; the health goes out."""
        if self._closing.is_set():
            return
        self._set_token(health.state == "connected")
        pub = self._health_pub
        if pub is not None:
            try:
                pub.put(encode(health))
            except Exception:
                log.debug("%s node: publishing health failed", self.node_name, exc_info=True)

    def _answer_health(self, query: zenoh.Query) -> None:
        # Zenoh's thread, but cheap and non-blocking: a snapshot of the link's state.
        link = self.link
        if link is None:
            return
        try:
            query.reply(self.keys.health(self.node_name), encode(link.health()), encoding=JSON)
        except Exception:
            log.debug("%s node: cannot answer health", self.node_name, exc_info=True)

    def _enqueuer(self, op: str, q: queue.SimpleQueue) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:
            # Runs on a Zenoh thread: only hand the query over, never block or call Zenoh here.
            q.put(Job(op, query, self.clock.monotonic()))

        return on_query

    @property
    def busy(self) -> str | None:
        """Name of the command being executed, if any."""
        return self._busy

    def queued(self) -> int:
        """Commands waiting behind the one being executed."""
        return self._queue.qsize()

    def close(self, join_timeout: float = 2.0) -> None:
        """Drop the token, stop serving, stop the workers, undeclare. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._closing.set()
        with self._token_lock:
            undeclare_quietly(self._token, *self._queryables)
            self._token = None
        self._queryables.clear()
        try:
            self._on_close()
        except Exception:
            log.exception("%s node: shutdown hook failed", self.node_name)
        for q, worker in ((self._queue, self._worker), (self._fast_queue, self._fast_worker)):
            q.put(_STOP)
            if worker.is_alive() and worker is not threading.current_thread():
                worker.join(join_timeout)
                if worker.is_alive():
                    log.warning(
                        "%s node: worker still busy with %s after %.1f s; leaving it",
                        self.node_name,
                        self._busy,
                        join_timeout,
                    )
        for pub in (self._publisher, self._health_pub):
            if pub is not None:
                undeclare_quietly(pub)
        self._publisher = self._health_pub = None
        log.info("%s node of robot %s closed", self.node_name, self.robot)

    def __enter__(self) -> ServedNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- worker
    def _run(self, q: queue.SimpleQueue, publishes: bool) -> None:
        period = self._period if publishes else None
        idle = self.idle_period if publishes else None
        next_pub = next_idle = self.clock.monotonic()
        while True:
            timeout = None
            if period is not None and not self._closing.is_set():
                now = self.clock.monotonic()
                if now >= next_pub:
                    self._publish_state()
                    # Keep the rate without bursts of catch-up samples after a long command.
                    next_pub = max(next_pub + period, now)
                timeout = max(0.0, next_pub - self.clock.monotonic())
            if idle is not None:
                now = self.clock.monotonic()
                if now >= next_idle:
                    try:
                        self._on_idle()
                    except Exception:
                        log.exception("%s node: idle hook failed", self.node_name)
                    next_idle = now + idle
                left = max(0.0, next_idle - self.clock.monotonic())
                timeout = left if timeout is None else min(timeout, left)
            try:
                job = q.get(timeout=timeout)
            except queue.Empty:
                continue
            if job is _STOP:
                return
            self._serve(job)

    def _publish_state(self) -> None:
        pub = self._publisher
        if pub is None or (self.link is not None and not self.link.connected):
            return
        try:
            with self._lock:
                msg = self._read_state()
            pub.put(encode(msg))
            self.published += 1
            self._last_publish_error = ""
        except Exception as e:
            text = f"{type(e).__name__}: {e}"
            if text != self._last_publish_error:  # log each distinct failure once, not at 20 Hz
                log.warning("%s node: publishing state failed: %s", self.node_name, text)
                self._last_publish_error = text

    def _parse(self, query: zenoh.Query, op: Op) -> Message:
        payload = query.payload
        data = payload.to_bytes() if payload is not None else b""
        if not data:
            try:  # a request whose fields all have defaults may come without a payload
                return op.request_type()
            except TypeError:
                pass
            raise MessageError(
                f"{op.key} needs a {op.request_type.__name__} payload (JSON), got none"
            )
        return decode(data, op.request_type)

    def _serve(self, job: Job) -> None:
        op = self._ops[job.op]
        if op.owns_query and not self._closing.is_set():
            try:
                op.fn(job.query, job.arrived)
            except Exception:  # it replies itself; a bug must not end the worker
                log.exception("%s node: %s failed", self.node_name, job.op)
            return
        with job.query as query:  # leaving the block drops the query: Zenoh sends the final reply
            try:
                if self._closing.is_set():
                    raise NodeUnavailableError(
                        f"{self.node_name} node of robot {self.robot} is shutting down"
                    )
                waited = self.clock.monotonic() - job.arrived
                budget = query_budget(query)
                if budget is not None and waited > budget:
                    raise NodeUnavailableError(
                        f"{job.op} waited {waited:.1f} s for the {self.node_name} node, longer "
                        f"than its caller's timeout ({budget:g} s); not executed"
                    )
                request = self._parse(query, op)
                if self.link is not None and not op.fast:
                    self.link.require()  # the reason, at once, while the device is away
                if op.fast:
                    result = op.fn(request)
                else:
                    self._busy = job.op
                    try:
                        with self._lock:
                            result = op.fn(request)
                    finally:
                        self._busy = None
                query.reply(op.key, encode(Reply.success(result)), encoding=JSON)
            except Exception as e:
                if not isinstance(e, ActiveTouchError | ValueError):
                    log.exception("%s node: %s failed", self.node_name, job.op)
                if self.link is not None:
                    self.link.report(e)  # a device that went away: reconnect
                try:
                    query.reply_err(encode(self._failure(e)), encoding=JSON)
                except Exception:
                    log.debug("%s node: cannot reply to %s", self.node_name, job.op, exc_info=True)
