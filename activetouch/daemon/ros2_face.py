"""The daemon's ROS 2 face (``[ros2] enabled``): the recognition service as ROS 2 node
``<namespace>/activetouch`` to any ROS 2 graph running rmw_zenoh, on the daemon's own Zenoh
session (docs/api.md, "ROS 2"; the wire protocol in activetouch/transport/rmw_zenoh.py).

Services (queryables declared complete; every reply carries the rmw_zenoh attachment):

| name | type | what |
|---|---|---|
| ``~/recognize`` | activetouch_interfaces/srv/Recognize | a recognition (Zenoh ``recognize``) |
| ``~/cancel`` | std_srvs/srv/Trigger | cancel the current recognition |
| ``~/estop`` | std_srvs/srv/Trigger | the emergency stop |
| ``~/status`` | std_srvs/srv/Trigger | ``message``: the daemon's status JSON |

Every request goes to `RecognitionService.submit` as a query of the Zenoh API would, its
payload the JSON request made from the ROS one: the same admission checks, limits, queue and
replies (a refusal is a response with ``success: false`` and the error text: rmw_zenoh clients
drop error replies). Topics: ``~/progress``, ``~/result`` (every recognition's end),
``~/contacts`` (each grasp's contacts, sensor_msgs/PointCloud2 in the hand frame),
``~/tactile`` (the hand state's 38 pressures and contacts; not published for a hand with
another sensor count, e.g. the BarrettHand's 96), ``joint_states`` (the arm's) and
``/tf`` (base -> object: the placement; object -> hand: the wrist at each grasp).

Threads: Zenoh callbacks and the service's observers only enqueue; one worker thread decodes,
submits and publishes. The service's threads send the replies (through `_RosQuery`).
"""

from __future__ import annotations

import itertools
import json
import logging
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from activetouch.config import Config
from activetouch.daemon.redaction import redact
from activetouch.daemon.serving import direct
from activetouch.errors import ActiveTouchError
from activetouch.planning.motion.base import Placement, workcell_placement
from activetouch.transport import rmw_zenoh as rz
from activetouch.transport.messages import HandStateMsg, JointStateMsg, Progress, decode, encode
from activetouch.transport.ros2_interfaces import definitions
from activetouch.transport.zenoh_session import undeclare_quietly

log = logging.getLogger("activetouch.ros2")

NODE_NAME = "activetouch"
RECOGNIZE = "activetouch_interfaces/srv/Recognize"
TRIGGER = rz.TRIGGER
PROGRESS = "activetouch_interfaces/msg/Progress"
RESULT = "activetouch_interfaces/msg/RecognitionResult"
TACTILE = "activetouch_interfaces/msg/Tactile"
TACTILE_SENSORS = 38  # its fixed arrays (the ReFlex's sensors)
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
JOINT_STATE = "sensor_msgs/msg/JointState"
TF = "tf2_msgs/msg/TFMessage"

# service -> (ROS name, type); topic -> (ROS name, type, history depth)
SERVICES: dict[str, tuple[str, str]] = {
    "recognize": ("~/recognize", RECOGNIZE),
    "cancel": ("~/cancel", TRIGGER),
    "estop": ("~/estop", TRIGGER),
    "status": ("~/status", TRIGGER),
}
TOPICS: dict[str, tuple[str, str, int]] = {
    "progress": ("~/progress", PROGRESS, 10),
    "result": ("~/result", RESULT, 10),
    "contacts": ("~/contacts", POINT_CLOUD, 10),
    "tactile": ("~/tactile", TACTILE, 10),
    "joint_states": ("joint_states", JOINT_STATE, 10),
    "tf": ("/tf", TF, 100),
}
ESTOP_REASON = "ROS 2 service call"
_STOP = object()

_TYPES: rz.Ros2Types | None = None
_TYPES_LOCK = threading.Lock()


def ros2_types() -> rz.Ros2Types:
    """The typestore with activetouch_interfaces registered (made once: it takes ~0.1 s)."""
    global _TYPES
    with _TYPES_LOCK:
        if _TYPES is None:
            _TYPES = rz.Ros2Types(definitions())
        return _TYPES


@dataclass
class _Endpoint:
    name: str  # fully qualified ROS name
    type_name: str
    key: str  # Zenoh data key
    token: str  # liveliness key
    gid: bytes


class _Payload:
    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


