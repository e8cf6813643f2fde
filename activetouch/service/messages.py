"""Every message that crosses a process boundary, as msgspec Structs (JSON on the wire).

One module, one schema version. Each message carries `v` (SCHEMA_VERSION); `decode` insists on
it at the top level and rejects any other version before looking at the rest, so an old or new
peer gets "schema version 2 is not supported" rather than a confusing field error. Nested
structs may omit `v` (it defaults to this version) but a wrong one is rejected too.

Receivers validate everything: types, lengths, ranges, cross-field consistency
(`__post_init__`), unknown fields (forbidden, to catch typos such as ``max_move``). A bad
payload becomes a `MessageError` whose text and `.field` name the offending field, e.g.
``invalid RecognizeRequest: field `max_moves`: Expected `int` >= 1``.

Value types mirror `activetouch.interfaces` (``PoseMsg`` <-> ``Pose`` ...); the ``*_to_msg`` /
``*_from_msg`` functions convert, and `to_msg` / `from_msg` dispatch on the type.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Generic, Literal, TypeVar

import msgspec
import numpy as np

from activetouch.errors import ActiveTouchError, MessageError
from activetouch.interfaces import (
    N_FINGERS,
    N_SENSORS,
    Grasp,
    HandState,
    JointState,
    JointTrajectory,
    Pose,
)

__all__ = [
    "SCHEMA_VERSION",
    "CancelRequest",
    "CancelResult",
    "EStopRequest",
    "EStopResult",
    "Empty",
    "ExecuteRequest",
    "GraspMsg",
    "HandStateMsg",
    "JointStateMsg",
    "JointTrajectoryMsg",
    "Message",
    "MessageError",
    "MoveWristRequest",
    "NodeHealth",
    "PoseMsg",
    "PreshapeRequest",
    "Progress",
    "RecognizeRequest",
    "RecognizeResult",
    "Reply",
    "SessionSummary",
    "SimPlaceRequest",
    "SimPlaceResult",
    "Status",
    "decode",
    "encode",
    "from_msg",
    "to_msg",
]

SCHEMA_VERSION = 1

T = TypeVar("T")

# Constrained scalar / array types (msgspec checks them while decoding).
Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
SensorId = Annotated[int, msgspec.Meta(ge=0, lt=N_SENSORS)]
NonNegInt = Annotated[int, msgspec.Meta(ge=0)]
PositiveInt = Annotated[int, msgspec.Meta(gt=0)]
NonNegFloat = Annotated[float, msgspec.Meta(ge=0.0)]
Probability = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Name = Annotated[str, msgspec.Meta(min_length=1, max_length=200)]
Pressures38 = Annotated[list[float], msgspec.Meta(min_length=N_SENSORS, max_length=N_SENSORS)]
Contacts38 = Annotated[list[bool], msgspec.Meta(min_length=N_SENSORS, max_length=N_SENSORS)]
FingerAngles = Annotated[list[float], msgspec.Meta(min_length=N_FINGERS, max_length=N_FINGERS)]
Policy = Literal["tree", "greedy", "random"]
LabelProb = tuple[str, Probability]


class Message(msgspec.Struct, forbid_unknown_fields=True):
    """Base of every wire message: carries the schema version."""

    v: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        if self.v != SCHEMA_VERSION:
            raise ValueError(_version_text(self.v))


def _version_text(v: object) -> str:
    return f"schema version {v!r} is not supported (this build speaks {SCHEMA_VERSION})"


# --------------------------------------------------------------------------- value types


class PoseMsg(Message, kw_only=True):
    """A pose: translation (m) and quaternion x, y, z, w (normalised by the receiver)."""

    xyz: Vec3
    quat: Quat

    def __post_init__(self) -> None:
        super().__post_init__()
        if float(np.dot(self.quat, self.quat)) < 1e-18:
            raise ValueError("`quat` has zero norm")


class GraspMsg(Message, kw_only=True):
    """One guarded grasp: the sensors in contact, their hand-frame XYZ and pressures."""

    sensor_ids: list[SensorId]
    xyz: list[Vec3]
    pressures: list[float]
    finger_angles: FingerAngles
    preshape: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        n = len(self.sensor_ids)
        if len(self.xyz) != n or len(self.pressures) != n:
            raise ValueError(
                f"`sensor_ids` ({n}), `xyz` ({len(self.xyz)}) and `pressures` "
                f"({len(self.pressures)}) differ in length"
            )
        if len(set(self.sensor_ids)) != n:
            raise ValueError("`sensor_ids` has duplicates")


class HandStateMsg(Message, kw_only=True):
    """A snapshot of all 38 sensors, the proximal finger angles and the preshape."""

    pressures: Pressures38
    contact: Contacts38
    finger_angles: FingerAngles
    preshape: float
    stamp: float  # seconds, monotonic clock of the producer


class JointStateMsg(Message, kw_only=True):
    names: list[Name]
    position: list[float]
    velocity: list[float] = []  # empty when the arm does not report velocities
    stamp: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        n = len(self.names)
        if len(self.position) != n:
            raise ValueError(f"`position` has {len(self.position)} values for {n} `names`")
        if self.velocity and len(self.velocity) != n:
            raise ValueError(f"`velocity` has {len(self.velocity)} values for {n} `names`")


class JointTrajectoryMsg(Message, kw_only=True):
    """Positions (n_points x n_joints) at non-decreasing times (s, from the start)."""

    names: Annotated[list[Name], msgspec.Meta(min_length=1)]
    times: Annotated[list[NonNegFloat], msgspec.Meta(min_length=1)]
    positions: list[list[float]]
    velocities: list[list[float]] | None = None
    meta: dict[str, Any] = {}

    def __post_init__(self) -> None:
        super().__post_init__()
        n_pts, n_j = len(self.times), len(self.names)
        if len(set(self.names)) != n_j:
            raise ValueError("`names` has duplicates")
        if any(b < a for a, b in zip(self.times, self.times[1:], strict=False)):
            raise ValueError("`times` must not decrease")
        for field, rows in (("positions", self.positions), ("velocities", self.velocities)):
            if rows is None:
                continue
            if len(rows) != n_pts:
                raise ValueError(f"`{field}` has {len(rows)} rows for {n_pts} `times`")
            for i, row in enumerate(rows):
                if len(row) != n_j:
                    raise ValueError(f"`{field}[{i}]` has {len(row)} values for {n_j} `names`")


# --------------------------------------------------------------------------- requests / replies


class Empty(Message, kw_only=True):
    """Request of a command without arguments (open, guarded_close, state, stop, status ...).

    A query with no payload at all is accepted as `Empty` too."""


class PreshapeRequest(Message, kw_only=True):
    angle: float  # rad, 0 cylinder ... 1.57 pinch (the hand checks its own range)


class MoveWristRequest(Message, kw_only=True):
    pose: PoseMsg  # hand frame in the object frame


class ExecuteRequest(Message, kw_only=True):
    trajectory: JointTrajectoryMsg


class Reply(Message, Generic[T], kw_only=True):
    """Answer to every query. ``ok`` true: `result` holds the value (None for plain commands).
    ``ok`` false: `error` says what went wrong and `error_type` / `error_bases` name the
    exception class and its bases, so a Python client re-raises the same type."""

    ok: bool
    result: T | None = None
    error: str | None = None
    error_type: str | None = None
    error_bases: list[str] = []

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.ok and self.error is not None:
            raise ValueError("`error` must be null when `ok` is true")
        if not self.ok and not self.error:
            raise ValueError("`error` must say what failed when `ok` is false")

    @classmethod
    def success(cls, result: Any = None) -> Reply:
        return cls(ok=True, result=result)

    @classmethod
    def failure(cls, exc: BaseException) -> Reply:
        bases = [
            c.__name__
            for c in type(exc).__mro__[1:]
            if issubclass(c, Exception) and c not in (Exception, BaseException)
        ]
        return cls(
            ok=False,
            error=str(exc) or type(exc).__name__,
            error_type=type(exc).__name__,
            error_bases=bases,
        )


# --------------------------------------------------------------------------- recognition daemon


class RecognizeRequest(Message, kw_only=True):
    """Start one recognition (paper Alg. 2). `object` names the object the twin places
    (simulation only; the real robot grasps whatever is on the table)."""

    policy: Policy
    max_moves: PositiveInt
    seed: NonNegInt | None = None  # None: the daemon draws one (and reports it)
    object: Name | None = None
    horizon: PositiveInt | None = None  # None: the configured planner horizon
    simulations: PositiveInt | None = None  # None: the configured number of simulations
    # Chosen by the client so it can pick its own progress samples out; None: the daemon
    # makes one. Reported back in every Progress and in the result.
    session_id: Name | None = None


class Progress(Message, kw_only=True):
    """Published on `progress` after every grasp of a recognition."""

    session_id: Name
    move: NonNegInt  # grasps so far: 1 is the initial grasp (as max_moves counts them)
    pose: PoseMsg | None  # wrist pose of this grasp (object frame); None if none was reached
    n_contacts: NonNegInt
    top3: Annotated[list[LabelProb], msgspec.Meta(max_length=3)]  # (label, probability), best first
    skipped: NonNegInt = 0  # planned poses skipped so far (unreachable)
    planning_s: NonNegFloat = 0.0  # planning time spent for this move
    stamp: float = 0.0  # wall clock (Unix seconds) of the producer
    pose_id: NonNegInt | None = None  # index of the grasp's pose in the model's training poses
    elapsed_s: NonNegFloat = 0.0  # since the session started


class RecognizeResult(Message, kw_only=True):
    session_id: Name
    label: str
    probability: Probability
    labels: list[str]  # top label after each grasp (index 0: the initial grasp)
    moves: NonNegInt  # grasps made, the initial one included (= len(labels))
    skipped: NonNegInt = 0  # planned poses that could not be reached
    planning_s: NonNegFloat = 0.0  # total planning time
    elapsed_s: NonNegFloat = 0.0  # request to result
    policy: Policy = "tree"
    seed: NonNegInt | None = None
    object: str | None = None
    stop_reason: str = ""  # confident | budget | exhausted | cancelled | skips
    pose_ids: list[NonNegInt] = []  # the executed grasps' poses, in order


class CancelRequest(Message, kw_only=True):
    session_id: Name | None = None  # None: the current recognition


class CancelResult(Message, kw_only=True):
    cancelled: bool
    session_id: str | None = None


class EStopRequest(Message, kw_only=True):
    reason: str = ""


class EStopResult(Message, kw_only=True):
    arm_stopped: bool
    hand_opened: bool
    errors: list[str] = []


class NodeHealth(Message, kw_only=True):
    alive: bool
    detail: str = ""


class SessionSummary(Message, kw_only=True):
    session_id: Name
    policy: Policy
    max_moves: PositiveInt
    move: NonNegInt = 0
    object: str | None = None
    started: float = 0.0  # wall clock, Unix seconds


class Status(Message, kw_only=True):
    robot: Name
    nodes: dict[str, NodeHealth]
    model_loaded: bool
    model: str | None = None  # model name / path / checksum
    session: SessionSummary | None = None  # the recognition in progress, if any
    uptime_s: NonNegFloat = 0.0
    mode: str = ""  # sim | hardware
    model_error: str | None = None  # why no model is loaded
    queued: NonNegInt = 0  # recognitions waiting behind the current one


class SimPlaceRequest(Message, kw_only=True):
    """Twin only: put a library object on the table and restart the hand's noise from `seed`
    (so a recognition repeats exactly for a seed)."""

    object: Name
    seed: NonNegInt | None = None


class SimPlaceResult(Message, kw_only=True):
    object: str
    extents: Vec3  # bounding-box size, metres


# --------------------------------------------------------------------------- encode / decode


def _enc_hook(obj: Any) -> Any:
    # numpy values sneak in through JointTrajectory.meta and hand-built messages.
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode objects of type {type(obj).__name__}")


_ENCODER = msgspec.json.Encoder(enc_hook=_enc_hook)
_DECODERS: dict[Any, msgspec.json.Decoder] = {}


class _Versioned(msgspec.Struct):
    v: int


_VERSION_DECODER = msgspec.json.Decoder(_Versioned)


def encode(msg: Message) -> bytes:
    """JSON bytes of `msg`."""
    try:
        return _ENCODER.encode(msg)
    except (TypeError, ValueError, OverflowError) as e:
        raise MessageError(f"cannot encode {type(msg).__name__}: {e}") from None


def _type_name(t: Any) -> str:
    origin = getattr(t, "__origin__", None)
    if origin is not None:
        args = ", ".join(_type_name(a) for a in getattr(t, "__args__", ()))
        return f"{getattr(origin, '__name__', origin)}[{args}]"
    return getattr(t, "__name__", repr(t))


_AT = re.compile(r" - at `\$(?P<path>[^`]*)`$")
_NAMED = re.compile(r"(?:missing required|unknown) field `(?P<name>[^`]+)`")


def _message_error(type_name: str, exc: msgspec.MsgspecError) -> MessageError:
    text = str(exc)
    path = ""
    m = _AT.search(text)
    if m:
        path = m.group("path").lstrip(".")
        text = text[: m.start()]
    named = _NAMED.search(text)
    if named:  # the field itself is missing/unknown: name it, under its parent's path
        path = f"{path}.{named.group('name')}" if path else named.group("name")
    if isinstance(exc, msgspec.DecodeError) and not isinstance(exc, msgspec.ValidationError):
        text = f"not valid JSON ({text})"
    if path:
        return MessageError(f"invalid {type_name}: field `{path}`: {text}", field=path)
    return MessageError(f"invalid {type_name}: {text}")


def decode(data: bytes | bytearray | memoryview | str, type: Any) -> Any:
    """Parse and validate `data` as `type`; raise `MessageError` naming the bad field."""
    name = _type_name(type)
    if isinstance(data, str):
        data = data.encode()
    if not data:
        raise MessageError(f"invalid {name}: empty payload")
    try:
        version = _VERSION_DECODER.decode(data).v
    except msgspec.MsgspecError as e:
        if "missing required field `v`" in str(e):
            raise MessageError(
                f"invalid {name}: field `v`: missing (schema version {SCHEMA_VERSION})",
                field="v",
            ) from None
        raise _message_error(name, e) from None
    if version != SCHEMA_VERSION:
        raise MessageError(f"invalid {name}: field `v`: {_version_text(version)}", field="v")
    dec = _DECODERS.get(type)
    if dec is None:
        dec = _DECODERS[type] = msgspec.json.Decoder(type)
    try:
        return dec.decode(data)
    except msgspec.MsgspecError as e:
        raise _message_error(name, e) from None


# --------------------------------------------------------------------------- conversions


def _floats(a: Any, field: str) -> list:
    arr = np.asarray(a, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise MessageError(f"`{field}` contains NaN or infinity", field=field)
    return arr.tolist()


def pose_to_msg(pose: Pose) -> PoseMsg:
    return PoseMsg(xyz=tuple(_floats(pose.xyz, "xyz")), quat=tuple(_floats(pose.quat, "quat")))


def pose_from_msg(msg: PoseMsg) -> Pose:
    return Pose(np.array(msg.xyz, dtype=np.float64), np.array(msg.quat, dtype=np.float64))


def grasp_to_msg(grasp: Grasp) -> GraspMsg:
    try:
        return GraspMsg(
            sensor_ids=[int(i) for i in grasp.sensor_ids],
            xyz=[tuple(p) for p in _floats(grasp.xyz, "xyz")],
            pressures=_floats(grasp.pressures, "pressures"),
            finger_angles=_floats(grasp.finger_angles, "finger_angles"),
            preshape=float(_floats(grasp.preshape, "preshape")),
        )
    except ValueError as e:  # __post_init__ consistency checks
        raise MessageError(f"invalid Grasp: {e}") from None


def _check_len(values: list, n: int, field: str) -> list:
    if len(values) != n:
        raise MessageError(f"`{field}` has {len(values)} values, expected {n}", field=field)
    return values


def grasp_from_msg(msg: GraspMsg) -> Grasp:
    return Grasp(
        sensor_ids=np.array(msg.sensor_ids, dtype=np.int64),
        xyz=np.array(msg.xyz, dtype=np.float64).reshape(-1, 3),
        pressures=np.array(msg.pressures, dtype=np.float64),
        finger_angles=np.array(msg.finger_angles, dtype=np.float64),
        preshape=float(msg.preshape),
    )


def hand_state_to_msg(state: HandState) -> HandStateMsg:
    return HandStateMsg(
        pressures=_check_len(_floats(state.pressures, "pressures"), N_SENSORS, "pressures"),
        contact=_check_len(
            [bool(c) for c in np.asarray(state.contact).reshape(-1)], N_SENSORS, "contact"
        ),
        finger_angles=_check_len(
            _floats(state.finger_angles, "finger_angles"), N_FINGERS, "finger_angles"
        ),
        preshape=float(_floats(state.preshape, "preshape")),
        stamp=float(state.stamp),
    )


def hand_state_from_msg(msg: HandStateMsg) -> HandState:
    return HandState(
        pressures=np.array(msg.pressures, dtype=np.float64),
        contact=np.array(msg.contact, dtype=bool),
        finger_angles=np.array(msg.finger_angles, dtype=np.float64),
        preshape=float(msg.preshape),
        stamp=float(msg.stamp),
    )


def joint_state_to_msg(state: JointState) -> JointStateMsg:
    try:
        return JointStateMsg(
            names=list(state.names),
            position=_floats(state.position, "position"),
            velocity=_floats(state.velocity, "velocity") if state.velocity is not None else [],
            stamp=float(state.stamp),
        )
    except ValueError as e:
        raise MessageError(f"invalid JointState: {e}") from None


def joint_state_from_msg(msg: JointStateMsg) -> JointState:
    n = len(msg.names)
    vel = msg.velocity if msg.velocity else [0.0] * n
    return JointState(
        names=tuple(msg.names),
        position=np.array(msg.position, dtype=np.float64),
        velocity=np.array(vel, dtype=np.float64),
        stamp=float(msg.stamp),
    )


def trajectory_to_msg(traj: JointTrajectory) -> JointTrajectoryMsg:
    n_j = len(traj.names)
    pos = np.asarray(traj.positions, dtype=np.float64).reshape(-1, n_j) if n_j else []
    try:
        return JointTrajectoryMsg(
            names=list(traj.names),
            times=_floats(np.asarray(traj.times).reshape(-1), "times"),
            positions=_floats(pos, "positions"),
            velocities=(
                None
                if traj.velocities is None
                else _floats(np.asarray(traj.velocities).reshape(-1, n_j), "velocities")
            ),
            meta=dict(traj.meta),
        )
    except ValueError as e:
        raise MessageError(f"invalid JointTrajectory: {e}") from None


def trajectory_from_msg(msg: JointTrajectoryMsg) -> JointTrajectory:
    n_j = len(msg.names)
    return JointTrajectory(
        names=tuple(msg.names),
        times=np.array(msg.times, dtype=np.float64),
        positions=np.array(msg.positions, dtype=np.float64).reshape(-1, n_j),
        velocities=(
            None
            if msg.velocities is None
            else np.array(msg.velocities, dtype=np.float64).reshape(-1, n_j)
        ),
        meta=dict(msg.meta),
    )


_TO_MSG = {
    Pose: pose_to_msg,
    Grasp: grasp_to_msg,
    HandState: hand_state_to_msg,
    JointState: joint_state_to_msg,
    JointTrajectory: trajectory_to_msg,
}
_FROM_MSG = {
    PoseMsg: pose_from_msg,
    GraspMsg: grasp_from_msg,
    HandStateMsg: hand_state_from_msg,
    JointStateMsg: joint_state_from_msg,
    JointTrajectoryMsg: trajectory_from_msg,
}


def to_msg(value: Pose | Grasp | HandState | JointState | JointTrajectory) -> Message:
    """The wire message of an `activetouch.interfaces` value."""
    for cls, fn in _TO_MSG.items():
        if isinstance(value, cls):
            return fn(value)
    raise TypeError(f"no wire message for {type(value).__name__}")


def from_msg(msg: Message) -> Pose | Grasp | HandState | JointState | JointTrajectory:
    """The `activetouch.interfaces` value of a wire message."""
    fn = _FROM_MSG.get(type(msg))
    if fn is None:
        raise TypeError(f"{type(msg).__name__} has no interfaces counterpart")
    return fn(msg)


def error_types() -> dict[str, type[Exception]]:
    """Exception classes a client may re-raise by the name a node reported."""
    from activetouch import errors

    known: dict[str, type[Exception]] = {"ValueError": ValueError}
    for obj in vars(errors).values():
        if isinstance(obj, type) and issubclass(obj, ActiveTouchError):
            known[obj.__name__] = obj
    return known
