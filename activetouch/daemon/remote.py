"""Client side of the device nodes (`RemoteHand`, `RemoteArm`, `RemotePlace`): `Hand` / `Arm`
implemented with Zenoh ``get``s, each with an explicit timeout. A node that does not answer in
time, is not there, or whose liveliness token drops mid-call raises `NodeUnavailableError`; a call
never hangs. An error raised by the served device comes back as the same type (see `Reply`). Do
not call them from inside a Zenoh callback."""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections.abc import Sequence
from typing import Any, Generic

import numpy as np
import zenoh

from activetouch.daemon.liveliness import Coalesced, tokens_left
from activetouch.daemon.serving import JSON, TIMEOUT_PARAM, M, direct
from activetouch.errors import (
    ConfigError,
    MessageError,
    NodeUnavailableError,
    RemoteError,
)
from activetouch.interfaces import (
    Grasp,
    Hand,
    HandState,
    JointState,
    JointTrajectory,
    Pose,
)
from activetouch.planning.motion.base import WristMotion
from activetouch.transport.keys import ARM_NODE, HAND_NODE, SIM_NODE, Keys
from activetouch.transport.messages import (
    Empty,
    ExecuteRequest,
    GraspMsg,
    HandInfo,
    HandStateMsg,
    JointStateMsg,
    MaskRequest,
    Message,
    MotionStats,
    MoveWristRequest,
    PreshapeRequest,
    Reply,
    SensorFlagsMsg,
    SensorSitesMsg,
    SimPlaceRequest,
    SimPlaceResult,
    ThresholdsRequest,
    clip_text,
    decode,
    encode,
    error_types,
    grasp_from_msg,
    hand_state_from_msg,
    joint_state_from_msg,
    pose_to_msg,
    trajectory_to_msg,
)
from activetouch.transport.zenoh_session import undeclare_quietly

log = logging.getLogger(__name__)


DONE = object()  # a get finished (all replies in, or timed out)


GONE = object()  # the node's liveliness token dropped


GRACE_S = 0.5  # beyond Zenoh's own timeout, before the client gives up regardless


_RAISE = object()  # `_call` without a `missing` value: no answer is an error


class RemoteNode:
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
        self._gone_check = Coalesced(self._check_gone, f"activetouch-{node}-liveliness")
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
                    self.alive_key, direct(self._on_liveliness), history=True
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
                q.put(GONE)

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
        """Send `request` to `key`; replies go to `q`, then `DONE`. The timeout travels with
        the query so the node can drop it once the caller has given up."""
        try:
            self._session.get(
                f"{key}?{TIMEOUT_PARAM}={timeout:g}",
                direct(q.put, lambda: q.put(DONE)),
                payload=encode(request),
                encoding=JSON,
                timeout=timeout,
            )
        except Exception as e:  # e.g. the session is closed
            raise NodeUnavailableError(f"cannot query {key}: {e}") from None

    def _call(
        self,
        op: str,
        key: str,
        request: Message,
        result_type: Any,
        timeout: float | None = None,
        missing: Any = _RAISE,
    ) -> Any:
        """The result of `request` on `key`. With `missing`: that, when the node is alive but
        nothing serves `key` (a node from before it was added), instead of an error."""
        timeout = self.timeout if timeout is None else float(timeout)
        if self._alive is False:
            raise self._gone_error(op)
        q: queue.SimpleQueue = queue.SimpleQueue()
        with self._cv:
            self._pending.add(q)
        start = time.monotonic()
        try:
            self._query(key, request, q, timeout)
            deadline = start + timeout + GRACE_S
            while True:
                try:
                    item = q.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    item = DONE
                if item is GONE:
                    raise self._gone_error(op)
                if item is DONE:
                    elapsed = time.monotonic() - start
                    if elapsed < 0.9 * timeout:
                        if missing is not _RAISE and self._alive:
                            return missing
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


class RemoteDevice(RemoteNode):
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


class RemoteHand(RemoteDevice, Hand):
    """A `Hand` served by a `HandNode` elsewhere.

    `timeout` bounds quick calls (state); `motion_timeout` bounds open, preshape and
    guarded_close. `connect()` waits (up to `timeout`) for the node's liveliness token, then
    asks the node's `HandInfo` (``hand/info``): `n_sensors` is the hand's sensor count (38
    from a node from before hand/info), and a state or grasp that does not fit it is refused
    with a `MessageError`. The info is asked again after the node's token reappears."""

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        timeout: float = 5.0,
        *,
        motion_timeout: float = 30.0,
    ) -> None:
        self._info: HandInfo | None = None
        super().__init__(session, robot, HAND_NODE, timeout, motion_timeout)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self._info = None  # a node (re)appearing may serve another hand: ask again
        super()._on_liveliness(sample)

    def connect(self) -> None:
        super().connect()
        # Asked now; a node slow to answer is asked again by the first call that needs it.
        with contextlib.suppress(NodeUnavailableError):
            self.info()

    def info(self) -> HandInfo:
        """The hand node's `HandInfo`: asked once (one query), then kept."""
        info = self._info
        if info is None:
            got = self._call("info", self.keys.hand_info, Empty(), HandInfo, missing=None)
            info = got if got is not None else HandInfo()  # an older node: 38 sensors
            self._info = info
        return info

    @property
    def n_sensors(self) -> int:
        return self.info().n_sensors

    def open(self) -> None:
        self._call("open", self.keys.hand_open, Empty(), None, self.motion_timeout)

    def mask_sensors(self, sensor_ids: Sequence[int]) -> bool:
        req = MaskRequest(sensor_ids=[int(i) for i in sensor_ids])
        return bool(self._call("mask", self.keys.hand_mask, req, bool))

    def set_contact_thresholds(self, thresholds: Sequence[float]) -> bool:
        req = ThresholdsRequest(thresholds=[float(t) for t in thresholds])
        return bool(self._call("thresholds", self.keys.hand_thresholds, req, bool))

    def sensor_flags(self) -> dict[int, str]:
        msg = self._call("sensor_flags", self.keys.hand_sensor_flags, Empty(), SensorFlagsMsg)
        return {int(k): v for k, v in msg.flags.items()}

    def _sensor_sites(self) -> SensorSitesMsg:
        """The node's ``hand/sensor_sites`` (a node from before it: neither list)."""
        msg = self._call(
            "sensor_sites", self.keys.hand_sensor_sites, Empty(), SensorSitesMsg, missing=None
        )
        return SensorSitesMsg() if msg is None else msg

    def sensor_sites(self) -> np.ndarray | None:
        sites = self._sensor_sites().sites
        if len(sites) != self.n_sensors:
            return None
        return np.array(sites, dtype=np.float64).reshape(-1, 3)

    def own_contact_thresholds(self) -> np.ndarray | None:
        own = self._sensor_sites().own_thresholds
        if len(own) != self.n_sensors:
            return None
        return np.array(own, dtype=np.float64)

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
        return grasp_from_msg(msg, self.n_sensors)

    def state(self) -> HandState:
        msg = self._call("state", self.keys.hand_state, Empty(), HandStateMsg)
        return hand_state_from_msg(msg, self.n_sensors)

    def stop(self) -> None:
        self._call("stop", self.keys.hand_stop, Empty(), None)

    def clear_stop(self) -> None:
        self._call("clear_stop", self.keys.hand_clear_stop, Empty(), None)


class RemoteArm(RemoteDevice, WristMotion):
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


class RemotePlace(RemoteNode):
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
        self._sub: Any = session.declare_subscriber(key, direct(self._on_sample))

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
