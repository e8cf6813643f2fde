"""Hand and arm nodes over Zenoh, and the clients that use them as a `Hand` / an `Arm`.

Serving side (`HandNode`, `ArmNode`): any `Hand` / `Arm` (the twin or a real driver) is
served on the keys of `activetouch.transport.keys`. Zenoh callbacks only enqueue the query;
one worker thread per node owns the device, runs one command at a time in arrival order,
replies, and between commands publishes the state periodically. The node's liveliness token
``activetouch/<robot>/alive/<node>`` is declared once everything is served and dropped first
on close. Arm ``stop`` bypasses the queue (its own thread, no lock), so it can halt a running
``execute`` / ``move_wrist``: an `Arm.stop()` must therefore be safe to call from another
thread while a motion runs. Nodes sharing one simulated world pass the same `lock`, so the
twin is never touched by two threads at once.

A query may carry the parameter ``timeout=<seconds>`` (the clients below always do): a command
that waited in the queue longer than that is not executed (its caller has given up) and gets
an error reply instead.

Client side (`RemoteHand`, `RemoteArm`): implement `Hand` / `Arm` with Zenoh ``get``s, each with
an explicit timeout. A node that does not answer in time, is not there, or whose liveliness
token drops mid-call raises `NodeUnavailableError`; a call never hangs. An error raised by the
served device comes back as the same type (`UnreachableError` stays `UnreachableError`; see
`Reply`). Do not call them from inside a Zenoh callback.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import zenoh

from activetouch.errors import (
    ActiveTouchError,
    ConfigError,
    MessageError,
    NodeUnavailableError,
    RemoteError,
)
from activetouch.interfaces import (
    Arm,
    Grasp,
    Hand,
    HandState,
    JointState,
    JointTrajectory,
    Pose,
)
from activetouch.planning.motion.base import Placement, WristMotion
from activetouch.transport.keys import ARM_NODE, HAND_NODE, SIM_NODE, Keys
from activetouch.transport.messages import (
    Empty,
    ExecuteRequest,
    GraspMsg,
    HandStateMsg,
    JointStateMsg,
    Message,
    MotionStats,
    MoveWristRequest,
    PreshapeRequest,
    Reply,
    SimPlaceRequest,
    SimPlaceResult,
    clip_text,
    decode,
    encode,
    error_types,
    grasp_from_msg,
    grasp_to_msg,
    hand_state_from_msg,
    hand_state_to_msg,
    joint_state_from_msg,
    joint_state_to_msg,
    pose_from_msg,
    pose_to_msg,
    trajectory_from_msg,
    trajectory_to_msg,
)
from activetouch.transport.zenoh_session import close_at_exit, undeclare_quietly

log = logging.getLogger(__name__)

JSON = zenoh.Encoding.APPLICATION_JSON
TIMEOUT_PARAM = "timeout"
_STOP = object()  # worker sentinel
_DONE = object()  # a get finished (all replies in, or timed out)
_GONE = object()  # the node's liveliness token dropped
MAX_STREAM_HZ = 100.0  # a streaming hand's state is published at most this often
_GRACE_S = 0.5  # beyond Zenoh's own timeout, before the client gives up regardless

M = TypeVar("M", bound=Message)


def _direct(fn: Callable[[Any], Any], drop: Callable[[], Any] | None = None) -> Any:
    """A Zenoh callback run on Zenoh's own thread (``indirect=False``).

    Ours only enqueue or store, so this is safe and cheap. The default (indirect) mode starts
    a non-daemon Python thread per declared callback that lives until it is undeclared: a
    session left open then hangs interpreter exit (threads are joined before atexit runs)."""
    try:
        return zenoh.handlers.Callback(fn, drop, indirect=False)
    except TypeError:  # a zenoh without the (unstable) `indirect` flag
        return zenoh.handlers.Callback(fn, drop)


@dataclass
class _Op:
    key: str
    request_type: type[Message]
    fn: Callable[[Any], Any]  # request -> reply result (a Message or None)
    fast: bool = False  # served on the priority thread, without the device lock


@dataclass
class _Job:
    op: str
    query: zenoh.Query
    arrived: float


def _query_budget(query: zenoh.Query) -> float | None:
    try:
        raw = query.parameters.get(TIMEOUT_PARAM)
        return float(raw) if raw else None
    except (TypeError, ValueError):
        return None


class _ServedNode:
    """Queryables feeding one worker thread that owns the device; periodic state publication."""

    node_name = ""

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        *,
        state_key: str,
        state_hz: float,
        lock: threading.Lock | None,
    ) -> None:
        if not state_hz >= 0:
            raise ConfigError(f"state_hz must be >= 0, got {state_hz}")
        self.keys = Keys(robot)
        self.robot = robot
        self._session = session
        self._lock = lock if lock is not None else threading.Lock()
        self._period = 1.0 / state_hz if state_hz > 0 else None
        self._state_key = state_key
        self._ops: dict[str, _Op] = {}
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._fast_queue: queue.SimpleQueue = queue.SimpleQueue()
        self._closing = threading.Event()
        self._closed = False
        self._busy: str | None = None  # op being executed by the worker
        self._queryables: list[Any] = []
        self._publisher: Any = None
        self._token: Any = None
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
    def _start(self) -> None:
        try:
            if self._period is not None:
                self._publisher = self._session.declare_publisher(
                    self._state_key, encoding=JSON, congestion_control=zenoh.CongestionControl.DROP
                )
            for name, op in self._ops.items():
                q = self._fast_queue if op.fast else self._queue
                self._queryables.append(
                    self._session.declare_queryable(op.key, _direct(self._enqueuer(name, q)))
                )
            self._worker.start()
            self._fast_worker.start()
            close_at_exit(self)  # stop the workers before the interpreter finalises
            # Last: a client that sees the token can use every queryable.
            self._token = self._session.liveliness().declare_token(self.keys.alive(self.node_name))
        except Exception:
            self.close()
            raise
        log.info(
            "%s node of robot %s serving under %s", self.node_name, self.robot, self.keys.prefix
        )

    def _enqueuer(self, op: str, q: queue.SimpleQueue) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:
            # Runs on a Zenoh thread: only hand the query over, never block or call Zenoh here.
            q.put(_Job(op, query, time.monotonic()))

        return on_query

    @property
    def busy(self) -> str | None:
        """Name of the command being executed, if any."""
        return self._busy

    def close(self, join_timeout: float = 2.0) -> None:
        """Drop the token, stop serving, stop the workers, undeclare. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._closing.set()
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
        if self._publisher is not None:
            undeclare_quietly(self._publisher)
            self._publisher = None
        log.info("%s node of robot %s closed", self.node_name, self.robot)

    def __enter__(self) -> _ServedNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- worker
    def _run(self, q: queue.SimpleQueue, publishes: bool) -> None:
        period = self._period if publishes else None
        next_pub = time.monotonic()
        while True:
            timeout = None
            if period is not None and not self._closing.is_set():
                now = time.monotonic()
                if now >= next_pub:
                    self._publish_state()
                    # Keep the rate without bursts of catch-up samples after a long command.
                    next_pub = max(next_pub + period, now)
                timeout = max(0.0, next_pub - time.monotonic())
            try:
                job = q.get(timeout=timeout)
            except queue.Empty:
                continue
            if job is _STOP:
                return
            self._serve(job)

    def _publish_state(self) -> None:
        pub = self._publisher
        if pub is None:
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

    def _parse(self, query: zenoh.Query, op: _Op) -> Message:
        payload = query.payload
        data = payload.to_bytes() if payload is not None else b""
        if not data:
            if op.request_type is Empty:
                return Empty()
            raise MessageError(
                f"{op.key} needs a {op.request_type.__name__} payload (JSON), got none"
            )
        return decode(data, op.request_type)

    def _serve(self, job: _Job) -> None:
        op = self._ops[job.op]
        with job.query as query:  # leaving the block drops the query: Zenoh sends the final reply
            try:
                if self._closing.is_set():
                    raise NodeUnavailableError(
                        f"{self.node_name} node of robot {self.robot} is shutting down"
                    )
                waited = time.monotonic() - job.arrived
                budget = _query_budget(query)
                if budget is not None and waited > budget:
                    raise NodeUnavailableError(
                        f"{job.op} waited {waited:.1f} s for the {self.node_name} node, longer "
                        f"than its caller's timeout ({budget:g} s); not executed"
                    )
                request = self._parse(query, op)
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
                try:
                    query.reply_err(encode(Reply.failure(e)), encoding=JSON)
                except Exception:
                    log.debug("%s node: cannot reply to %s", self.node_name, job.op, exc_info=True)


