"""Talking to the recognition daemon (`activetouch serve`) over Zenoh.

`DaemonClient` sends `recognize`, `status`, `cancel` and `estop` queries to the daemon of one
robot, each a Zenoh ``get`` with an explicit timeout (Zenoh's default of 10 s is far too short
for a recognition). While a recognition runs, the daemon publishes a `Progress` sample on
``activetouch/<robot>/progress`` after every grasp; the client subscribes before it asks and
hands the samples of its own session to `on_progress` on the calling thread. The daemon's
liveliness token is watched: if the daemon goes away mid-request the call fails at once with
`NodeUnavailableError` instead of waiting out its timeout.

Errors the daemon reports come back as exceptions: `MessageError` (malformed request),
`BusyError` (a recognition is already running), `DataError` (no model, unknown object),
`NodeUnavailableError` (the hand or arm node is gone) ... each with the daemon's text.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np
import zenoh

from activetouch.daemon.remote import DONE, GONE, GRACE_S, RemoteNode
from activetouch.daemon.serving import direct
from activetouch.errors import ActiveTouchError, MessageError, NodeUnavailableError
from activetouch.session.loop import Progress as SessionProgress
from activetouch.session.loop import RecognitionResult
from activetouch.transport.keys import DAEMON_NODE
from activetouch.transport.messages import (
    CancelRequest,
    CancelResult,
    Empty,
    EStopRequest,
    EStopResult,
    Progress,
    RecognizeRequest,
    RecognizeResult,
    Reply,
    Status,
    decode,
)
from activetouch.transport.zenoh_session import (
    ZenohSession,
    ZenohSettings,
    free_tcp_port,
    loopback_endpoint,
)


class BusyError(ActiveTouchError):
    """The daemon is already running a recognition (and its queue, if any, is full)."""


class RecognitionAbortedError(ActiveTouchError):
    """A recognition was stopped by an emergency stop or by the daemon shutting down."""


_PROGRESS = "progress"
_GONE_GRACE_S = 2.0  # after the daemon's token drops, wait this long for its last answer


def client_settings(
    connect: Sequence[str], zenoh_config: str | Path | None = None
) -> ZenohSettings:
    """A client session: connects to `connect`, listens on nothing, scouting off."""
    return ZenohSettings(
        listen=(),
        connect=tuple(connect),
        config_file=Path(zenoh_config) if zenoh_config else None,
    )


def new_session_id() -> str:
    return uuid.uuid4().hex[:12]


class DaemonClient(RemoteNode):
    """The recognition daemon of `robot`, reached through `session`.

    `timeout` bounds the quick queries (status, cancel, estop); `recognize` takes its own."""

    def __init__(self, session: zenoh.Session, robot: str, timeout: float = 5.0) -> None:
        super().__init__(session, robot, DAEMON_NODE, timeout)

    def connect(self, timeout: float | None = None) -> None:
        """Wait for the daemon's liveliness token (NodeUnavailableError if it does not appear)."""
        self._watch()
        self.wait_alive(timeout)

    def status(self) -> Status:
        return self._call("status", self.keys.status, Empty(), Status)

    def cancel(self, session_id: str | None = None) -> CancelResult:
        return self._call(
            "cancel", self.keys.cancel, CancelRequest(session_id=session_id), CancelResult
        )

    def estop(self, reason: str = "") -> EStopResult:
        return self._call("estop", self.keys.estop, EStopRequest(reason=reason), EStopResult)

    def recognize(
        self,
        request: RecognizeRequest,
        on_progress: Callable[[Progress], None] | None = None,
        timeout: float = 600.0,
        detached: bool = False,
    ) -> RecognizeResult:
        """Run one recognition; `on_progress` sees every grasp of it (on this thread).

        Gives up after `timeout` s (NodeUnavailableError), at once if the daemon goes away.
        While it waits, this client holds the liveliness token ``requests/<session_id>``: if
        the client goes away (closed, killed), the daemon cancels the recognition (it moves a
        robot nobody watches any more). `detached`: no token, the recognition runs to its end."""
        if request.session_id is None:
            request = msgspec.structs.replace(request, session_id=new_session_id())
        sid = request.session_id
        if self._alive is False:
            raise self._gone_error("recognize")
        q: queue.SimpleQueue = queue.SimpleQueue()

        def on_sample(sample: zenoh.Sample) -> None:
            # Zenoh's thread: decode and hand over, never block or print here.
            try:
                msg = decode(sample.payload.to_bytes(), Progress)
            except MessageError:
                return
            if msg.session_id == sid:
                q.put((_PROGRESS, msg))

        sub = self._session.declare_subscriber(self.keys.progress, direct(on_sample))
        token = None
        if not detached:
            token = self._session.liveliness().declare_token(self.keys.requester(sid))
        with self._cv:
            self._pending.add(q)
        start = time.monotonic()
        try:
            self._query(self.keys.recognize, request, q, timeout)
            deadline = start + timeout + GRACE_S
            reply: Reply | None = None
            gone = False
            while True:
                try:
                    item = q.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    item = DONE
                if item is GONE:
                    # A daemon shutting down drops its token first and then answers (why it
                    # stopped): wait a moment for that answer; a crashed one sends none.
                    gone = True
                    deadline = min(deadline, time.monotonic() + _GONE_GRACE_S)
                    continue
                if isinstance(item, tuple) and item[0] == _PROGRESS:
                    if on_progress is not None:
                        on_progress(item[1])
                    continue
                if isinstance(item, zenoh.Reply):
                    # Zenoh's own error (its query timeout): not a Reply to decode.
                    failure = self._zenoh_failure("recognize", self.keys.recognize, item, timeout)
                    if failure is not None:
                        raise failure
                    # Progress published before the reply may still be queued: keep
                    # draining until the get is done, then answer.
                    reply = decode(item.result.payload.to_bytes(), Reply[RecognizeResult])
                    continue
                if item is DONE:
                    break
            if reply is None and gone:
                raise NodeUnavailableError(
                    f"the recognition daemon of robot {self.robot!r} went away during "
                    f"recognition {sid} (its liveliness token {self.alive_key} dropped)"
                )
            if reply is None:
                if time.monotonic() - start < 0.9 * timeout:
                    raise NodeUnavailableError(
                        f"no recognition daemon for robot {self.robot!r} answers on "
                        f"{self.keys.recognize} (is it running, and are the Zenoh endpoints right?)"
                    )
                raise NodeUnavailableError(f"recognition {sid} did not finish within {timeout:g} s")
            if reply.ok:
                return reply.result
            raise self._remote_error("recognize", reply)
        finally:
            with self._cv:
                self._pending.discard(q)
            with suppress(Exception):  # the session may be closed already
                sub.undeclare()
            if token is not None:
                with suppress(Exception):
                    token.undeclare()

    def _remote_error(self, op: str, env: Reply) -> Exception:
        for cls in (BusyError, RecognitionAbortedError):
            if env.error_type == cls.__name__:
                return cls(env.error)
        return super()._remote_error(op, env)


