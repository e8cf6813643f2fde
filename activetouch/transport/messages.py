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

import json
import re
import time
from typing import Annotated, Any, Generic, Literal, TypeVar

import msgspec
import numpy as np

from activetouch import errors
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
    "MAX_SENSORS",
    "SCHEMA_VERSION",
    "CancelRequest",
    "CancelResult",
    "DeviceHealth",
    "EStopRequest",
    "EStopResult",
    "Empty",
    "ExecuteRequest",
    "GraspMsg",
    "HandInfo",
    "HandStateMsg",
    "JointStateMsg",
    "JointTrajectoryMsg",
    "MaskRequest",
    "Message",
    "MessageError",
    "MotionStats",
    "MoveWristRequest",
    "NodeHealth",
    "PoseMsg",
    "PreshapeRequest",
    "Progress",
    "RecognizeRequest",
    "RecognizeResult",
    "Reply",
    "SensorFlagsMsg",
    "SensorSitesMsg",
    "SessionSummary",
    "SimPlaceRequest",
    "SimPlaceResult",
    "Status",
    "ThresholdsRequest",
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
# Tactile sensors on the wire: any hand with 1 .. MAX_SENSORS of them (the ReFlex's 38,
# N_SENSORS, the count wherever none is given; the BarrettHand's 96 cells). The hand node says
# its hand's count (`HandInfo`, ``hand/info``) and each side checks a message against it.
MAX_SENSORS = 96
SensorId = Annotated[int, msgspec.Meta(ge=0, lt=MAX_SENSORS)]
SensorCount = Annotated[int, msgspec.Meta(ge=1, le=MAX_SENSORS)]
NonNegInt = Annotated[int, msgspec.Meta(ge=0)]
PositiveInt = Annotated[int, msgspec.Meta(gt=0)]
NonNegFloat = Annotated[float, msgspec.Meta(ge=0.0)]
Probability = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Name = Annotated[str, msgspec.Meta(min_length=1, max_length=200)]
# Free text (reasons, details, error texts): long enough for any real message, short enough
# that a hostile peer cannot make us log or echo megabytes (issue 16, finding 8).
Text = Annotated[str, msgspec.Meta(max_length=1000)]
_MAX_ERROR = 4000
ErrorText = Annotated[str, msgspec.Meta(max_length=_MAX_ERROR)]
PathText = Annotated[str, msgspec.Meta(max_length=4096)]
Label = Annotated[str, msgspec.Meta(max_length=200)]
Pressures = Annotated[list[float], msgspec.Meta(min_length=1, max_length=MAX_SENSORS)]
Contacts = Annotated[list[bool], msgspec.Meta(min_length=1, max_length=MAX_SENSORS)]
FingerAngles = Annotated[list[float], msgspec.Meta(min_length=N_FINGERS, max_length=N_FINGERS)]
Policy = Literal["tree", "greedy", "random", "mesh"]

# Upper bounds of RecognizeRequest, checked at admission (issue 16, finding 2): unbounded
# values froze the daemon (3e6 simulations held the planner for a minute) or failed only
# after a grasp (1e10 simulations, horizon >= 2**63). Each covers the configured defaults
# (planner.simulations 200, planner.horizon 5, session.max_moves 20) many times over.
MAX_SIMULATIONS = 20_000
MAX_HORIZON = 50
MAX_MOVES = 1_000
MAX_SEED = 2**63 - 1  # numpy / int64 seeds
Seed = Annotated[int, msgspec.Meta(ge=0, le=MAX_SEED)]
LabelProb = tuple[Label, Probability]
MAX_CLASSES = 1_000  # classes in a belief (a model has a few dozen)


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

    sensor_ids: Annotated[list[SensorId], msgspec.Meta(max_length=MAX_SENSORS)]
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
    """A snapshot of all the hand's sensors (its `HandInfo.n_sensors`: 38 for a ReFlex, 96
    for a BarrettHand), the proximal finger angles and the preshape."""

    pressures: Pressures
    contact: Contacts
    finger_angles: FingerAngles
    preshape: float
    stamp: float  # seconds, monotonic clock of the producer
    # Optional (older producers omit them). The same instant on the producer's wall clock
    # (time.time(), so readers on other machines can place it to within their clock sync;
    # 0: unknown), and whether the hand's data stream is stale (no data within its timeout:
    # this reading is the last one there was).
    wall_stamp: float = 0.0
    stale: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.contact) != len(self.pressures):
            raise ValueError(
                f"`pressures` ({len(self.pressures)}) and `contact` ({len(self.contact)}) "
                "differ in length"
            )