class _RosQuery:
    """A ROS 2 request as the recognition service sees a Zenoh query: a JSON payload; its JSON
    reply (success or error) goes back to the ROS client as the service's response, with the
    client's sequence number and GID in the attachment."""

    def __init__(
        self,
        face: Ros2Face,
        service: str,
        query: zenoh.Query,
        attachment: rz.Attachment,
        fmt: str,
        payload: bytes,
    ) -> None:
        self._face, self._service, self._query = face, service, query
        self._attachment, self._fmt = attachment, fmt
        self.payload = _Payload(payload)
        self.parameters: dict[str, str] = {}
        self._done = False
        self._lock = threading.Lock()

    def reply(self, _key: Any, payload: Any, **_kw: Any) -> None:
        self._answer(payload)

    def reply_err(self, payload: Any, **_kw: Any) -> None:
        self._answer(payload)

    def _answer(self, payload: Any) -> None:
        data = payload if isinstance(payload, bytes | bytearray) else payload.to_bytes()
        envelope = json.loads(bytes(data))
        with self._lock:
            if self._done:
                return
            self._done = True
        self._face.send_response(self._service, self._query, self._attachment, self._fmt, envelope)

    def drop(self) -> None:
        try:
            self._query.drop()
        except Exception:
            log.debug("dropping a ROS 2 query failed", exc_info=True)

    def __enter__(self) -> _RosQuery:
        return self

    def __exit__(self, *exc: object) -> None:
        self.drop()