class HandNode(_ServedNode):
    """Serve `hand` on ``activetouch/<robot>/hand/...``; publish its state at `state_hz`.

    The hand must already be connected; the node does not connect or disconnect it."""

    node_name = HAND_NODE

    def __init__(
        self,
        hand: Hand,
        session: zenoh.Session,
        robot: str,
        *,
        state_hz: float = 20.0,
        lock: threading.Lock | None = None,
    ) -> None:
        # A hand that reports each reading as it arrives (the ReFlex drivers: 40 Hz, and once
        # when its stream goes stale) is published from there, beside a running grasp;
        # other hands on the node's timer, between commands.
        streams = callable(getattr(hand, "add_state_listener", None))
        super().__init__(
            session,
            robot,
            state_key=Keys(robot).hand_state,
            state_hz=0.0 if streams else state_hz,
            lock=lock,
        )
        self.hand = hand
        self._stream_pub: Any = None
        self._min_gap = 1.0 / MAX_STREAM_HZ
        self._last_put = 0.0
        if streams:
            self._stream_pub = session.declare_publisher(
                self.keys.hand_state, encoding=JSON, congestion_control=zenoh.CongestionControl.DROP
            )
            hand.add_state_listener(self._on_reading)
        k = self.keys
        self._ops = {
            "open": _Op(k.hand_open, Empty, lambda _r: hand.open()),
            "preshape": _Op(k.hand_preshape, PreshapeRequest, lambda r: hand.preshape(r.angle)),
            "guarded_close": _Op(
                k.hand_guarded_close, Empty, lambda _r: grasp_to_msg(hand.guarded_close())
            ),
            "state": _Op(k.hand_state, Empty, lambda _r: hand_state_to_msg(hand.state())),
            # At once, beside a running grasp: the close ends within one control step.
            "stop": _Op(k.hand_stop, Empty, lambda _r: hand.stop(), fast=True),
            "clear_stop": _Op(k.hand_clear_stop, Empty, lambda _r: hand.clear_stop(), fast=True),
        }
        self._start()

    def _read_state(self) -> Message:
        return hand_state_to_msg(self.hand.state())

    def _on_reading(self, state: HandState) -> None:
        # The driver's receive thread: encode and put (non-blocking, drops under congestion).
        pub = self._stream_pub
        now = time.monotonic()
        if pub is None or (now - self._last_put < self._min_gap and not state.stale):
            return
        self._last_put = now
        try:
            pub.put(encode(hand_state_to_msg(state)))
            self.published += 1
        except Exception as e:
            log.debug("hand node: publishing a reading failed: %s", e)

    def _on_close(self) -> None:
        pub, self._stream_pub = self._stream_pub, None
        if pub is not None:
            undeclare_quietly(pub)