class HandInfo(Message, kw_only=True):
    """What the hand node says of its hand (``hand/info``): its tactile sensor count, which
    every state, grasp, threshold list and mask of it is checked against, and its type
    (``hand.type``; "" if the node was not told). A node from before ``hand/info`` serves a
    hand with N_SENSORS (38) sensors."""

    n_sensors: SensorCount = N_SENSORS
    device: Label = ""


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
    accelerations: list[list[float]] | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        n_pts, n_j = len(self.times), len(self.names)
        if len(set(self.names)) != n_j:
            raise ValueError("`names` has duplicates")
        if any(b < a for a, b in zip(self.times, self.times[1:], strict=False)):
            raise ValueError("`times` must not decrease")
        for field, rows in (
            ("positions", self.positions),
            ("velocities", self.velocities),
            ("accelerations", self.accelerations),
        ):
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


class MaskRequest(Message, kw_only=True):
    """The sensors the hand ignores from now on (replacing an earlier mask; [] none); ids
    below the hand's `HandInfo.n_sensors` (the node refuses others)."""

    sensor_ids: list[SensorId] = []


class ThresholdsRequest(Message, kw_only=True):
    """Per-sensor contact thresholds measured at rest (sensor units), one per sensor of the
    hand (`HandInfo.n_sensors`; the node refuses another count): the hand counts a contact
    only above its own and its configured threshold, until set again."""

    thresholds: Annotated[list[NonNegFloat], msgspec.Meta(min_length=1, max_length=MAX_SENSORS)]


class SensorFlagsMsg(Message, kw_only=True):
    """Sensor id (as text) -> the flag the hand's tactile calibration gave it."""

    flags: dict[str, str] = {}


class SensorSitesMsg(Message, kw_only=True):
    """Where each sensor of the hand is now (hand frame, at the joint angles it reports; one
    per sensor, `HandInfo.n_sensors`) and the thresholds the hand itself counts contact over
    (sensor units, one per sensor). Either list empty: the hand does not tell."""

    sites: Annotated[list[Vec3], msgspec.Meta(max_length=MAX_SENSORS)] = []
    own_thresholds: Annotated[list[NonNegFloat], msgspec.Meta(max_length=MAX_SENSORS)] = []


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
    error: ErrorText | None = None
    error_type: Label | None = None
    error_bases: Annotated[list[Label], msgspec.Meta(max_length=32)] = []

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
        text = str(exc) or type(exc).__name__
        if len(text) > _MAX_ERROR:  # stay decodable by the peer (ErrorText)
            text = text[: _MAX_ERROR - 20] + " ... (truncated)"
        return cls(
            ok=False,
            error=text,
            error_type=type(exc).__name__,
            error_bases=bases,
        )


# --------------------------------------------------------------------------- recognition daemon


class RecognizeRequest(Message, kw_only=True):
    """Start one recognition (paper Alg. 2). `object` names the object the twin places
    (simulation only; the real robot grasps whatever is on the table)."""

    policy: Policy
    # Grasps, the initial one included: 1 ... MAX_MOVES (1000).
    max_moves: Annotated[int, msgspec.Meta(ge=1, le=MAX_MOVES)]
    # 0 ... MAX_SEED (2**63 - 1); None: the daemon draws one (and reports it).
    seed: Seed | None = None
    object: Name | None = None
    # Planning depth, 1 ... MAX_HORIZON (50); None: the configured planner horizon.
    horizon: Annotated[int, msgspec.Meta(ge=1, le=MAX_HORIZON)] | None = None
    # Simulations per plan, 1 ... MAX_SIMULATIONS (20000); None: the configured number.
    simulations: Annotated[int, msgspec.Meta(ge=1, le=MAX_SIMULATIONS)] | None = None
    # Chosen by the client so it can pick its own progress samples out; None: the daemon
    # makes one. Reported back in every Progress and in the result.
    session_id: Name | None = None
    # False: the daemon writes no recording of this recognition (`recognize --no-record`);
    # None: its `recording.enabled`. Added later: sent only when set, so a request without it
    # still reaches a daemon from before it.
    record: bool | None = None


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
    motion_s: NonNegFloat = 0.0  # robot seconds moving since the session started
    # For a live view (`activetouch view`); added later: optional, left out of the JSON while
    # empty, so a daemon that has none of them still speaks to clients from before them.
    # This grasp's contacts in the object frame (table contacts dropped), metres.
    contacts: Annotated[list[Vec3], msgspec.Meta(max_length=MAX_SENSORS)] = []
    # p(y|h) of every class after this grasp, in the model's class order (empty before the
    # first grasp that felt anything).
    belief: Annotated[list[LabelProb], msgspec.Meta(max_length=MAX_CLASSES)] = []
    # The object frame in the robot base frame (the placement the recognition used).
    object_pose: PoseMsg | None = None
    object: Label | None = None  # the placed object's name (simulation), None if unknown
    extents: Vec3 | None = None  # its bounding-box size, metres, None if unknown