@contextmanager
def open_client(
    connect: Sequence[str],
    robot: str,
    *,
    timeout: float = 5.0,
    zenoh_config: str | Path | None = None,
    wait: float | None = None,
) -> Iterator[DaemonClient]:
    """A connected `DaemonClient` in its own Zenoh session, closed on exit.

    Waits up to `wait` s (default `timeout`) for the daemon's liveliness token."""
    with ZenohSession(client_settings(connect, zenoh_config)) as zs:
        client = zs.closing(DaemonClient(zs.session, robot, timeout))
        client.connect(timeout if wait is None else wait)
        yield client


# --------------------------------------------------------------------------- conversions


def session_progress(msg: Progress) -> SessionProgress:
    """The in-process `Progress` of a wire sample (for the same terminal output)."""
    pose = (
        np.array([*msg.pose.xyz, *msg.pose.quat], dtype=np.float64)
        if msg.pose is not None
        else np.full(7, np.nan)
    )
    return SessionProgress(
        move=msg.move,
        pose_id=-1 if msg.pose_id is None else msg.pose_id,
        pose=pose,
        n_contacts=msg.n_contacts,
        top=[(label, float(p)) for label, p in msg.top3],
        skipped=msg.skipped,
        elapsed_s=msg.elapsed_s,
        motion_s=msg.motion_s,
    )