class ArmNode(_ServedNode):
    """Serve `arm` on ``activetouch/<robot>/arm/...``; publish joint states at `state_hz`.

    ``move_wrist`` (a wrist pose in the object frame) goes through `wrist`, the motion layer
    for this arm, next to the arm (`placement()` says where the object is before each move).
    ``stop`` runs at once on its own thread, concurrently with a running motion. Closing the
    node while a motion runs stops the arm."""

    node_name = ARM_NODE

    def __init__(
        self,
        arm: Arm,
        session: zenoh.Session,
        robot: str,
        *,
        wrist: WristMotion | None = None,
        placement: Callable[[], Placement] | None = None,
        state_hz: float = 20.0,
        lock: threading.Lock | None = None,
    ) -> None:
        super().__init__(
            session, robot, state_key=Keys(robot).arm_joint_states, state_hz=state_hz, lock=lock
        )
        self.arm = arm
        self.wrist = wrist
        self.placement = placement
        k = self.keys
        self._ops = {
            "joint_state": _Op(
                k.arm_joint_state, Empty, lambda _r: joint_state_to_msg(arm.joint_state())
            ),
            "move_wrist": _Op(k.arm_move_wrist, MoveWristRequest, self._move_wrist),
            "execute": _Op(
                k.arm_execute,
                ExecuteRequest,
                lambda r: arm.execute(trajectory_from_msg(r.trajectory)),
            ),
            "stop": _Op(k.arm_stop, Empty, lambda _r: arm.stop(), fast=True),
            "clear_stop": _Op(k.arm_clear_stop, Empty, lambda _r: arm.clear_stop(), fast=True),
            # The robot's own e-stop where it has one (stop() otherwise): at once, beside a
            # motion. Enabling is explicit, queued like a motion.
            "estop": _Op(k.arm_estop, Empty, lambda _r: arm.estop(), fast=True),
            "enable": _Op(k.arm_enable, Empty, lambda _r: arm.enable()),
            "disable": _Op(k.arm_disable, Empty, lambda _r: arm.disable()),
            # Robot time of the motion layer (a read of three numbers: at once, beside a
            # motion, so a progress report never waits for one).
            "motion_stats": _Op(k.arm_motion_stats, Empty, self._motion_stats, fast=True),
        }
        self._start()

    def _motion_stats(self, _req: Empty) -> MotionStats:
        w = self.wrist
        if w is None:
            return MotionStats()
        return MotionStats(
            robot_s=float(w.robot_seconds), planning_s=float(w.planning_seconds), moves=w.moves
        )

    def _move_wrist(self, req: MoveWristRequest) -> None:
        if self.wrist is None:
            raise ActiveTouchError(f"the {self.node_name} node has no motion layer for move_wrist")
        if self.placement is not None:
            self.wrist.set_placement(self.placement())
        self.wrist.move_to(pose_from_msg(req.pose))

    def _read_state(self) -> Message:
        return joint_state_to_msg(self.arm.joint_state())

    def _on_close(self) -> None:
        if self._busy in ("move_wrist", "execute"):
            log.warning("arm node closing during %s: stopping the arm", self._busy)
            self.arm.stop()