class RecognizeResult(Message, kw_only=True):
    session_id: Name
    label: Label
    probability: Probability
    labels: list[Label]  # top label after each grasp (index 0: the initial grasp)
    moves: NonNegInt  # grasps made, the initial one included (= len(labels))
    skipped: NonNegInt = 0  # planned poses that could not be reached
    planning_s: NonNegFloat = 0.0  # planning: the search plus the arm's motion planning
    elapsed_s: NonNegFloat = 0.0  # request to result
    policy: Policy = "tree"
    seed: Seed | None = None
    object: Label | None = None
    stop_reason: Label = ""  # confident | budget | exhausted | cancelled | skips
    pose_ids: list[NonNegInt] = []  # the executed grasps' poses, in order
    # Robot time (added later: optional, so results of older daemons still decode).
    motion_s: NonNegFloat = 0.0  # the arm moving: sum of executed trajectory durations
    motion_planning_s: NonNegFloat = 0.0  # the arm's motion planning (wall seconds)
    grasp_s: NonNegFloat = 0.0  # the hand's open / preshape / guarded close
    search_s: NonNegFloat = 0.0  # the policy's search alone (part of planning_s)
    total_s: NonNegFloat = 0.0  # robot time: motion_s + grasp_s + planning_s
    # Sensors ignored throughout this recognition (flagged by the tactile calibration, in
    # contact with the hand open, or dead at rest), and why: sensor id (as text) -> reason.
    masked_sensors: list[SensorId] = []
    masked_reasons: dict[str, str] = {}
    # recognition.belief = pose: the placement estimate under the label (dx_m, dy_m, yaw_deg
    # and their standard deviations sd_x_m, sd_y_m, sd_yaw_deg)
    pose_estimate: dict[str, float] | None = None
    profile: str = ""  # the daemon's configuration profile (`--profile`)
    settings: dict[str, str | float | int | bool] = {}  # the settings that define its method


class MotionStats(Message, kw_only=True):
    """What the arm node's motion layer has done since it was made (``arm/motion_stats``);
    readers take differences."""

    robot_s: NonNegFloat = 0.0  # sum of executed trajectory durations
    planning_s: NonNegFloat = 0.0  # wall seconds planning them (failed plans included)
    moves: NonNegInt = 0  # completed motions


class CancelRequest(Message, kw_only=True):
    session_id: Name | None = None  # None: the current recognition


class CancelResult(Message, kw_only=True):
    cancelled: bool
    session_id: Label | None = None


class EStopRequest(Message, kw_only=True):
    reason: Text = ""


class EStopResult(Message, kw_only=True):
    arm_stopped: bool
    hand_opened: bool
    errors: Annotated[list[ErrorText], msgspec.Meta(max_length=32)] = []


DeviceLinkState = Literal["connected", "waiting", "lost", ""]


class NodeHealth(Message, kw_only=True):
    alive: bool
    detail: Text = ""
    # A device node: connected, waiting (never connected yet) or lost, and since when
    # (wall clock, Unix seconds); "" for nodes that are no device (daemon, sim).
    state: DeviceLinkState = ""
    since: float | None = None
    device: Label = ""  # the device type (hand.type / arm.type)


