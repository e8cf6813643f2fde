"""Baxter's ROS 1 side as seen through zenoh-bridge-ros1: topics, bridge keys, message bytes.

The bridge (eclipse-zenoh/zenoh-plugin-ros1) carries each ROS 1 topic on one Zenoh key
``<hex of "pkg/Type">/<md5>/<bridge namespace>/<topic without the leading slash>`` (bridges
built before commit 3d90897, 2025-02, have no namespace chunk: ``<hex>/<md5>/<topic>``). The
payload is the ROS 1 serialisation of the message body without the 4-byte TCPROS length
prefix. Facts and sources: docs/protocols/baxter.md.

Serialisation goes through `rosbags` (no ROS needed): its ROS 1 typestore plus
``baxter_core_msgs`` registered from the .msg texts below. `Ros1Codec` checks at start that
the md5 sums rosbags derives equal the known ones, so a wrong .msg text cannot reach the robot.
rosbags is imported only when a codec is made (the device registry imports this package for
its config class alone).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from activetouch.errors import ConfigError, MessageError

SIDES = ("left", "right")
JOINTS = ("s0", "s1", "e0", "e1", "w0", "w1", "w2")  # shoulder -> wrist, baxter_interface order
BRIDGE_FORMATS = ("namespaced", "legacy")
# `auto`: take the format from the first joint state, on either key form (a tagged release of
# zenoh-plugin-ros1, 0.10.0-rc to 1.0.0-rc.1, is `legacy`; untagged main since 2025-02-26 is
# `namespaced`).
BRIDGE_FORMAT_CHOICES = ("auto", *BRIDGE_FORMATS)
# The bridge's own default namespace is the literal chunk "*": it declares its publishers and
# subscribers on ".../*/topic". Zenoh delivers a put on that key to every intersecting
# subscriber and a subscriber on it receives puts on any namespace, so "*" interoperates with
# a default bridge in both directions (measured with eclipse-zenoh 1.10, tests/drivers/baxter).
DEFAULT_BRIDGE_NAMESPACE = "*"

# ROS 1 message types used (ROS names, "pkg/Type").
JOINT_COMMAND = "baxter_core_msgs/JointCommand"
ASSEMBLY_STATE = "baxter_core_msgs/AssemblyState"
JOINT_STATE = "sensor_msgs/JointState"
BOOL = "std_msgs/Bool"
EMPTY = "std_msgs/Empty"
FLOAT64 = "std_msgs/Float64"

# md5 sums from genmsg over the SDK >= 1.0 baxter_common / std_msgs / common_msgs files
# (shared/protocol-facts.md A.1). Release-0.7.0 robots differ (see docs/protocols/baxter.md).
MD5: dict[str, str] = {
    JOINT_COMMAND: "19bfec8434dd568ab3c633d187c36f2e",
    ASSEMBLY_STATE: "356d9dd237ce73b2667da9235f541933",
    JOINT_STATE: "3066dcd76a6cfaef579bd0f34173e9fd",
    BOOL: "8b94c1b53db61fb6aed406028ad6332a",
    EMPTY: "d41d8cd98f00b204e9800998ecf8427e",
    FLOAT64: "fdb28210bfa9d7c91146260178d9a584",
}

# baxter_common baxter_core_msgs/msg/JointCommand.msg, verbatim.
JOINT_COMMAND_MSG = """int32 mode
float64[] command
string[]  names

int32 POSITION_MODE=1
int32 VELOCITY_MODE=2
int32 TORQUE_MODE=3
int32 RAW_POSITION_MODE=4
"""
# baxter_common baxter_core_msgs/msg/AssemblyState.msg (comments shortened).
ASSEMBLY_STATE_MSG = """bool ready               # enabled and ready to operate, e.g. not homing
bool enabled
bool stopped             # e-stop asserted
bool error               # a component of the assembly has an error
uint8  estop_button
  uint8   ESTOP_BUTTON_UNPRESSED = 0
  uint8   ESTOP_BUTTON_PRESSED   = 1
  uint8   ESTOP_BUTTON_UNKNOWN   = 2   # asserted by a non-user source
  uint8   ESTOP_BUTTON_RELEASED  = 3   # was pressed, released, robot still stopped
uint8  estop_source      # if stopped: the source of the e-stop
  uint8  ESTOP_SOURCE_NONE      = 0
  uint8  ESTOP_SOURCE_USER      = 1   # the red button
  uint8  ESTOP_SOURCE_UNKNOWN   = 2
  uint8  ESTOP_SOURCE_FAULT     = 3   # motor controller, joint fault
  uint8  ESTOP_SOURCE_BRAIN     = 4   # lapse of the brain heartbeat