class PlaceNode(_ServedNode):
    """Simulated robots only: ``sim/place`` puts an object on the table via `place`
    (`SimPlaceRequest` -> `SimPlaceResult`), e.g. the twin's or the fake's."""

    node_name = SIM_NODE

    def __init__(
        self,
        place: Callable[[SimPlaceRequest], SimPlaceResult],
        session: zenoh.Session,
        robot: str,
        *,
        lock: threading.Lock | None = None,
    ) -> None:
        super().__init__(session, robot, state_key=Keys(robot).sim_place, state_hz=0.0, lock=lock)
        self._ops = {"place": _Op(self.keys.sim_place, SimPlaceRequest, place)}
        self._start()


# --------------------------------------------------------------------------- clients


LIVELINESS_CHECK_S = 1.0  # how long to ask for a key's tokens after one of them dropped


def tokens_left(session: zenoh.Session, key: str, timeout: float = LIVELINESS_CHECK_S) -> bool:
    """True if some session still holds a liveliness token on `key` (True also when the
    question cannot be asked: a node is never declared gone on a failed check alone)."""
    try:
        replies = session.liveliness().get(key, timeout=timeout)
        return any(r.ok is not None for r in replies)
    except Exception:
        log.debug("liveliness check of %s failed", key, exc_info=True)
        return True