class DeviceHealth(Message, kw_only=True):
    """What a device node says of its device (``health/<node>``): published on each change and
    while it is not connected; the daemon's status shows it."""

    node: Name
    device: Label
    state: DeviceLinkState
    detail: Text = ""  # why it is waiting or lost (the last connection error)
    since: float = 0.0  # wall clock, Unix seconds, of the last change of state
    attempts: NonNegInt = 0  # connection attempts since the last change


class SessionSummary(Message, kw_only=True):
    session_id: Name
    policy: Policy
    max_moves: PositiveInt
    move: NonNegInt = 0
    object: Label | None = None
    started: float = 0.0  # wall clock, Unix seconds


class Status(Message, kw_only=True):
    robot: Name
    nodes: dict[str, NodeHealth]
    model_loaded: bool
    model: PathText | None = None  # model name / path / checksum
    session: SessionSummary | None = None  # the recognition in progress, if any
    uptime_s: NonNegFloat = 0.0
    mode: Label = ""  # sim | hardware
    model_error: ErrorText | None = None  # why no model is loaded
    queued: NonNegInt = 0  # recognitions waiting behind the current one


class SimPlaceRequest(Message, kw_only=True):
    """Twin only: put a library object on the table and restart the hand's noise from `seed`
    (so a recognition repeats exactly for a seed)."""

    object: Name
    seed: Seed | None = None


class SimPlaceResult(Message, kw_only=True):
    object: Label
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


# Optional fields added after a message shipped: left out of the JSON while None (or empty),
# so the daemons and clients from before them (which refuse unknown fields) still read the
# message when they are not used.
_ADDED_LATER: dict[type, tuple[str, ...]] = {
    RecognizeRequest: ("record",),
    Progress: ("contacts", "belief", "object_pose", "object", "extents"),
}


def _unset(value: Any) -> bool:
    return value is None or (isinstance(value, list) and not value)


def encode(msg: Message) -> bytes:
    """JSON bytes of `msg`."""
    try:
        later = _ADDED_LATER.get(type(msg))
        if later and any(_unset(getattr(msg, name)) for name in later):
            d = msgspec.to_builtins(msg, enc_hook=_enc_hook)
            for name in later:
                if _unset(d.get(name)):
                    d.pop(name, None)
            return _ENCODER.encode(d)
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


# Admission limits of `decode` (issue 16, finding 8). A payload is refused before it is
# parsed if it is larger than its limit or nested deeper than MAX_DEPTH; every error text is
# cut to MAX_ERROR_TEXT characters with control characters escaped, so a hostile field is
# never echoed back or logged at length.
MAX_PAYLOAD = 64 * 1024  # bytes; every request and reply but a trajectory is far smaller
# A trajectory is sampled at 100 Hz with positions, velocities and accelerations: a 60 s
# motion of 7 joints is about 3 MB of JSON.
MAX_TRAJECTORY_PAYLOAD = 16 * 1024 * 1024
MAX_DEPTH = 32  # our deepest message (Reply > Status > nodes > NodeHealth) has 4 levels
MAX_ERROR_TEXT = 300
_LARGE = ("ExecuteRequest", "JointTrajectoryMsg")

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def clip_text(text: str, limit: int = MAX_ERROR_TEXT) -> str:
    """`text` on one line, control characters escaped, at most about `limit` characters."""
    if len(text) > limit:
        text = text[:limit] + f"... ({len(text)} characters)"
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def _message_error(type_name: str, exc: msgspec.MsgspecError) -> MessageError:
    text = str(exc)
    path = ""
    m = _AT.search(text)
    if m:
        path = clip_text(m.group("path").lstrip("."), 100)
        text = text[: m.start()]
    text = clip_text(text, 4 * MAX_ERROR_TEXT)  # the field name may follow a long value
    named = _NAMED.search(text)
    if named:  # the field itself is missing/unknown: name it, under its parent's path
        name = clip_text(named.group("name"), 100)
        path = f"{path}.{name}" if path else name
    text = clip_text(text)
    if isinstance(exc, msgspec.DecodeError) and not isinstance(exc, msgspec.ValidationError):
        text = f"not valid JSON ({text})"
    if path:
        return MessageError(f"invalid {type_name}: field `{path}`: {text}", field=path)
    return MessageError(f"invalid {type_name}: {text}")


