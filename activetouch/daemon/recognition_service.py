"""The recognition service: admission, one recognition at a time (with an optional queue),
cancel, status and the emergency stop, on the daemon's Zenoh keys (docs/api.md).

In the daemon it reaches the hand and the arm *only* through Zenoh (`RemoteHand`,
`RemoteArm`), whether the nodes live in the same process or another one; everything it uses
(devices, progress publication, requesters' tokens) comes in `ServiceLinks`, so tests run it
in memory on the devices themselves (`local_links`) with queries handed to `submit`.

Threads: the daemon's queryables are a `ServedNode` (activetouch.daemon.serving, the serving
base of every node): Zenoh callbacks only enqueue queries; its main worker (the control
thread) answers ``status`` and ``cancel`` and admits ``recognize`` requests (validation, busy
check); its fast worker answers ``estop`` (it must not wait behind anything); a runner thread
runs one recognition at a time and holds its query until the final reply.

One recognition at a time: while one runs, a new request is refused with a `BusyError`
reply, unless ``service.max_queued`` > 0, in which case up to that many wait in a FIFO queue
(a waiting request whose caller's ``timeout`` has passed is dropped with an error).

Emergency stop: trips the interlock of the running recognition (every further hand/arm
command of it is refused, so it ends at once with a `RecognitionAbortedError` reply), drops
the queued requests, stops the arm and the hand (``arm/stop``, ``hand/stop``: served beside a
running motion or grasp, so both halt within a control step) and opens the hand. The devices
stay stopped until the next recognition starts, which clears the stop: a new request is the
operator's explicit go-ahead.

Where the object is: on a simulated robot the ``sim/place`` node puts it on the table (standing
on the workcell's table at its object x, y); on a real one the workcell configures it. Either
way the table plane in the object frame comes from the workcell, and contacts on it are
dropped.
"""

from __future__ import annotations

import dataclasses
import logging
import secrets
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import zenoh

from activetouch import paths
from activetouch.config import Config, profile_settings
from activetouch.daemon.client import BusyError, RecognitionAbortedError
from activetouch.daemon.interlock import GuardedHand, GuardedWrist, Interlock
from activetouch.daemon.jobs import EXPIRY_SWEEP_S, Job, Running, TimedPolicy
from activetouch.daemon.links import ServiceLinks, zenoh_links
from activetouch.daemon.redaction import redact, set_redactions
from activetouch.daemon.serving import JSON, Op, ServedNode, query_budget
from activetouch.errors import (
    ActiveTouchError,
    DataError,
    MessageError,
    NodeUnavailableError,
)
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.motion.base import workcell_placement
from activetouch.planning.policies import PlanningState, make_policy
from activetouch.recordings.format import placement_pose
from activetouch.recordings.writer import close_recorder, open_recorder
from activetouch.session.local import load_trained
from activetouch.session.loop import Progress as SessionProgress
from activetouch.session.loop import RecognitionSession, belief_table_of, policy_for
from activetouch.transport.keys import ARM_NODE, DAEMON_NODE, HAND_NODE, SIM_NODE, Keys
from activetouch.transport.messages import (
    MAX_PAYLOAD,
    CancelRequest,
    CancelResult,
    Empty,
    EStopRequest,
    EStopResult,
    Message,
    NodeHealth,
    PoseMsg,
    Progress,
    RecognizeRequest,
    RecognizeResult,
    Reply,
    SessionSummary,
    Status,
    decode,
    encode,
)
from activetouch.transport.zenoh_session import undeclare_quietly

log = logging.getLogger("activetouch.daemon")


def _probability(p: float) -> float:
    return min(1.0, max(0.0, float(p)))


def _parse(query: zenoh.Query, request_type: type[Message]) -> Any:
    payload = query.payload
    data = payload.to_bytes() if payload is not None else b""
    if not data and request_type in (Empty, CancelRequest, EStopRequest):
        return request_type()
    return decode(data, request_type)


def _failure(exc: BaseException) -> Reply:
    """The error reply, with the data directory's paths redacted."""
    env = Reply.failure(exc)
    return msgspec.structs.replace(env, error=redact(env.error) or "")


def _reply_error(query: zenoh.Query, exc: BaseException) -> None:
    try:
        query.reply_err(encode(_failure(exc)), encoding=JSON)
    except Exception:
        log.debug("cannot send an error reply", exc_info=True)