class _Coalesced:
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


class _RemoteNode:
    """Zenoh gets with explicit timeouts, watched by the node's liveliness token."""

    def __init__(self, session: zenoh.Session, robot: str, node: str, timeout: float) -> None:
        if not timeout > 0:
            raise ConfigError(f"timeout must be > 0 s, got {timeout}")
        self.keys = Keys(robot)
        self.robot = robot
        self.node = node
        self.timeout = float(timeout)
        self._session = session
        self._alive: bool | None = None  # None: not heard of yet
        self._cv = threading.Condition()
        self._pending: set[queue.SimpleQueue] = set()
        self._live_sub: Any = None
        self._gone_check = _Coalesced(self._check_gone, f"activetouch-{node}-liveliness")
        self._watch()

    @property
    def alive_key(self) -> str:
        return self.keys.alive(self.node)

    @property
    def alive(self) -> bool | None:
        """True / False once the node's token was seen / dropped; None before."""
        return self._alive

    def _watch(self) -> None:
        if self._live_sub is None:
            try:
                self._live_sub = self._session.liveliness().declare_subscriber(
                    self.alive_key, _direct(self._on_liveliness), history=True
                )
            except Exception as e:  # e.g. the session is closed
                raise NodeUnavailableError(f"cannot watch {self.alive_key}: {e}") from None

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with self._cv:
                self._alive = True  # a token reappearing brings the node back
                self._cv.notify_all()
            return
        # A dropped token may be anyone's (a client can declare and drop the same key): the
        # node is gone only if no token of its key is left. Asking is a Zenoh call, so not
        # here in the callback; one check at a time, repeated if more drops came meanwhile.
        self._gone_check.request()

    def _check_gone(self) -> None:
        if not tokens_left(self._session, self.alive_key):
            with self._cv:
                self._alive = False
                self._cv.notify_all()
                waiting = list(self._pending)
            for q in waiting:  # wake calls in flight: their node is gone
                q.put(_GONE)

    def wait_alive(self, timeout: float | None = None) -> None:
        """Return once the node's liveliness token is seen; NodeUnavailableError after `timeout`."""
        timeout = self.timeout if timeout is None else timeout
        with self._cv:
            if not self._cv.wait_for(lambda: self._alive is True, timeout=timeout):
                raise NodeUnavailableError(
                    f"no {self.node} node for robot {self.robot!r}: its liveliness token "
                    f"{self.alive_key} did not appear within {timeout:g} s "
                    "(is it running, and are the Zenoh endpoints right?)"
                )

    def close(self) -> None:
        sub, self._live_sub = self._live_sub, None
        if sub is not None:
            undeclare_quietly(sub)

    def _gone_error(self, op: str) -> NodeUnavailableError:
        return NodeUnavailableError(
            f"{self.node} node of robot {self.robot!r} is gone (liveliness token "
            f"{self.alive_key} dropped); {op} not done"
        )

    def _query(self, key: str, request: Message, q: queue.SimpleQueue, timeout: float) -> None:
        """Send `request` to `key`; replies go to `q`, then `_DONE`. The timeout travels with
        the query so the node can drop it once the caller has given up."""
        try:
            self._session.get(
                f"{key}?{TIMEOUT_PARAM}={timeout:g}",
                _direct(q.put, lambda: q.put(_DONE)),
                payload=encode(request),
                encoding=JSON,
                timeout=timeout,
            )
        except Exception as e:  # e.g. the session is closed
            raise NodeUnavailableError(f"cannot query {key}: {e}") from None

    def _call(
        self, op: str, key: str, request: Message, result_type: Any, timeout: float | None = None
    ) -> Any:
        timeout = self.timeout if timeout is None else float(timeout)
        if self._alive is False:
            raise self._gone_error(op)
        q: queue.SimpleQueue = queue.SimpleQueue()
        with self._cv:
            self._pending.add(q)
        start = time.monotonic()
        try:
            self._query(key, request, q, timeout)
            deadline = start + timeout + _GRACE_S
            while True:
                try:
                    item = q.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    item = _DONE
                if item is _GONE:
                    raise self._gone_error(op)
                if item is _DONE:
                    elapsed = time.monotonic() - start
                    if elapsed < 0.9 * timeout:
                        raise NodeUnavailableError(
                            f"no {self.node} node of robot {self.robot!r} answers on {key} "
                            "(is it running, and are the Zenoh endpoints right?)"
                        )
                    raise NodeUnavailableError(
                        f"{self.node} node of robot {self.robot!r} did not answer {op} "
                        f"within {timeout:g} s"
                    )
                if not isinstance(item, zenoh.Reply):
                    continue
                failure = self._zenoh_failure(op, key, item, timeout)
                if failure is not None:
                    raise failure
                res = item.result
                env = decode(res.payload.to_bytes(), Reply[result_type])
                if env.ok:
                    return env.result
                raise self._remote_error(op, env)
        finally:
            with self._cv:
                self._pending.discard(q)

    def _zenoh_failure(
        self, op: str, key: str, reply: zenoh.Reply, timeout: float
    ) -> NodeUnavailableError | None:
        """The error of a reply made by Zenoh itself (not our JSON `Reply`), else None.

        Zenoh answers a query nobody replied to in time with an error reply whose payload is
        the plain string "Timeout"; decoding that as a `Reply` said "not valid JSON"."""
        if reply.ok:
            return None
        err = reply.err
        data = err.payload.to_bytes()
        if str(err.encoding).startswith(str(JSON)) or data.lstrip().startswith(b"{"):
            return None  # one of ours (reply_err with a JSON Reply)
        text = clip_text(data[:200].decode("utf-8", "replace"), 100)
        what = f"{self.node} node of robot {self.robot!r}: {op} on {key}"
        if text.strip().lower() == "timeout":
            return NodeUnavailableError(f"{what} timed out (no reply within {timeout:g} s)")
        return NodeUnavailableError(f"{what} failed in Zenoh: {text or 'no reason given'}")

    def _remote_error(self, op: str, env: Reply) -> Exception:
        known = error_types()
        for name in (env.error_type, *env.error_bases):
            cls = known.get(name or "")
            if cls is not None:
                return cls(env.error)
        return RemoteError(f"{self.node} node: {op} failed: {env.error_type}: {env.error}")