_STRINGS = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)


def _depth(data: bytes) -> int:
    """Deepest nesting of arrays / objects in `data` (strings ignored), without recursing."""
    bare = _STRINGS.sub(b'""', data)
    b = np.frombuffer(bare, dtype=np.uint8)
    step = np.isin(b, (ord("["), ord("{"))).astype(np.int32)
    step -= np.isin(b, (ord("]"), ord("}")))
    return int(np.cumsum(step).max(initial=0))


class _DuplicateKeyError(Exception):
    pass


def _no_duplicates(pairs: list[tuple[str, Any]]) -> None:
    seen: set[str] = set()
    for k, _ in pairs:
        if k in seen:
            raise _DuplicateKeyError(k)
        seen.add(k)


def _check_duplicates(data: bytes, name: str) -> None:
    """msgspec keeps the last of duplicated keys silently; refuse them at every level so
    ``{"v":2,"v":1}`` and ``{"v":1,"v":2}`` are treated alike (both refused)."""
    try:
        json.loads(data, object_pairs_hook=_no_duplicates)
    except _DuplicateKeyError as e:
        key = clip_text(str(e.args[0]), 100)
        raise MessageError(f"invalid {name}: duplicate key `{key}`", field=key) from None
    except (ValueError, RecursionError):
        pass  # malformed JSON: msgspec says what is wrong below


def decode(data: bytes | bytearray | memoryview | str, type: Any) -> Any:
    """Parse and validate `data` as `type`; raise `MessageError` naming the bad field.

    Refused before parsing: more than MAX_PAYLOAD bytes (MAX_TRAJECTORY_PAYLOAD for a
    trajectory), nesting deeper than MAX_DEPTH, and any key given twice in one object."""
    name = _type_name(type)
    if isinstance(data, str):
        data = data.encode()
    data = bytes(data)
    if not data:
        raise MessageError(f"invalid {name}: empty payload")
    limit = MAX_TRAJECTORY_PAYLOAD if getattr(type, "__name__", "") in _LARGE else MAX_PAYLOAD
    if len(data) > limit:
        raise MessageError(f"invalid {name}: payload of {len(data)} bytes exceeds {limit} bytes")
    depth = _depth(data)
    if depth > MAX_DEPTH:
        raise MessageError(f"invalid {name}: JSON nested {depth} deep, more than {MAX_DEPTH}")
    _check_duplicates(data, name)
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
    except RecursionError:  # cannot happen below MAX_DEPTH; never let a traceback out
        raise MessageError(f"invalid {name}: JSON nested too deep") from None


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


def check_sensor_count(n_sensors: int, what: str = "the hand") -> int:
    """`n_sensors` if the hand messages can carry it (1 .. MAX_SENSORS), else MessageError."""
    n = int(n_sensors)
    if not 1 <= n <= MAX_SENSORS:
        raise MessageError(
            f"{what} has {n} tactile sensors: the hand messages carry 1..{MAX_SENSORS}"
        )
    return n


def _check_ids(ids: list[int], n_sensors: int | None, field: str, who: str) -> list[int]:
    """`ids` if every one is a sensor id of a hand with `n_sensors` (MAX_SENSORS: None)."""
    n = MAX_SENSORS if n_sensors is None else int(n_sensors)
    bad = [i for i in ids if not 0 <= i < n]
    if bad:
        raise MessageError(
            f"`{field}` has {bad[:8]}{' ...' if len(bad) > 8 else ''}: not a sensor id of "
            f"{who} (0..{n - 1})",
            field=field,
        )
    return ids


def _who(n_sensors: int | None) -> str:
    return "any hand" if n_sensors is None else f"a hand with {n_sensors} sensors"


def grasp_to_msg(grasp: Grasp, n_sensors: int | None = None) -> GraspMsg:
    """The wire message of `grasp`; its sensor ids checked against the hand's `n_sensors`
    (None: against MAX_SENSORS)."""
    ids = _check_ids([int(i) for i in grasp.sensor_ids], n_sensors, "sensor_ids", _who(n_sensors))
    try:
        return GraspMsg(
            sensor_ids=ids,
            xyz=[tuple(p) for p in _floats(grasp.xyz, "xyz")],
            pressures=_floats(grasp.pressures, "pressures"),
            finger_angles=_floats(grasp.finger_angles, "finger_angles"),
            preshape=float(_floats(grasp.preshape, "preshape")),
        )
    except ValueError as e:  # __post_init__ consistency checks
        raise MessageError(f"invalid Grasp: {e}") from None


