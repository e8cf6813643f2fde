"""What a recording holds: its channels, their schemas, and the ROS 2 messages.

ROS 2 channels (schema encoding ``ros2msg``, message encoding ``cdr``; schemas and CDR from
rosbags' typestore, so `ros2 bag play`, Foxglove and Lichtblick decode them):

- ``/joint_states`` (sensor_msgs/msg/JointState): after each grasp, the hand's preshape and
  proximal finger angles;
- ``/activetouch/contacts`` (sensor_msgs/msg/PointCloud2): after each grasp, its contacts in
  the hand frame (fields x y z pressure as float32, sensor_id as uint32);
- ``/tf_static`` (tf2_msgs/msg/TFMessage): world -> object (the placement), at the start;
- ``/tf`` (tf2_msgs/msg/TFMessage): object -> hand (the wrist pose) after each grasp;
- ``/activetouch/wrist_goal`` (geometry_msgs/msg/PoseStamped): before each move, the wrist
  goal in the object frame.

JSON channels (schema encoding ``jsonschema``, message encoding ``json``): `JSON_TOPICS`.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

SCHEMA_VERSION = 1
PROFILE = "ros2"
WORLD_FRAME, OBJECT_FRAME, HAND_FRAME = "world", "object", "hand"
HAND_JOINTS = ("reflex_preshape", "reflex_proximal_1", "reflex_proximal_2", "reflex_proximal_3")

JOINT_STATES = "/joint_states"
CONTACTS = "/activetouch/contacts"
TF = "/tf"
TF_STATIC = "/tf_static"
WRIST_GOAL = "/activetouch/wrist_goal"
ROS_TOPICS = {
    JOINT_STATES: "sensor_msgs/msg/JointState",
    CONTACTS: "sensor_msgs/msg/PointCloud2",
    TF: "tf2_msgs/msg/TFMessage",
    TF_STATIC: "tf2_msgs/msg/TFMessage",
    WRIST_GOAL: "geometry_msgs/msg/PoseStamped",
}

REQUEST = "/activetouch/request"
GRASP = "/activetouch/grasp"
BELIEF = "/activetouch/belief"
PLAN = "/activetouch/plan"
ROBOT_TIME = "/activetouch/robot_time"
ERROR = "/activetouch/error"
RESULT = "/activetouch/result"
HAND_STATE = "/activetouch/hand_state"

# What a recording holds (`REQUEST`'s "kind"): a recognition, or a `calibrate` procedure.
RECOGNITION, CALIBRATION = "recognition", "calibration"

_num = {"type": "number"}
_int = {"type": "integer"}
_str = {"type": "string"}
_nums = {"type": "array", "items": _num}
_ints = {"type": "array", "items": _int}


def _obj(title: str, description: str, props: dict[str, Any], required: list[str]) -> dict:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": {"v": _int, "move": _int, **props},
        "required": ["v", *required],
    }


_pose = {"type": "array", "items": _num, "minItems": 7, "maxItems": 7}
JSON_TOPICS: dict[str, tuple[str, dict]] = {
    REQUEST: (
        "activetouch.Request",
        _obj(
            "activetouch.Request",
            "What was asked, and what answered it: a recognition's request, model and belief "
            "settings, or a calibration's procedure, device and settings",
            {
                "kind": {"enum": [RECOGNITION, CALIBRATION]},
                "session_id": _str,
                "procedure": _str,
                "device": _str,
                "settings": {"type": "object"},
                "source": _str,
                "policy": _str,
                "max_moves": _int,
                "seed": _int,
                "object": {"type": ["string", "null"]},
                "horizon": _int,
                "simulations": _int,
                "model": _str,
                "model_checksum": _str,
                "class_names": {"type": "array", "items": _str},
                "recognition": {"type": "object"},
                "session": {"type": "object"},
                "placement": _pose,
                "started": _num,
            },
            ["session_id"],
        ),
    ),
    GRASP: (
        "activetouch.Grasp",
        _obj(
            "activetouch.Grasp",
            "One guarded grasp as the session observed it (table contacts dropped): contacts "
            "in the hand frame, pressures above the zero offset, finger angles, wrist pose",
            {
                "pose_id": _int,
                "pose": _pose,
                "sensor_ids": _ints,
                "xyz": {"type": "array", "items": _nums},
                "pressures": _nums,
                "finger_angles": _nums,
                "preshape": _num,
                "ignored_sensors": _ints,
                "support_z": _num,
            },
            ["move", "pose_id", "pose", "sensor_ids", "xyz", "pressures", "finger_angles"],
        ),
    ),
    BELIEF: (
        "activetouch.Belief",
        _obj(
            "activetouch.Belief",
            "p(y | grasps so far) after a grasp; label is '' while nothing was felt",
            {
                "label": _str,
                "felt": {"type": "boolean"},
                "probabilities": _nums,
                "class_names": {"type": "array", "items": _str},
                "top3": {"type": "array"},
            },
            ["label", "probabilities"],
        ),
    ),
    PLAN: (
        "activetouch.Plan",
        _obj(
            "activetouch.Plan",
            "The planner's choice after `move` grasps: the poses, actions, and their values",
            {
                "policy": _str,
                "poses": _ints,
                "actions": _ints,
                "value": {"type": ["number", "null"]},
                "step_values": _nums,
                "step_visits": _ints,
                "simulations": _int,
                "n_nodes": _int,
                "exhausted": {"type": "boolean"},
                "search_s": _num,
            },
            ["policy", "poses"],
        ),
    ),
    ROBOT_TIME: (
        "activetouch.RobotTime",
        _obj(
            "activetouch.RobotTime",
            "Robot seconds so far: moving, grasping, planning (search + motion) and their total",
            {
                "motion_s": _num,
                "grasp_s": _num,
                "search_s": _num,
                "motion_planning_s": _num,
                "total_s": _num,
                "elapsed_s": _num,
            },
            ["total_s"],
        ),
    ),
    ERROR: (
        "activetouch.Error",
        _obj(
            "activetouch.Error",
            "What went wrong: a skipped (unreachable) pose, or the error that ended it",
            {"kind": _str, "error_type": _str, "error": _str, "pose_id": _int},
            ["kind", "error"],
        ),
    ),
    RESULT: (
        "activetouch.Result",
        _obj(
            "activetouch.Result",
            "The recognition's answer (the daemon's RecognizeResult fields), or its error",
            {"label": _str, "labels": {"type": "array", "items": _str}, "error": _str},
            [],
        ),
    ),
}

# A `calibrate` recording: REQUEST (kind "calibration"), every new hand state on HAND_STATE
# (and /joint_states), every flange goal on /activetouch/wrist_goal (world frame) and where
# the hand got to on /tf, ERROR, and RESULT: the stored calibration record, or the error.
CALIBRATION_TOPICS: dict[str, tuple[str, dict]] = {
    REQUEST: JSON_TOPICS[REQUEST],
    HAND_STATE: (
        "activetouch.HandState",
        _obj(
            "activetouch.HandState",
            "One new state of the hand during a calibration: every sensor's pressure above "
            "the zero offset, those in contact, finger angles (rad), the producer's stamp (s)",
            {
                "pressures": _nums,
                "contact": _ints,
                "finger_angles": _nums,
                "preshape": _num,
                "stamp": _num,
            },
            ["pressures", "contact", "finger_angles"],
        ),
    ),
    ERROR: JSON_TOPICS[ERROR],
    RESULT: (
        "activetouch.CalibrationResult",
        _obj(
            "activetouch.CalibrationResult",
            "The calibration record as `calibrate` stores it (kind, device, values, quality), "
            "or the error that ended the procedure",
            {"record": {"type": "object"}, "stored": {"type": "boolean"}, "error": _str},
            [],
        ),
    ),
}


@functools.cache
def typestore() -> Any:
    # deferred: rosbags only when ROS messages are (de)serialised
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@functools.cache
def ros_schema(typename: str) -> bytes:
    """The ``ros2msg`` schema text (the type with its dependencies, as rosbag2 writes it)."""
    text, _ = typestore().generate_msgdef(typename, ros_version=2)
    return text.encode()


def _stamp(ns: int) -> Any:
    t = typestore().types
    return t["builtin_interfaces/msg/Time"](
        sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)
    )


def _header(ns: int, frame: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=_stamp(ns), frame_id=frame)


def cdr(msg: Any) -> bytes:
    return bytes(typestore().serialize_cdr(msg, msg.__msgtype__))


def joint_state(ns: int, preshape: float, finger_angles: np.ndarray) -> bytes:
    t = typestore().types
    pos = np.array([preshape, *np.asarray(finger_angles, dtype=np.float64)[:3]], dtype=np.float64)
    return cdr(
        t["sensor_msgs/msg/JointState"](
            header=_header(ns, HAND_FRAME),
            name=list(HAND_JOINTS[: len(pos)]),
            position=pos,
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
    )


POINT_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pressure", "<f4"), ("sensor_id", "<u4")]
)


def point_cloud(ns: int, xyz: np.ndarray, pressures: np.ndarray, sensor_ids: np.ndarray) -> bytes:
    t = typestore().types
    pf = t["sensor_msgs/msg/PointField"]
    pts = np.zeros(len(sensor_ids), dtype=POINT_DTYPE)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    pts["x"], pts["y"], pts["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    pts["pressure"] = pressures
    pts["sensor_id"] = sensor_ids
    fields = [
        pf(name=name, offset=POINT_DTYPE.fields[name][1], datatype=kind, count=1)
        for name, kind in (
            ("x", pf.FLOAT32),
            ("y", pf.FLOAT32),
            ("z", pf.FLOAT32),
            ("pressure", pf.FLOAT32),
            ("sensor_id", pf.UINT32),
        )
    ]
    return cdr(
        t["sensor_msgs/msg/PointCloud2"](
            header=_header(ns, HAND_FRAME),
            height=1,
            width=len(pts),
            fields=fields,
            is_bigendian=False,
            point_step=POINT_DTYPE.itemsize,
            row_step=POINT_DTYPE.itemsize * len(pts),
            data=np.frombuffer(pts.tobytes(), dtype=np.uint8),
            is_dense=True,
        )
    )


def _pose_parts(pose: np.ndarray) -> tuple[Any, Any]:
    t = typestore().types
    p = np.asarray(pose, dtype=np.float64).reshape(7)
    return (
        t["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
        t["geometry_msgs/msg/Quaternion"](
            x=float(p[3]), y=float(p[4]), z=float(p[5]), w=float(p[6])
        ),
    )


def tf_message(ns: int, transforms: list[tuple[str, str, np.ndarray]]) -> bytes:
    """(parent, child, pose of child in parent (x y z qx qy qz qw)) each."""
    t = typestore().types
    out = []
    for parent, child, pose in transforms:
        v, q = _pose_parts(pose)
        out.append(
            t["geometry_msgs/msg/TransformStamped"](
                header=_header(ns, parent),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](translation=v, rotation=q),
            )
        )
    return cdr(t["tf2_msgs/msg/TFMessage"](transforms=out))


def pose_stamped(ns: int, frame: str, pose: np.ndarray) -> bytes:
    t = typestore().types
    v, q = _pose_parts(pose)
    point = t["geometry_msgs/msg/Point"](x=v.x, y=v.y, z=v.z)
    return cdr(
        t["geometry_msgs/msg/PoseStamped"](
            header=_header(ns, frame),
            pose=t["geometry_msgs/msg/Pose"](position=point, orientation=q),
        )
    )


def deserialize(data: bytes, typename: str) -> Any:
    return typestore().deserialize_cdr(data, typename)


def placement_pose(xyz: np.ndarray, yaw_rad: float) -> np.ndarray:
    """(7,) the object frame in the world (robot base) frame: turned about z only."""
    h = 0.5 * float(yaw_rad)
    return np.array([*np.asarray(xyz, dtype=np.float64).reshape(3), 0.0, 0.0, np.sin(h), np.cos(h)])