"""

POSITION_MODE = 1
ESTOP_BUTTONS = {0: "unpressed", 1: "pressed", 2: "unknown", 3: "released"}
ESTOP_SOURCES = {0: "none", 1: "user (red button)", 2: "unknown", 3: "joint fault", 4: "brain"}


def joint_names(side: str) -> tuple[str, ...]:
    """The seven joints of one arm in baxter_interface's order (``left_s0`` ... ``left_w2``)."""
    if side not in SIDES:
        raise ConfigError(f"arm.side: expected one of {SIDES}, got {side!r}")
    return tuple(f"{side}_{j}" for j in JOINTS)


@dataclass(frozen=True)
class Topics:
    """The ROS 1 topics the driver uses for one arm (absolute names)."""

    side: str

    @property
    def joint_states(self) -> str:
        return "/robot/joint_states"

    @property
    def robot_state(self) -> str:
        return "/robot/state"

    @property
    def joint_command(self) -> str:
        return f"/robot/limb/{self.side}/joint_command"

    @property
    def speed_ratio(self) -> str:
        return f"/robot/limb/{self.side}/set_speed_ratio"

    @property
    def command_timeout(self) -> str:
        return f"/robot/limb/{self.side}/joint_command_timeout"

    @property
    def enable(self) -> str:
        return "/robot/set_super_enable"

    @property
    def stop(self) -> str:
        return "/robot/set_super_stop"

    @property
    def reset(self) -> str:
        return "/robot/set_super_reset"


def check_namespace(namespace: str) -> str:
    """`namespace` if it is one Zenoh key chunk the bridge could use, else ConfigError."""
    bad = not namespace or "/" in namespace or any(c in namespace for c in "?#$ ")
    if bad or ("*" in namespace and namespace != "*"):
        raise ConfigError(
            f"arm.bridge_namespace {namespace!r} is invalid: one key chunk without '/', "
            "'?', '#', '$' or spaces, or exactly '*' (the bridge's default)"
        )
    return namespace


def bridge_key(ros_type: str, topic: str, namespace: str, fmt: str, md5: str | None = None) -> str:
    """The Zenoh key zenoh-bridge-ros1 uses for ROS topic `topic` of type `ros_type`."""
    if fmt not in BRIDGE_FORMATS:
        raise ConfigError(f"arm.bridge_format: expected one of {BRIDGE_FORMATS}, got {fmt!r}")
    md5 = md5 or MD5[ros_type]
    name = topic.strip("/")
    if not name:
        raise ConfigError(f"ROS topic {topic!r} is empty")
    head = f"{ros_type.encode().hex()}/{md5}"
    if fmt == "legacy":
        return f"{head}/{name}"
    return f"{head}/{check_namespace(namespace)}/{name}"


def auto_keys(ros_type: str, topic: str, md5: str | None = None) -> tuple[str, str]:
    """The key expressions to hear `topic` on in either format: legacy, then namespaced (any
    one-chunk namespace)."""
    legacy = bridge_key(ros_type, topic, "", "legacy", md5)
    md5 = md5 or MD5[ros_type]
    return legacy, f"{ros_type.encode().hex()}/{md5}/*/{topic.strip('/')}"


def format_of_key(key: str, ros_type: str, topic: str, md5: str | None = None) -> tuple[str, str]:
    """(format, namespace) of a key a bridge published `topic` on."""
    legacy = bridge_key(ros_type, topic, "", "legacy", md5)
    if str(key) == legacy:
        return "legacy", ""
    head = legacy[: -len(topic.strip("/"))]  # "<hex>/<md5>/"
    middle = str(key)[len(head) : -len(topic.strip("/")) - 1]
    return "namespaced", middle


@dataclass(frozen=True)
class RosJointState:
    """A decoded sensor_msgs/JointState (all joints the robot reports)."""

    names: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    stamp: float  # header stamp, s (the robot's clock)

    def select(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray] | None:
        """Positions and velocities of `names` in that order; None if one is missing.

        Baxter omits velocities only in malformed messages; a short velocity array reads as 0."""
        index = {n: i for i, n in enumerate(self.names)}
        if not all(n in index for n in names):
            return None
        idx = np.array([index[n] for n in names])
        if len(self.position) != len(self.names):
            return None
        vel = self.velocity[idx] if len(self.velocity) == len(self.names) else np.zeros(len(idx))
        return self.position[idx].copy(), np.asarray(vel, dtype=np.float64).copy()