def _stamp(types: rz.Ros2Types, t: float | None = None) -> Any:
    ns = time.time_ns() if t is None or t <= 0 else int(t * 1e9)
    return types.new("builtin_interfaces/msg/Time", sec=ns // 10**9, nanosec=ns % 10**9)


def _header(types: rz.Ros2Types, frame: str, t: float | None = None) -> Any:
    return types.new("std_msgs/msg/Header", stamp=_stamp(types, t), frame_id=frame)


class Ros2Face:
    """Node ``<namespace>/activetouch`` in ROS 2 domain ``ros2.domain_id`` (see the module)."""

    def __init__(self, session: zenoh.Session, service: Any, cfg: Config) -> None:
        self.cfg, self.rcfg = cfg, cfg.ros2
        self.service = service
        self.keys = service.keys
        self._session = session
        self.types = ros2_types()
        self.node = rz.NodeInfo(
            domain_id=self.rcfg.domain_id,
            zid=str(session.zid()),
            node_id=0,
            name=NODE_NAME,
            namespace=self.rcfg.namespace or "/",
        )
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._worker = threading.Thread(target=self._run, name="activetouch-ros2", daemon=True)
        self._ids = itertools.count(1)
        self.services: dict[str, _Endpoint] = {}
        self.topics: dict[str, _Endpoint] = {}
        self._publishers: dict[str, Any] = {}
        self._seq: dict[str, itertools.count] = {}
        self._queryables: list[Any] = []
        self._subscribers: list[Any] = []
        self._tokens: list[Any] = []
        self._placements: dict[str, Placement] = {}
        self._tactile_skipped = False  # warned once: a hand state Tactile cannot carry
        self._closed = False
        for short, (name, type_name) in SERVICES.items():
            self.services[short] = self._endpoint(rz.SERVICE, name, type_name)
        for short, (name, type_name, depth) in TOPICS.items():
            self.topics[short] = self._endpoint(rz.PUBLISHER, name, type_name, depth)

    def _endpoint(self, kind: str, name: str, type_name: str, depth: int = 10) -> _Endpoint:
        fq = self.node.resolve(name)
        h = self.types.hash(type_name)
        token = self.node.entity_token(
            next(self._ids), kind, fq, type_name, h, rz.qos_key(depth=depth)
        )
        key = rz.data_key(self.node.domain_id, fq, type_name, h)
        return _Endpoint(fq, type_name, key, token, rz.gid_of(token))

    # -- lifecycle
    def start(self) -> None:
        """Declare the publishers, queryables and subscriptions, then the graph's tokens."""
        s = self._session
        try:
            self._worker.start()
            for short, ep in self.topics.items():
                self._publishers[short] = s.declare_publisher(ep.key)
                self._seq[short] = itertools.count(1)
            for short, ep in self.services.items():
                self._queryables.append(
                    s.declare_queryable(ep.key, direct(self._enqueuer(short)), complete=True)
                )
            for key, kind in (
                (self.keys.progress, "progress"),
                (self.keys.hand_state, "tactile"),
                (self.keys.arm_joint_states, "joint_states"),
            ):
                self._subscribers.append(s.declare_subscriber(key, direct(self._sampler(kind))))
            self.service.observers.append(self)
            # Last: a ROS client that sees a service's token can call it.
            self._tokens.append(s.liveliness().declare_token(self.node.node_token()))
            for ep in (*self.topics.values(), *self.services.values()):
                self._tokens.append(s.liveliness().declare_token(ep.token))
        except Exception:
            self.close()
            raise
        log.info(
            "ROS 2 face ready",
            extra={
                "node": self.node.fqn,
                "domain_id": self.node.domain_id,
                "attachment": self.rcfg.attachment,
            },
        )

    def close(self) -> None:
        """Tokens first (the graph forgets the node), then everything else. Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self in self.service.observers:
            self.service.observers.remove(self)
        undeclare_quietly(*self._tokens, *self._queryables, *self._subscribers)
        self._tokens.clear()
        self._queryables.clear()
        self._subscribers.clear()
        self._queue.put(_STOP)
        if self._worker.is_alive() and self._worker is not threading.current_thread():
            self._worker.join(2.0)
        undeclare_quietly(*self._publishers.values())
        self._publishers.clear()
        log.info("ROS 2 face closed")

    # -- Zenoh callbacks and observers: hand over only
    def _enqueuer(self, service: str) -> Any:
        def on_query(query: zenoh.Query) -> None:
            self._queue.put(("query", service, query))

        return on_query

    def _sampler(self, kind: str) -> Any:
        def on_sample(sample: zenoh.Sample) -> None:
            self._queue.put(("sample", kind, sample.payload.to_bytes()))

        return on_sample

    def on_start(self, session_id: str, placement: Placement) -> None:
        self._queue.put(("start", session_id, placement))

    def on_grasp(self, session_id: str, grasp: Any) -> None:
        self._queue.put(("grasp", session_id, grasp))

    def on_result(self, session_id: str, result: Any, error: BaseException | None) -> None:
        self._queue.put(("result", session_id, (result, error)))

    # -- the worker
    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            what, name, value = item
            try:
                if what == "query":
                    self._on_query(name, value)
                elif what == "sample":
                    self._on_sample(name, value)
                elif what == "start":
                    self._placements = {name: value}  # only the current recognition's
                elif what == "grasp":
                    self._publish("contacts", self._cloud(value))
                elif what == "result":
                    self._publish("result", self._result_msg(name, *value))
            except Exception:
                log.warning("ROS 2 face: handling %s failed", what, exc_info=True)

    def _on_query(self, service: str, query: zenoh.Query) -> None:
        raw = query.attachment
        if raw is None:
            log.warning("ROS 2 request without an attachment dropped", extra={"service": service})
            query.drop()
            return
        try:
            attachment, fmt = rz.decode_attachment(raw.to_bytes())
        except ActiveTouchError as e:
            log.warning("ROS 2 request dropped", extra={"service": service, "error": str(e)[:300]})
            query.drop()
            return
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            request = self._request_json(service, payload)
        except Exception as e:
            env = {"ok": False, "error": str(e)[:1000], "error_type": type(e).__name__}
            try:
                self.send_response(service, query, attachment, fmt, env)
            finally:
                query.drop()
            return
        key = getattr(self.keys, service)
        self.service.submit(key, _RosQuery(self, service, query, attachment, fmt, request))

    def _request_json(self, service: str, payload: bytes) -> bytes:
        """The Zenoh API's JSON request for a ROS request (validated by the service)."""
        if service != "recognize":
            if payload:  # Trigger's request has no fields: its bytes only need to be CDR
                self.types.deserialize(payload, f"{TRIGGER}_Request")
            if service == "estop":
                return json.dumps({"v": 1, "reason": ESTOP_REASON}).encode()
            return b""
        req = self.types.deserialize(payload, f"{RECOGNIZE}_Request")
        cfg = self.cfg
        return json.dumps(
            {
                "v": 1,
                "policy": req.policy or cfg.planner.policy,
                "max_moves": req.max_moves or cfg.session.max_moves,
                "seed": None if req.seed == -1 else req.seed,
                "object": req.object or None,
                "horizon": req.horizon or None,
                "simulations": req.simulations or None,
                "session_id": req.session_id or None,
            }
        ).encode()

    def send_response(
        self,
        service: str,
        query: zenoh.Query,
        attachment: rz.Attachment,
        fmt: str,
        envelope: dict[str, Any],
    ) -> None:
        """Answer `query` with the ROS response for the service's JSON reply `envelope`."""
        ep = self.services[service]
        ok = bool(envelope.get("ok"))
        result = envelope.get("result")
        error = envelope.get("error") or ""
        if error and envelope.get("error_type"):
            error = f"{envelope['error_type']}: {error}"
        t = self.types
        if service == "recognize":
            msg = t.new(
                f"{RECOGNIZE}_Response",
                success=ok,
                message="" if ok else error,
                result=self._result_fields(result if ok else None, None if ok else envelope),
            )
            type_name = f"{RECOGNIZE}_Response"
        else:
            success = ok
            if ok and service == "estop":
                success = bool(result and result.get("arm_stopped") and result.get("hand_opened"))
            elif ok and service == "cancel":
                success = bool(result and result.get("cancelled"))
            text = json.dumps(result, separators=(",", ":")) if ok else error
            msg = t.new(f"{TRIGGER}_Response", success=success, message=text)
            type_name = f"{TRIGGER}_Response"
        reply = rz.Attachment(attachment.sequence_number, rz.now_ns(), attachment.gid)
        query.reply(ep.key, t.serialize(msg, type_name), attachment=reply.encode(fmt))

    # -- publications
    def _publish(self, topic: str, msg: Any) -> None:
        pub = self._publishers.get(topic)
        if pub is None or msg is None:
            return
        ep = self.topics[topic]
        att = rz.Attachment(next(self._seq[topic]), rz.now_ns(), ep.gid)
        pub.put(
            self.types.serialize(msg, ep.type_name), attachment=att.encode(self.rcfg.attachment)
        )

    def _on_sample(self, kind: str, data: bytes) -> None:
        t = self.types
        if kind == "progress":
            p = decode(data, Progress)
            self._publish("progress", self._progress_msg(p))
            if p.pose is not None:
                self._publish("tf", self._tf_msg(p))
        elif kind == "tactile":
            h = decode(data, HandStateMsg)
            if len(h.pressures) != TACTILE_SENSORS:
                if not self._tactile_skipped:
                    self._tactile_skipped = True
                    log.warning(
                        "ROS 2 face: ~/tactile not published: the hand has %d sensors, "
                        "activetouch_interfaces/msg/Tactile carries %d",
                        len(h.pressures),
                        TACTILE_SENSORS,
                    )
                return
            self._publish(
                "tactile",
                t.new(
                    TACTILE,
                    header=_header(t, self.rcfg.hand_frame, h.wall_stamp or None),
                    pressures=np.asarray(h.pressures, dtype=np.float64),
                    contact=np.asarray(h.contact, dtype=np.bool_),
                    finger_angles=np.asarray(h.finger_angles, dtype=np.float64),
                    preshape=float(h.preshape),
                ),
            )
        elif kind == "joint_states":
            j = decode(data, JointStateMsg)
            self._publish(
                "joint_states",
                t.new(
                    JOINT_STATE,
                    header=_header(t, ""),
                    name=list(j.names),
                    position=np.asarray(j.position, dtype=np.float64),
                    velocity=np.asarray(j.velocity, dtype=np.float64),
                    effort=np.zeros(0, dtype=np.float64),
                ),
            )

    def _pose(self, xyz: Any, quat: Any) -> Any:
        t = self.types
        return t.new(
            "geometry_msgs/msg/Pose",
            position=t.new("geometry_msgs/msg/Point", x=xyz[0], y=xyz[1], z=xyz[2]),
            orientation=t.new(
                "geometry_msgs/msg/Quaternion", x=quat[0], y=quat[1], z=quat[2], w=quat[3]
            ),
        )

    def _progress_msg(self, p: Progress) -> Any:
        t = self.types
        pose = p.pose
        return t.new(
            PROGRESS,
            header=_header(t, self.rcfg.object_frame, p.stamp),
            session_id=p.session_id,
            move=p.move,
            has_pose=pose is not None,
            pose=self._pose(pose.xyz, pose.quat) if pose else self._pose((0, 0, 0), (0, 0, 0, 1)),
            pose_id=-1 if p.pose_id is None else p.pose_id,
            n_contacts=p.n_contacts,
            top_labels=[label for label, _ in p.top3],
            top_probabilities=np.asarray([pr for _, pr in p.top3], dtype=np.float64),
            skipped=p.skipped,
            planning_s=p.planning_s,
            elapsed_s=p.elapsed_s,
            motion_s=p.motion_s,
        )

    def _transform(self, parent: str, child: str, xyz: Any, quat: Any, stamp: float) -> Any:
        t = self.types
        return t.new(
            "geometry_msgs/msg/TransformStamped",
            header=_header(t, parent, stamp),
            child_frame_id=child,
            transform=t.new(
                "geometry_msgs/msg/Transform",
                translation=t.new("geometry_msgs/msg/Vector3", x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=t.new(
                    "geometry_msgs/msg/Quaternion", x=quat[0], y=quat[1], z=quat[2], w=quat[3]
                ),
            ),
        )

    def _tf_msg(self, p: Progress) -> Any:
        r = self.rcfg
        placement = self._placements.get(p.session_id) or workcell_placement(self.cfg.workcell)
        q = placement.rotation.as_quat()
        assert p.pose is not None
        return self.types.new(
            TF,
            transforms=[
                self._transform(
                    r.base_frame, r.object_frame, placement.xyz.tolist(), q.tolist(), p.stamp
                ),
                self._transform(r.object_frame, r.hand_frame, p.pose.xyz, p.pose.quat, p.stamp),
            ],
        )

    def _cloud(self, grasp: Any) -> Any:
        t = self.types
        xyz = np.asarray(grasp.xyz, dtype=np.float32).reshape(-1, 3)
        pts = np.zeros((len(xyz), 4), dtype="<f4")
        pts[:, :3] = xyz
        pts[:, 3] = np.asarray(grasp.pressures, dtype=np.float32)
        fields = [
            t.new("sensor_msgs/msg/PointField", name=n, offset=4 * i, datatype=7, count=1)
            for i, n in enumerate(("x", "y", "z", "pressure"))
        ]
        return t.new(
            POINT_CLOUD,
            header=_header(t, self.rcfg.hand_frame),
            height=1,
            width=len(pts),
            fields=fields,
            is_bigendian=False,
            point_step=16,
            row_step=16 * len(pts),
            data=np.frombuffer(pts.tobytes(), dtype=np.uint8),
            is_dense=True,
        )

    def _result_fields(self, r: dict[str, Any] | None, env: dict[str, Any] | None) -> Any:
        """A RecognitionResult message from a RecognizeResult (JSON dict) or a failure."""
        t = self.types
        r = r or {}
        env = env or {}

        def f(name: str) -> float:
            return float(r.get(name) or 0.0)

        seed = r.get("seed")
        return t.new(
            RESULT,
            header=_header(t, self.rcfg.object_frame),
            success=not env,
            error=str(env.get("error") or ""),
            error_type=str(env.get("error_type") or ""),
            session_id=str(r.get("session_id") or env.get("session_id") or ""),
            label=str(r.get("label") or ""),
            probability=f("probability"),
            labels=[str(x) for x in r.get("labels") or []],
            moves=int(r.get("moves") or 0),
            skipped=int(r.get("skipped") or 0),
            policy=str(r.get("policy") or ""),
            seed=-1 if seed is None else int(seed),
            object=str(r.get("object") or ""),
            stop_reason=str(r.get("stop_reason") or ""),
            pose_ids=np.asarray(r.get("pose_ids") or [], dtype=np.int64),
            planning_s=f("planning_s"),
            elapsed_s=f("elapsed_s"),
            motion_s=f("motion_s"),
            motion_planning_s=f("motion_planning_s"),
            grasp_s=f("grasp_s"),
            search_s=f("search_s"),
            total_s=f("total_s"),
        )

    def _result_msg(self, session_id: str, result: Any, error: BaseException | None) -> Any:
        if result is not None:
            return self._result_fields(json.loads(encode(result)), None)
        env = {
            "error": (redact(str(error)) or "")[:1000] if error is not None else "",
            "error_type": type(error).__name__ if error is not None else "",
            "session_id": session_id,
        }
        return self._result_fields(None, env)