class _RemoteDevice(_RemoteNode):
    """A hand or arm node elsewhere: quick calls bounded by `timeout`, motions by
    `motion_timeout`; `connect()` waits for the node's liveliness token."""

    def __init__(
        self, session: zenoh.Session, robot: str, node: str, timeout: float, motion_timeout: float
    ) -> None:
        super().__init__(session, robot, node, timeout)
        if not motion_timeout > 0:
            raise ConfigError(f"motion_timeout must be > 0 s, got {motion_timeout}")
        self.motion_timeout = float(motion_timeout)

    def connect(self) -> None:
        self._watch()
        self.wait_alive()

    def disconnect(self) -> None:
        self.close()

    def __enter__(self) -> Any:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


class RemoteHand(_RemoteDevice, Hand):
    """A `Hand` served by a `HandNode` elsewhere.

    `timeout` bounds quick calls (state); `motion_timeout` bounds open, preshape and
    guarded_close. `connect()` waits (up to `timeout`) for the node's liveliness token."""

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        timeout: float = 5.0,
        *,
        motion_timeout: float = 30.0,
    ) -> None:
        super().__init__(session, robot, HAND_NODE, timeout, motion_timeout)

    def open(self) -> None:
        self._call("open", self.keys.hand_open, Empty(), None, self.motion_timeout)

    def preshape(self, angle: float) -> None:
        self._call(
            "preshape",
            self.keys.hand_preshape,
            PreshapeRequest(angle=float(angle)),
            None,
            self.motion_timeout,
        )

    def guarded_close(self) -> Grasp:
        msg = self._call(
            "guarded_close", self.keys.hand_guarded_close, Empty(), GraspMsg, self.motion_timeout
        )
        return grasp_from_msg(msg)

    def state(self) -> HandState:
        return hand_state_from_msg(self._call("state", self.keys.hand_state, Empty(), HandStateMsg))

    def stop(self) -> None:
        self._call("stop", self.keys.hand_stop, Empty(), None)

    def clear_stop(self) -> None:
        self._call("clear_stop", self.keys.hand_clear_stop, Empty(), None)