@dataclass(frozen=True)
class RobotState:
    """A decoded baxter_core_msgs/AssemblyState (``/robot/state``)."""

    ready: bool
    enabled: bool
    stopped: bool
    error: bool
    estop_button: int
    estop_source: int

    def describe(self) -> str:
        if self.stopped:
            button = ESTOP_BUTTONS.get(self.estop_button, str(self.estop_button))
            source = ESTOP_SOURCES.get(self.estop_source, str(self.estop_source))
            return f"e-stopped (source {source}, button {button})"
        if self.error:
            return "in error"
        return "enabled" if self.enabled else "disabled"


def _make_typestore() -> Any:
    # deferred: rosbags only when ROS messages are (de)serialised
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    types: dict[str, Any] = {}
    types.update(get_types_from_msg(JOINT_COMMAND_MSG, "baxter_core_msgs/msg/JointCommand"))
    types.update(get_types_from_msg(ASSEMBLY_STATE_MSG, "baxter_core_msgs/msg/AssemblyState"))
    ts.register(types)
    return ts


def _store_name(ros_type: str) -> str:
    pkg, name = ros_type.split("/")
    return f"{pkg}/msg/{name}"


class Ros1Codec:
    """Serialise / parse the messages the driver exchanges with Baxter, via rosbags.

    Construction fails with ConfigError if an md5 rosbags derives differs from `MD5`."""

    def __init__(self) -> None:
        self._ts = _make_typestore()
        for ros_type, known in MD5.items():
            _, md5 = self._ts.generate_msgdef(_store_name(ros_type))
            if md5 != known:
                raise ConfigError(
                    f"{ros_type}: the message definition hashes to {md5}, Baxter expects {known}"
                )
        self._types = {t: self._ts.types[_store_name(t)] for t in MD5}

    def _ser(self, ros_type: str, msg: Any) -> bytes:
        return bytes(self._ts.serialize_ros1(msg, _store_name(ros_type)))

    def _de(self, ros_type: str, raw: bytes) -> Any:
        # deferred: rosbags only when ROS messages are (de)serialised
        from rosbags.serde import SerdeError

        try:
            return self._ts.deserialize_ros1(memoryview(raw), _store_name(ros_type))
        except (SerdeError, ValueError, IndexError, UnicodeDecodeError) as e:
            raise MessageError(f"{ros_type}: malformed ROS 1 bytes ({len(raw)} B): {e}") from None
        except Exception as e:  # rosbags' generated code raises plain struct errors too
            raise MessageError(f"{ros_type}: malformed ROS 1 bytes ({len(raw)} B): {e}") from None

    # --- what the driver sends
    def joint_command(self, names: tuple[str, ...], positions: np.ndarray) -> bytes:
        """JointCommand in POSITION_MODE."""
        cmd = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1)
        if len(cmd) != len(names):
            raise ValueError("joint command: names and positions differ in length")
        msg = self._types[JOINT_COMMAND](mode=POSITION_MODE, command=cmd, names=list(names))
        return self._ser(JOINT_COMMAND, msg)

    def float64(self, value: float) -> bytes:
        return self._ser(FLOAT64, self._types[FLOAT64](data=float(value)))

    def bool(self, value: bool) -> bytes:
        return self._ser(BOOL, self._types[BOOL](data=bool(value)))

    def empty(self) -> bytes:
        return self._ser(EMPTY, self._types[EMPTY]())

    # --- what the driver receives
    def parse_joint_state(self, raw: bytes) -> RosJointState:
        m = self._de(JOINT_STATE, raw)
        # ROS 1 time is (uint32 sec, uint32 nsec); rosbags' ROS 1 store reads sec as int32
        # (the ROS 2 Time type), so stamps past 2038 would come out negative: undo that.
        sec = int(m.header.stamp.sec) % (1 << 32)
        stamp = float(sec) + 1e-9 * float(m.header.stamp.nanosec)
        pos = np.asarray(m.position, dtype=np.float64)
        vel = np.asarray(m.velocity, dtype=np.float64)
        eff = np.asarray(m.effort, dtype=np.float64)
        return RosJointState(tuple(m.name), pos, vel, eff, stamp)

    def parse_robot_state(self, raw: bytes) -> RobotState:
        m = self._de(ASSEMBLY_STATE, raw)
        return RobotState(
            bool(m.ready),
            bool(m.enabled),
            bool(m.stopped),
            bool(m.error),
            int(m.estop_button),
            int(m.estop_source),
        )

    # --- round-trip helpers the tests use against hand-built bytes
    def parse_joint_command(self, raw: bytes) -> tuple[int, tuple[str, ...], np.ndarray]:
        m = self._de(JOINT_COMMAND, raw)
        return int(m.mode), tuple(m.names), np.asarray(m.command, dtype=np.float64)