class DaemonNode(ServedNode):
    """The daemon's queryables on the serving base: ``status``, ``cancel`` and the admission
    of ``recognize`` on the main worker, ``estop`` on the fast one; between queries a sweep
    answers queued recognitions whose caller gave up. Its liveliness token is declared by
    the service once it has waited for the device nodes."""

    node_name = DAEMON_NODE
    idle_period = EXPIRY_SWEEP_S

    def __init__(self, service: RecognitionService, session: zenoh.Session | None) -> None:
        super().__init__(
            session, service.robot, state_key=service.keys.status, state_hz=0.0, lock=None
        )
        self.service = service
        k = self.keys
        self._ops = {
            "recognize": Op(k.recognize, RecognizeRequest, service._admit, owns_query=True),
            "status": Op(k.status, Empty, lambda _r: service.status()),
            "cancel": Op(k.cancel, CancelRequest, service._cancel),
            "estop": Op(k.estop, EStopRequest, lambda r: service.estop(r.reason), fast=True),
        }

    def _on_idle(self) -> None:
        self.service._expire_queued()

    def _failure(self, exc: BaseException) -> Reply:
        return _failure(exc)

    def _on_close(self) -> None:
        self.service._stop_recognitions()


class RecognitionService:
    """Serves ``recognize``, ``cancel``, ``status``, ``estop``; publishes ``progress``.

    Over Zenoh, `start` declares the daemon's queryables on `session`; without a session
    (tests), hand queries to `submit` — any object with ``payload``, ``parameters``,
    ``reply``, ``reply_err`` and ``with`` support does."""

    def __init__(
        self,
        session: zenoh.Session | None,
        robot: str,
        mode: str,
        cfg: Config,
        model_dir: Path,
        data: Path | None = None,
        links: ServiceLinks | None = None,
    ) -> None:

        set_redactions(data)
        self.data, self.model_dir = data, model_dir  # recordings go to <data>/recordings/
        self.keys = Keys(robot)
        self.robot, self.mode, self.cfg = robot, mode, cfg
        self.svc = cfg.service
        self._session = session
        self._t0 = time.monotonic()
        self.model: Any = None
        self.model_desc: str | None = None
        self.model_error: str | None = None
        try:
            self.model = load_trained(model_dir)
            self.model_desc = (
                f"{model_dir.resolve()} ({', '.join(self.model.class_names)}; "
                f"dataset {self.model.dataset_checksum[:12]})"
            )
            log.info(
                "model loaded", extra={"model": str(model_dir), "classes": self.model.n_classes}
            )
            self._warm_up()
        except ActiveTouchError as e:
            self.model_error = str(e)
            log.warning("no model", extra={"model": str(model_dir), "error": str(e)})
        self._cv = threading.Condition()
        self._pending: deque[Job] = deque()
        self._running: Running | None = None
        self._closing = False
        self._closed = False
        self._close_reason = ""
        # Told what each recognition does (the ROS 2 face): objects with any of
        # on_start(session_id, placement), on_grasp(session_id, grasp) and
        # on_result(session_id, result | None, error | None), called on the runner thread;
        # they must only hand the news over, never block.
        self.observers: list[Any] = []
        if links is None:
            if session is None:
                raise ValueError("a RecognitionService needs a Zenoh session or its links")
            links = zenoh_links(session, robot, mode, self.svc)
        self.links = links
        self.hand, self.arm = links.hand, links.arm
        self._runner = threading.Thread(
            target=self._runner_loop, name="activetouch-runner", daemon=True
        )
        self.node = DaemonNode(self, session)

    def _warm_up(self) -> None:
        """Plan once now, so the first request does not wait for numba to load (or compile)
        the tree search, nor for the grasp-likelihood table (cached on the model)."""

        t = time.perf_counter()
        try:
            belief = belief_table_of(self.model, self.cfg.recognition)
            policy = make_policy(
                "tree",
                dataclasses.replace(self.cfg.planner, horizon=1, simulations=2),
                self.model.observation,
                self.model.classifier.kernel(),
                belief,
            )
            state = PlanningState(
                pose=0,
                visited=np.array([0], dtype=np.int64),
                counts=np.zeros(self.model.spec.n_bins),
                cells=np.zeros(0, dtype=np.int64),
                log_belief=None if belief is None else np.zeros(self.model.n_classes),
            )
            policy.plan(state, np.random.default_rng(0))
        except Exception as e:  # best effort: the first request then pays instead
            log.debug("planner warm-up failed", extra={"error": str(e)})
            return
        log.info("planner warmed up", extra={"s": round(time.perf_counter() - t, 3)})

    @property
    def node_names(self) -> tuple[str, ...]:
        return (HAND_NODE, ARM_NODE, SIM_NODE) if self.mode == "sim" else (HAND_NODE, ARM_NODE)

    def start(self, wait_nodes: float) -> None:
        """Serve; wait up to `wait_nodes` s for the nodes; then declare the daemon's token."""
        try:
            self._runner.start()
            self.node.start(declare_token=False)
            if self._session is None:
                return  # in memory: queries come through `submit`
            deadline = time.monotonic() + wait_nodes
            for node in (self.hand, self.arm):
                wait = getattr(node, "wait_alive", None)
                if wait is None:
                    continue
                try:
                    wait(max(0.0, deadline - time.monotonic()))
                except NodeUnavailableError as e:
                    log.warning("node not there yet", extra={"node": node.node, "error": str(e)})
            # Last: a client that sees the token can use every queryable.
            self.node.declare_token()
        except Exception:
            self.close()
            raise
        log.info(
            "recognition service ready",
            extra={"robot": self.robot, "mode": self.mode, "model": self.model is not None},
        )

    def healthy(self) -> bool:
        return self._runner.is_alive() and self.node.workers_alive()

    def submit(self, key: str, query: Any) -> None:
        """Take a query on one of the daemon's keys (the e-stop on its own thread)."""
        self.node.submit(key, query)

    def _notify(self, event: str, *args: Any) -> None:
        for obs in list(self.observers):
            fn = getattr(obs, event, None)
            if fn is None:
                continue
            try:
                fn(*args)
            except Exception:
                log.warning("an observer failed", extra={"event": event}, exc_info=True)

    def _expire_queued(self) -> None:
        """Answer queued requests whose caller's timeout has passed now, not when they reach
        the front (their caller has given up; the error says why)."""
        now = time.monotonic()
        with self._cv:
            expired = [
                j for j in self._pending if j.budget is not None and now - j.arrived > j.budget
            ]
            for job in expired:
                self._pending.remove(job)
        for job in expired:
            log.info("queued recognition expired", extra={"session": job.session_id})
            with job.query as q:
                _reply_error(
                    q,
                    NodeUnavailableError(
                        f"recognition {job.session_id} waited {now - job.arrived:.1f} s in the "
                        f"queue, longer than its caller's timeout ({job.budget:g} s); not started"
                    ),
                )

    def _check_request(self, req: RecognizeRequest) -> None:
        if self.model is None:
            raise DataError(f"no model: run `activetouch train` ({self.model_error})")
        if self.mode == "sim" and req.object is None:
            raise MessageError(
                "invalid RecognizeRequest: field `object`: the twin needs the object to place "
                "(this daemon runs in simulation)",
                field="object",
            )
        if self.mode == "hardware" and req.object is not None:
            raise MessageError(
                "invalid RecognizeRequest: field `object`: this daemon drives a real robot and "
                "cannot place objects; leave it null",
                field="object",
            )
        self._require_devices()

    def _busy_text(self) -> str:
        cur = self._running
        queued = len(self._pending)
        if cur is not None:
            r = cur.job.request
            what = (
                f"recognition {cur.job.session_id} ({r.object or 'object on the table'}, "
                f"{r.policy}, grasp {cur.move}/{r.max_moves}) is running"
            )
        else:
            what = "a recognition is starting"
        if self.svc.max_queued:
            what += f" and {queued} are queued (service.max_queued = {self.svc.max_queued})"
        return (
            f"busy: {what}; the daemon runs one recognition at a time — try again when it "
            "finishes, or cancel it (`activetouch cancel`)"
        )

    def _admit(self, query: zenoh.Query, arrived: float) -> None:
        try:
            req = _parse(query, RecognizeRequest)
            self._check_request(req)
            sid = req.session_id or secrets.token_hex(6)
            seed = req.seed if req.seed is not None else secrets.randbelow(2**31)
            with self._cv:
                if self._closing:
                    raise NodeUnavailableError("the recognition daemon is shutting down")
                ids = {j.session_id for j in self._pending}
                if self._running is not None:
                    ids.add(self._running.job.session_id)
                if sid in ids:
                    raise MessageError(
                        f"invalid RecognizeRequest: field `session_id`: {sid!r} is in use",
                        field="session_id",
                    )
                busy = self._running is not None or bool(self._pending)
                if busy and len(self._pending) >= self.svc.max_queued:
                    raise BusyError(self._busy_text())
                job = Job(query, req, sid, seed, arrived, query_budget(query))
                self._pending.append(job)
                self._cv.notify_all()
        except Exception as e:
            log.info(
                "recognize refused",
                extra={"error_type": type(e).__name__, "error": str(e)},
            )
            with query:
                _reply_error(query, e)
            return
        log.info(
            "recognize accepted",
            extra={
                "session": sid,
                "object": req.object,
                "policy": req.policy,
                "max_moves": req.max_moves,
                "seed": seed,
                "queued": len(self._pending) - (0 if busy else 1),
            },
        )

    def _cancel(self, req: CancelRequest) -> CancelResult:
        dropped: Job | None = None
        with self._cv:
            cur = self._running
            if cur is not None and req.session_id in (None, cur.job.session_id):
                cur.cancel.set()
                if cur.policy is not None:
                    cur.policy.interrupt()
                sid = cur.job.session_id
            else:
                for job in self._pending:
                    if req.session_id in (None, job.session_id):
                        dropped = job
                        break
                if dropped is None:
                    return CancelResult(cancelled=False, session_id=req.session_id)
                self._pending.remove(dropped)
                sid = dropped.session_id
        if dropped is not None:
            with dropped.query as q:
                _reply_error(
                    q, RecognitionAbortedError(f"recognition {sid} cancelled before it started")
                )
        log.info("cancel", extra={"session": sid, "queued": dropped is not None})
        return CancelResult(cancelled=True, session_id=sid)

    def _node_health(self, name: str, seen: dict[str, bool]) -> NodeHealth:
        """One node as `status` shows it: a device node connected, waiting or lost (with why
        and since when, from its own health, or from its token when its process is gone)."""
        alive = self.links.alive
        since = (alive.since(name) if alive is not None else None) or 0.0
        health = self.links.health(name) if self.links.health is not None else None
        device = health.device if health is not None else ""
        if seen.get(name):
            changed = time.time() - since
            if health is not None and health.state == "connected":
                changed = health.since
            return NodeHealth(
                alive=True,
                detail=f"up for {since:.1f} s",
                state="connected" if name in (HAND_NODE, ARM_NODE) else "",
                since=changed,
                device=device,
            )
        if health is not None and health.state != "connected":
            age = max(0.0, time.time() - health.since)
            what = "not connected yet" if health.state == "waiting" else "lost"
            return NodeHealth(
                alive=False,
                detail=f"{what} for {age:.0f} s: {health.detail}"[:1000],
                state=health.state,
                since=health.since,
                device=device,
            )
        if name not in seen:
            return NodeHealth(
                alive=False,
                detail=f"no {name} node heard yet (never seen)",
                state="waiting",
                since=time.time() - (time.monotonic() - self._t0),
                device=device,
            )
        return NodeHealth(
            alive=False,
            detail=f"the {name} node went away {since:.1f} s ago (its process stopped?)",
            state="lost",
            since=time.time() - since,
            device=device,
        )

    def _require_devices(self) -> None:
        """Refuse at once, with the reason, while a node the recognition needs is missing."""
        alive = self.links.alive
        if alive is None:
            return
        seen = alive.snapshot()
        for name in self.node_names:
            if seen.get(name):
                continue
            confirm = self.links.confirm_alive
            if confirm is not None and confirm(name):
                continue  # its token just appeared
            h = self._node_health(name, seen)
            raise NodeUnavailableError(
                f"cannot recognise now: the {name} is {h.state or 'missing'} ({h.detail}); "
                "nothing was moved. `activetouch status` shows the devices"
            )

    def status(self) -> Status:
        alive = self.links.alive
        seen = alive.snapshot() if alive is not None else dict.fromkeys(self.node_names, True)
        nodes: dict[str, NodeHealth] = {DAEMON_NODE: NodeHealth(alive=True, detail="serving")}
        for name in self.node_names:
            nodes[name] = self._node_health(name, seen)
        with self._cv:
            cur = self._running
            queued = len(self._pending)
        summary = None
        if cur is not None:
            r = cur.job.request
            summary = SessionSummary(
                session_id=cur.job.session_id,
                policy=r.policy,
                max_moves=r.max_moves,
                move=cur.move,
                object=r.object,
                started=cur.started,
            )
        return Status(
            robot=self.robot,
            nodes=nodes,
            model_loaded=self.model is not None,
            model=redact(self.model_desc),
            session=summary,
            uptime_s=time.monotonic() - self._t0,
            mode=self.mode,
            model_error=redact(self.model_error),
            queued=queued,
        )

    # -- runner thread: one recognition at a time
    def _runner_loop(self) -> None:
        while True:
            with self._cv:
                self._cv.wait_for(lambda: bool(self._pending) or self._closing)
                if self._closing:
                    return
                job = self._pending.popleft()
                running = Running(job, threading.Event(), Interlock(), time.time())
                self._running = running
            try:
                self._serve(running)
            finally:
                self._finish(running)

    def _serve(self, running: Running) -> None:
        job = running.job
        with job.query as query:
            result: RecognizeResult | None = None
            error: Exception | None = None
            try:
                waited = time.monotonic() - job.arrived
                if job.budget is not None and waited > job.budget:
                    raise NodeUnavailableError(
                        f"recognition {job.session_id} waited {waited:.1f} s in the queue, "
                        f"longer than its caller's timeout ({job.budget:g} s); not started"
                    )
                watch = self._watch_requester(running)
                try:
                    result = self._recognize(running)
                finally:
                    undeclare_quietly(watch)
            except Exception as e:
                error = e
            # Done before the caller hears of it: a status it asks next shows no session.
            self._finish(running)
            self._notify("on_result", job.session_id, result, error)
            if result is not None:
                try:
                    query.reply(self.keys.recognize, encode(Reply.success(result)), encoding=JSON)
                except Exception:
                    log.warning("cannot send the result", exc_info=True)
                log.info(
                    "recognition done",
                    extra={
                        "session": job.session_id,
                        "object": result.object,
                        "label": result.label,
                        "probability": round(result.probability, 4),
                        "grasps": result.moves,
                        "stop_reason": result.stop_reason,
                        "elapsed_s": round(result.elapsed_s, 4),
                        "place_s": round(running.place_s, 4),
                        "session_s": round(running.session_s, 4),
                        "planning_s": round(result.planning_s, 4),
                    },
                )
                return
            assert error is not None
            if isinstance(error, ActiveTouchError | ValueError):
                log.warning(
                    "recognition failed",
                    extra={
                        "session": job.session_id,
                        "error_type": type(error).__name__,
                        "error": str(error),
                    },
                )
            else:
                log.error(
                    "recognition crashed",
                    exc_info=error,
                    extra={"session": job.session_id},
                )
            _reply_error(query, error)

    def _watch_requester(self, running: Running) -> Any:
        """Cancel `running` when its requester goes away (its client closed or was killed):
        the client holds the liveliness token ``requests/<session_id>`` while it waits. A
        request without one (a plain Zenoh client, or ``recognize --detach``) runs detached.
        Returns the handle to undeclare, or None."""
        sid = running.job.session_id
        watch = self.links.watch_requester

        def gone() -> None:
            log.warning("requester gone: cancelling", extra={"session": sid})
            running.interlock.trip("its requester is gone")
            running.cancel.set()
            if running.policy is not None:
                running.policy.interrupt()

        handle = watch(sid, gone) if watch is not None else None
        if handle is None:
            log.info(
                "recognition runs detached (its requester holds no token)", extra={"session": sid}
            )
        return handle

    def _finish(self, running: Running) -> None:
        with self._cv:
            if self._running is running:
                self._running = None
                self._cv.notify_all()

    def _recognize(self, running: Running) -> RecognizeResult:
        job, req, cfg = running.job, running.job.request, self.cfg
        model = self.model
        if model is None:  # unloaded since admission (cannot happen today; keep the text)
            raise DataError(f"no model: run `activetouch train` ({self.model_error})")
        wc = cfg.workcell
        placement = workcell_placement(wc)
        extents: tuple[float, float, float] | None = None
        if self.links.place is not None:
            running.interlock.check("placing the object")
            assert req.object is not None
            t_place = time.perf_counter()
            placed = self.links.place(req.object, job.seed)
            running.place_s = time.perf_counter() - t_place
            extents = tuple(float(e) for e in placed.extents)
            # A simulated robot stands the object on the workcell's table.
            placement = dataclasses.replace(
                placement,
                xyz=np.array(
                    [wc.object_xyz[0], wc.object_xyz[1], wc.table_top_z + placed.extents[2] / 2]
                ),
            )
        support_z = placement.support_z(wc.table_top_z)
        self._notify("on_start", running.job.session_id, placement)
        recorder = self._open_recorder(running, placement)
        try:
            result = self._run_session(running, model, support_z, recorder, placement, extents)
        except BaseException as e:
            close_recorder(recorder, self.data or Path("."), cfg, error=e)
            raise
        close_recorder(recorder, self.data or Path("."), cfg, result=msgspec.to_builtins(result))
        return result

    def _open_recorder(self, running: Running, placement: Any) -> Any:
        """The recording of this recognition (None: `recording.enabled` off, the request's
        `record: false`, or no data directory)."""

        job, req = running.job, running.job.request
        if self.data is None or req.record is False:
            return None
        try:
            return open_recorder(
                self.data,
                self.cfg,
                session_id=job.session_id,
                source=f"daemon {self.robot} ({self.mode})",
                policy=req.policy,
                max_moves=req.max_moves,
                seed=job.seed,
                object_name=req.object,
                model=self.model,
                model_dir=self.model_dir,
                placement=placement_pose(placement.xyz, placement.yaw_rad),
                extra={
                    "horizon": req.horizon or self.cfg.planner.horizon,
                    "simulations": req.simulations or self.cfg.planner.simulations,
                },
            )
        except Exception as e:  # a recording must never stop a recognition
            log.warning("cannot record", extra={"session": job.session_id, "error": str(e)})
            return None

    def _run_session(
        self,
        running: Running,
        model: Any,
        support_z: float,
        recorder: Any,
        placement: Any,
        extents: tuple[float, float, float] | None,
    ) -> RecognizeResult:

        job, req, cfg = running.job, running.job.request, self.cfg
        sid = job.session_id
        # A new recognition is the operator's go-ahead after a stop (see the module).
        running.interlock.check("starting")
        self.hand.clear_stop()
        self.arm.clear_stop()
        planner_cfg = dataclasses.replace(
            cfg.planner,
            horizon=req.horizon or cfg.planner.horizon,
            simulations=req.simulations or cfg.planner.simulations,
        )
        policy = TimedPolicy(
            policy_for(model, req.policy, planner_cfg, cfg.recognition),
            self.svc.max_plan_s,
        )
        running.policy = policy
        session_cfg = dataclasses.replace(cfg.session, max_moves=req.max_moves)
        rng = np.random.default_rng(job.seed)
        object_pose = placement.pose
        object_msg = PoseMsg(
            xyz=tuple(object_pose.xyz.tolist()), quat=tuple(object_pose.quat.tolist())
        )

        def on_progress(ev: SessionProgress) -> None:
            running.move = ev.move
            pose = np.asarray(ev.pose, dtype=np.float64)
            contacts = (
                []
                if ev.contacts is None
                else [tuple(c) for c in np.asarray(ev.contacts, dtype=np.float64).tolist()]
            )
            msg = Progress(
                session_id=sid,
                move=ev.move,
                pose=PoseMsg(xyz=tuple(pose[:3].tolist()), quat=tuple(pose[3:].tolist())),
                n_contacts=ev.n_contacts,
                top3=[(label, _probability(p)) for label, p in ev.top[:3]],
                skipped=ev.skipped,
                planning_s=policy.take(),
                stamp=time.time(),
                pose_id=ev.pose_id,
                elapsed_s=max(0.0, ev.elapsed_s),
                motion_s=max(0.0, ev.motion_s),
                contacts=contacts,
                belief=[(label, _probability(p)) for label, p in ev.belief],
                object_pose=object_msg,
                object=req.object,
                extents=extents,
            )
            publish = self.links.publish
            if publish is not None:
                try:
                    data = encode(msg)
                    if len(data) > MAX_PAYLOAD:  # a huge model's belief: receivers refuse it
                        data = encode(msgspec.structs.replace(msg, belief=[]))
                    publish(data)
                except Exception as e:  # a lost progress sample must not end the recognition
                    log.warning("publishing progress failed", extra={"error": str(e)})

        session = RecognitionSession(
            GuardedHand(
                self.hand, running.interlock, lambda grasp: self._notify("on_grasp", sid, grasp)
            ),
            GuardedWrist(self.arm, running.interlock),
            model,
            policy,
            session_cfg,
            rng,
            on_progress,
            running.cancel,
            support_z=support_z,
            recognition=self.cfg.recognition,
            recorder=recorder,
            library=ObjectLibrary(paths.objects_dir(self.data))
            if self.cfg.recognition.belief == "pose"
            else None,
        )
        t_run = time.perf_counter()
        try:
            res = session.run()
            running.session_s = time.perf_counter() - t_run
        except Exception as e:
            if running.interlock.reason is not None:
                raise RecognitionAbortedError(
                    f"recognition {sid} aborted after {running.move} grasps: "
                    f"{running.interlock.reason}"
                ) from e
            raise
        if running.interlock.reason is not None:
            raise RecognitionAbortedError(
                f"recognition {sid} aborted after {running.move} grasps: {running.interlock.reason}"
            )
        return RecognizeResult(
            session_id=sid,
            label=res.label,
            probability=_probability(res.probability),
            labels=list(res.labels),
            moves=len(res.labels),
            skipped=res.skipped,
            planning_s=max(0.0, res.planning_s),
            elapsed_s=time.monotonic() - job.arrived,
            policy=req.policy,
            seed=job.seed,
            object=req.object,
            stop_reason=res.stop_reason,
            pose_ids=[int(p) for p in res.pose_ids],
            motion_s=max(0.0, res.motion_s),
            motion_planning_s=max(0.0, res.motion_planning_s),
            grasp_s=max(0.0, res.grasp_s),
            search_s=res.search_s,
            total_s=max(0.0, res.total_s),
            masked_sensors=list(res.masked_sensors),
            masked_reasons={str(i): w for i, w in res.masked_reasons.items()},
            pose_estimate=res.pose_estimate,
            profile=self.cfg.profile,
            settings=profile_settings(self.cfg, getattr(self.model, "config", None), req.policy),
        )

    def _stop_recognitions(self) -> None:
        """At close, once nothing new can arrive: abort the running one, join the runner."""
        cur = self._abort_all(self._close_reason or "the recognition daemon is shutting down")
        with self._cv:
            self._cv.notify_all()
        if self._runner.is_alive():
            self._runner.join(self.svc.shutdown_timeout_s)
            if self._runner.is_alive():
                log.warning(
                    "recognition still running at shutdown; leaving it",
                    extra={"session": cur.job.session_id if cur else None},
                )

    def _abort_all(self, reason: str) -> Running | None:
        """Trip the running recognition's interlock and fail every queued one."""
        with self._cv:
            cur = self._running
            dropped = list(self._pending)
            self._pending.clear()
        if cur is not None:
            cur.interlock.trip(reason)
            cur.cancel.set()
            if cur.policy is not None:
                cur.policy.interrupt()
        for job in dropped:
            with job.query as q:
                _reply_error(
                    q,
                    RecognitionAbortedError(f"recognition {job.session_id} not started: {reason}"),
                )
        return cur

    def estop(self, reason: str = "") -> EStopResult:
        """Abort the recognition, stop the arm, open the hand."""
        text = "emergency stop" + (f" ({reason})" if reason else "")
        cur = self._abort_all(text)
        log.warning(
            "emergency stop",
            extra={"reason": reason, "session": cur.job.session_id if cur else None},
        )
        errors: list[str] = []
        arm_stopped = hand_opened = False
        try:
            self.arm.estop()  # stop, and the robot's own e-stop where it has one
            arm_stopped = True
        except Exception as e:
            errors.append(f"arm stop: {e}")
        try:
            self.hand.stop()  # ends a running grasp, so the open below is not queued behind it
        except Exception as e:
            errors.append(f"hand stop: {e}")
        try:
            self.hand.open()
            hand_opened = True
        except Exception as e:
            errors.append(f"hand open: {e}")
        if errors:
            log.error("emergency stop incomplete", extra={"errors": "; ".join(errors)})
        return EStopResult(arm_stopped=arm_stopped, hand_opened=hand_opened, errors=errors)

    # -- shutdown
    def close(self, reason: str = "the recognition daemon is shutting down") -> None:
        """Stop serving, abort the running recognition, join the threads. Idempotent."""
        with self._cv:
            if self._closed:
                return
            self._closed = self._closing = True
            self._close_reason = reason
            self._cv.notify_all()
        # Token and queryables go first; then `_stop_recognitions`; then the node's workers.
        self.node.close(join_timeout=1.0)
        while self.links.closers:
            close = self.links.closers.pop()
            try:
                close()
            except Exception:
                log.debug("close failed", exc_info=True)
        log.info("recognition service closed")