class RemoteArm(_RemoteDevice, WristMotion):
    """The arm served by an `ArmNode` elsewhere: its joint-level calls, and wrist motion
    (``move_to`` = ``arm/move_wrist``, planned by the node's motion layer, next to the arm).

    `timeout` bounds quick calls (joint_state, stop); `motion_timeout` bounds move_wrist, and
    execute waits for at least the trajectory's duration plus `timeout`."""

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        timeout: float = 5.0,
        *,
        motion_timeout: float = 120.0,
    ) -> None:
        super().__init__(session, robot, ARM_NODE, timeout, motion_timeout)

    def joint_state(self) -> JointState:
        msg = self._call("joint_state", self.keys.arm_joint_state, Empty(), JointStateMsg)
        return joint_state_from_msg(msg)

    def execute(self, trajectory: JointTrajectory) -> None:
        msg = trajectory_to_msg(trajectory)
        duration = msg.times[-1] - msg.times[0]
        timeout = max(self.motion_timeout, duration + self.timeout)
        self._call("execute", self.keys.arm_execute, ExecuteRequest(trajectory=msg), None, timeout)

    def move_wrist(self, pose: Pose) -> None:
        self._call(
            "move_wrist",
            self.keys.arm_move_wrist,
            MoveWristRequest(pose=pose_to_msg(pose)),
            None,
            self.motion_timeout,
        )

    def move_to(self, pose: Pose) -> None:
        self.move_wrist(pose)

    # The node's motion layer's robot time (``arm/motion_stats``), as `WristMotion` counts it;
    # the session reads these around a recognition. Each is one query.
    @property  # type: ignore[override]
    def robot_seconds(self) -> float:
        k = self.keys.arm_motion_stats
        return self._call("motion_stats", k, Empty(), MotionStats).robot_s

    @property  # type: ignore[override]
    def planning_seconds(self) -> float:
        k = self.keys.arm_motion_stats
        return self._call("motion_stats", k, Empty(), MotionStats).planning_s

    def stop(self) -> None:
        self._call("stop", self.keys.arm_stop, Empty(), None)

    def clear_stop(self) -> None:
        self._call("clear_stop", self.keys.arm_clear_stop, Empty(), None)

    def estop(self) -> None:
        self._call("estop", self.keys.arm_estop, Empty(), None)

    def enable(self) -> None:
        self._call("enable", self.keys.arm_enable, Empty(), None, self.motion_timeout)

    def disable(self) -> None:
        self._call("disable", self.keys.arm_disable, Empty(), None, self.motion_timeout)


class RemotePlace(_RemoteNode):
    """The ``sim/place`` node of a simulated robot."""

    def __init__(self, session: zenoh.Session, robot: str, timeout: float) -> None:
        super().__init__(session, robot, SIM_NODE, timeout)

    def place(self, obj: str, seed: int | None) -> SimPlaceResult:
        return self._call(
            "place", self.keys.sim_place, SimPlaceRequest(object=obj, seed=seed), SimPlaceResult
        )