def session_result(msg: RecognizeResult) -> RecognitionResult:
    """The in-process `RecognitionResult` of a wire result (fields the wire carries)."""
    return RecognitionResult(
        label=msg.label,
        probability=msg.probability,
        labels=list(msg.labels),
        pose_ids=list(msg.pose_ids),
        skipped=msg.skipped,
        # A daemon from before search_s sent the search alone as planning_s.
        search_s=msg.search_s if msg.search_s or msg.total_s else msg.planning_s,
        elapsed_s=msg.elapsed_s,
        stop_reason=msg.stop_reason,
        motion_s=msg.motion_s,
        motion_planning_s=msg.motion_planning_s,
        grasp_s=msg.grasp_s,
        masked_sensors=list(msg.masked_sensors),
        masked_reasons={int(k): v for k, v in msg.masked_reasons.items()},
        pose_estimate=msg.pose_estimate,
        profile=msg.profile,
        settings=dict(msg.settings),
    )


def describe_status(st: Status) -> list[str]:
    """Lines for a terminal."""
    lines = [f"robot {st.robot} ({st.mode or '?'}), up {st.uptime_s:.0f} s"]
    for name, h in sorted(st.nodes.items()):
        state = h.state or ("alive" if h.alive else "down")
        state = state if h.alive else state.upper()
        device = f" ({h.device})" if h.device else ""
        lines.append(f"  {name:<7} {state}{device}{'  ' + h.detail if h.detail else ''}")
    if st.model_loaded:
        lines.append(f"  model   {st.model}")
    else:
        lines.append(f"  model   none: {st.model_error or 'not loaded'}")
    if st.session is not None:
        s = st.session
        obj = f" {s.object}" if s.object else ""
        lines.append(
            f"  session {s.session_id}:{obj} {s.policy}, grasp {s.move}/{s.max_moves}, "
            f"running {max(0.0, time.time() - s.started):.1f} s"
        )
    else:
        lines.append("  session none")
    if st.queued:
        lines.append(f"  queued  {st.queued}")
    return lines


# --------------------------------------------------------------------------- a local daemon


@dataclass
class LocalDaemon:
    """A daemon this process started (`local_daemon`): its endpoint and process."""

    endpoint: str
    robot: str
    proc: subprocess.Popen
    log: Path | None


@contextmanager
def local_daemon(
    data: str | Path | None,
    *,
    robot: str = "sim",
    args: Sequence[str] = (),
    log: Path | None = None,
    start_timeout: float = 120.0,
    stop_timeout: float = 10.0,
) -> Iterator[LocalDaemon]:
    """Run ``python -m activetouch serve --sim`` on a free 127.0.0.1 port until the block ends.

    Waits for the daemon's liveliness token; afterwards sends SIGTERM to its pid and waits for
    it (SIGKILL if it has not exited within `stop_timeout`). Its log goes to `log` (or is
    discarded)."""

    endpoint = loopback_endpoint(free_tcp_port())
    cmd = [sys.executable, "-m", "activetouch", "serve", "--sim", "--robot", robot]
    cmd += ["--listen", endpoint, *(["--data", str(data)] if data else []), *args]
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NOTIFY_", "WATCHDOG_"))}
    out = open(log, "w") if log else subprocess.DEVNULL  # noqa: SIM115 - closed below
    proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env)
    try:
        deadline = time.monotonic() + start_timeout
        with ZenohSession(client_settings([endpoint])) as zs:
            client = zs.closing(DaemonClient(zs.session, robot))
            while True:
                if proc.poll() is not None:
                    tail = log.read_text()[-2000:] if log else ""
                    raise ActiveTouchError(
                        f"the daemon exited with status {proc.returncode} while starting"
                        + (f"; its log ({log}) ends:\n{tail}" if log else "")
                    )
                try:
                    client.wait_alive(min(1.0, max(0.01, deadline - time.monotonic())))
                    break
                except NodeUnavailableError:
                    if time.monotonic() > deadline:
                        raise NodeUnavailableError(
                            f"the daemon (pid {proc.pid}) did not come up within "
                            f"{start_timeout:g} s"
                        ) from None
        yield LocalDaemon(endpoint, robot, proc, log)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGTERM)
            try:
                proc.wait(stop_timeout)
            except subprocess.TimeoutExpired:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait()
        if out is not subprocess.DEVNULL:
            out.close()