def _check_len(values: list, n: int, field: str, why: str = "") -> list:
    if len(values) != n:
        raise MessageError(f"`{field}` has {len(values)} values, expected {n}{why}", field=field)
    return values


def grasp_from_msg(msg: GraspMsg, n_sensors: int | None = None) -> Grasp:
    """The `Grasp` of `msg`; with `n_sensors` (the count its hand node reported), a sensor id
    that hand does not have is a MessageError."""
    if n_sensors is not None:
        _check_ids(
            list(msg.sensor_ids),
            n_sensors,
            "sensor_ids",
            f"the hand, whose node reported {n_sensors} sensors",
        )
    return Grasp(
        sensor_ids=np.array(msg.sensor_ids, dtype=np.int64),
        xyz=np.array(msg.xyz, dtype=np.float64).reshape(-1, 3),
        pressures=np.array(msg.pressures, dtype=np.float64),
        finger_angles=np.array(msg.finger_angles, dtype=np.float64),
        preshape=float(msg.preshape),
    )


def hand_state_to_msg(state: HandState, n_sensors: int | None = None) -> HandStateMsg:
    """The wire message of `state`, whose pressures and contacts have `n_sensors` values each
    (the hand's; None: as many as the pressures, 1 .. MAX_SENSORS)."""
    pressures = _floats(state.pressures, "pressures")
    pressures = pressures if isinstance(pressures, list) else [pressures]
    n = check_sensor_count(len(pressures), "the hand state") if n_sensors is None else n_sensors
    why = f" (the hand's {n} sensors)"
    return HandStateMsg(
        pressures=_check_len(pressures, n, "pressures", why),
        contact=_check_len(
            [bool(c) for c in np.asarray(state.contact).reshape(-1)], n, "contact", why
        ),
        finger_angles=_check_len(
            _floats(state.finger_angles, "finger_angles"), N_FINGERS, "finger_angles"
        ),
        preshape=float(_floats(state.preshape, "preshape")),
        stamp=float(state.stamp),
        wall_stamp=_wall_stamp(state),
        stale=bool(getattr(state, "stale", False)),
    )


def _wall_stamp(state: HandState) -> float:
    """The state's wall-clock stamp: its own (drivers stamp each packet), else its monotonic
    stamp carried over to the wall clock now (both clocks are this process's)."""

    wall = float(getattr(state, "wall_stamp", 0.0) or 0.0)
    if wall > 0.0 or not state.stamp > 0.0:
        return wall
    return time.time() - (time.monotonic() - float(state.stamp))


def hand_state_from_msg(msg: HandStateMsg, n_sensors: int | None = None) -> HandState:
    """The `HandState` of `msg`; with `n_sensors` (the count its hand node reported), other
    lengths are a MessageError."""
    if n_sensors is not None:
        why = f" (the hand node reported {n_sensors} sensors)"
        _check_len(msg.pressures, n_sensors, "pressures", why)
        _check_len(msg.contact, n_sensors, "contact", why)
    return HandState(
        pressures=np.array(msg.pressures, dtype=np.float64),
        contact=np.array(msg.contact, dtype=bool),
        finger_angles=np.array(msg.finger_angles, dtype=np.float64),
        preshape=float(msg.preshape),
        stamp=float(msg.stamp),
        stale=bool(msg.stale),
        wall_stamp=float(msg.wall_stamp),
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
            accelerations=(
                None
                if traj.accelerations is None
                else _floats(np.asarray(traj.accelerations).reshape(-1, n_j), "accelerations")
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
        accelerations=(
            None
            if msg.accelerations is None
            else np.array(msg.accelerations, dtype=np.float64).reshape(-1, n_j)
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

    known: dict[str, type[Exception]] = {"ValueError": ValueError}
    for obj in vars(errors).values():
        if isinstance(obj, type) and issubclass(obj, ActiveTouchError):
            known[obj.__name__] = obj
    return known