class Latest(Generic[M]):
    """Keeps the latest valid message published on `key` (e.g. hand state, joint states).

    Invalid samples are counted and their error kept (`last_error`), never raised in the
    Zenoh callback."""

    def __init__(self, session: zenoh.Session, key: str, msg_type: type[M]) -> None:
        self.key = key
        self.msg_type = msg_type
        self._cv = threading.Condition()
        self._msg: M | None = None
        self._received_at = 0.0
        self.count = 0
        self.invalid = 0
        self.last_error: str | None = None
        self._sub: Any = session.declare_subscriber(key, _direct(self._on_sample))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), self.msg_type)
        except MessageError as e:
            with self._cv:
                self.invalid += 1
                self.last_error = str(e)
            return
        with self._cv:
            self._msg = msg
            self._received_at = time.monotonic()
            self.count += 1
            self._cv.notify_all()

    def get(self) -> M | None:
        """The latest message, or None if none arrived yet."""
        return self._msg

    def age(self) -> float | None:
        """Seconds since the latest message arrived, or None."""
        return None if self._msg is None else time.monotonic() - self._received_at

    def wait(self, timeout: float, newer_than: int | None = None) -> M:
        """Wait for a message (or for one after the `newer_than`-th); NodeUnavailableError."""
        seen = self.count if newer_than is None else newer_than
        with self._cv:
            ok = self._cv.wait_for(lambda: self.count > seen, timeout=timeout)
            if not ok:
                raise NodeUnavailableError(f"nothing published on {self.key} within {timeout:g} s")
            assert self._msg is not None
            return self._msg

    def close(self) -> None:
        sub, self._sub = self._sub, None
        if sub is not None:
            undeclare_quietly(sub)


class AliveNodes:
    """Which nodes of a robot are alive, from their liveliness tokens (for status reports)."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.keys = Keys(robot)
        self._cv = threading.Condition()
        self._state: dict[str, bool] = {}
        self._changed: dict[str, float] = {}
        self._session = session
        self._checks: dict[str, _Coalesced] = {}
        self._sub: Any = session.liveliness().declare_subscriber(
            self.keys.alive_all, _direct(self._on_sample), history=True
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        node = Keys.node_of_alive_key(str(sample.key_expr))
        if sample.kind == zenoh.SampleKind.PUT:
            self._set(node, True)
            return
        with self._cv:  # confirm off the callback, as `_RemoteNode` does
            check = self._checks.get(node)
            if check is None:
                check = self._checks[node] = _Coalesced(
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


class DeviceNodes:
    """The robot's devices served as its hand and arm nodes (and ``sim/place`` when they are
    simulated), all holding the devices' one lock. Whatever the device types: the twin, the
    fakes or real drivers (activetouch.devices)."""

    def __init__(self, devices: Any, session: zenoh.Session, robot: str, state_hz: float) -> None:
        self.devices = devices
        self.nodes: list[_ServedNode] = []
        lock = devices.lock
        try:
            self.nodes.append(HandNode(devices.hand, session, robot, state_hz=state_hz, lock=lock))
            self.nodes.append(
                ArmNode(
                    devices.arm,
                    session,
                    robot,
                    wrist=devices.wrist,
                    placement=devices.placement,
                    state_hz=state_hz,
                    lock=lock,
                )
            )
            if devices.simulated and devices.ctx.place is not None:
                self.nodes.append(PlaceNode(devices.ctx.place, session, robot, lock=lock))
            from activetouch.daemon.calibration_node import CalibrationNode

            # calibrate/<kind>: the procedures of activetouch.calibration on these devices.
            self.nodes.append(CalibrationNode(devices, session, robot, lock=lock))
        except Exception:
            self.close()
            raise
        cfg = devices.ctx.cfg
        log.info(
            "device nodes serving",
            extra={
                "robot": robot,
                "hand": cfg.hand.type,
                "arm": cfg.arm.type,
                "nodes": ",".join(n.node_name for n in self.nodes),
            },
        )

    def healthy(self) -> bool:
        return all(n._worker.is_alive() for n in self.nodes)

    def close(self, join_timeout: float = 1.0) -> None:
        for node in reversed(self.nodes):
            node.close(join_timeout)
        self.nodes.clear()
