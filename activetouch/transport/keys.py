"""Every Zenoh key expression the system uses, in one place.

All keys live under ``activetouch/<robot>/``. `<robot>` is one key chunk: letters, digits,
``_ . -``; no wildcards (``*``, ``$``), ``/``, ``?``, ``#`` or spaces, so a robot name can never
widen a subscription or a query to other robots.

| key | kind | payload |
|---|---|---|
| hand/state | publication (periodic) and queryable | HandStateMsg / Empty -> Reply[HandStateMsg] |
| hand/info | queryable (at once: the hand's sensor count and type) | Empty -> Reply[HandInfo] |
| hand/open | queryable | Empty -> Reply[None] |
| hand/preshape | queryable | PreshapeRequest -> Reply[None] |
| hand/mask | queryable (sensors to ignore) | MaskRequest -> Reply[bool] |
| hand/thresholds | queryable (noise thresholds) | ThresholdsRequest -> Reply[bool] |
| hand/sensor_flags | queryable (tactile calibration flags) | Empty -> Reply[SensorFlagsMsg] |
| hand/sensor_sites | queryable (sites now, own thresholds) | Empty -> Reply[SensorSitesMsg] |
| hand/guarded_close | queryable | Empty -> Reply[GraspMsg] |
| hand/stop | queryable (served at once, beside a running grasp) | Empty -> Reply[None] |
| hand/clear_stop | queryable | Empty -> Reply[None] |
| arm/joint_states | publication (periodic) | JointStateMsg |
| arm/joint_state | queryable | Empty -> Reply[JointStateMsg] |
| arm/move_wrist | queryable | MoveWristRequest -> Reply[None] |
| arm/execute | queryable | ExecuteRequest -> Reply[None] |
| arm/stop | queryable (served at once, beside a running motion) | Empty -> Reply[None] |
| arm/clear_stop | queryable | Empty -> Reply[None] |
| arm/estop | queryable (served at once) | Empty -> Reply[None] |
| arm/enable, arm/disable | queryable | Empty -> Reply[None] |
| arm/motion_stats | queryable | Empty -> Reply[MotionStats] |
| recognize | queryable (daemon) | RecognizeRequest -> Reply[RecognizeResult] |
| progress | publication (daemon) | Progress |
| cancel | queryable (daemon) | CancelRequest -> Reply[CancelResult] |
| status | queryable (daemon) | Empty -> Reply[Status] |
| estop | queryable (daemon) | EStopRequest -> Reply[EStopResult] |
| sim/place | queryable (simulated devices only) | SimPlaceRequest -> Reply[SimPlaceResult] |
| alive/<node> | liveliness token (a device node: only while its device is connected) | (none) |
| health/<node> | publication (on change, and while not connected) and queryable | DeviceHealth |
| requests/<session_id> | liveliness token (the requesting client) | (none) |
| calibrate/<kind> | queryable (tactile fingers mount object) | CalibrateRequest -> Reply |
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from activetouch.errors import ConfigError

ROOT = "activetouch"
HAND_NODE = "hand"
ARM_NODE = "arm"
DAEMON_NODE = "daemon"
SIM_NODE = "sim"

_CHUNK = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,62}$")


def _check_chunk(value: str, what: str) -> str:
    if not isinstance(value, str) or not _CHUNK.fullmatch(value):
        raise ConfigError(
            f"{what} {value!r} is invalid: use 1-63 letters, digits, '_', '.', '-' "
            "(starting with a letter or digit; no '/', wildcards or spaces)"
        )
    return value


def validate_robot(name: str) -> str:
    """`name` if it is a valid robot name (one key chunk), else ConfigError."""
    return _check_chunk(name, "robot name")


def validate_node(name: str) -> str:
    return _check_chunk(name, "node name")


@dataclass(frozen=True)
class Keys:
    """The key expressions of one robot."""

    robot: str

    def __post_init__(self) -> None:
        validate_robot(self.robot)

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.robot}"

    def _k(self, *parts: str) -> str:
        return "/".join((self.prefix, *parts))

    # hand node
    @property
    def hand_state(self) -> str:
        return self._k("hand", "state")

    @property
    def hand_info(self) -> str:
        return self._k("hand", "info")

    @property
    def hand_open(self) -> str:
        return self._k("hand", "open")

    @property
    def hand_preshape(self) -> str:
        return self._k("hand", "preshape")

    @property
    def hand_mask(self) -> str:
        return self._k("hand", "mask")

    @property
    def hand_thresholds(self) -> str:
        return self._k("hand", "thresholds")

    @property
    def hand_sensor_flags(self) -> str:
        return self._k("hand", "sensor_flags")

    @property
    def hand_sensor_sites(self) -> str:
        return self._k("hand", "sensor_sites")

    @property
    def hand_guarded_close(self) -> str:
        return self._k("hand", "guarded_close")

    @property
    def hand_stop(self) -> str:
        return self._k("hand", "stop")

    @property
    def hand_clear_stop(self) -> str:
        return self._k("hand", "clear_stop")

    # arm node
    @property
    def arm_joint_states(self) -> str:
        return self._k("arm", "joint_states")

    @property
    def arm_joint_state(self) -> str:
        return self._k("arm", "joint_state")

    @property
    def arm_move_wrist(self) -> str:
        return self._k("arm", "move_wrist")

    @property
    def arm_execute(self) -> str:
        return self._k("arm", "execute")

    @property
    def arm_stop(self) -> str:
        return self._k("arm", "stop")

    @property
    def arm_clear_stop(self) -> str:
        return self._k("arm", "clear_stop")

    @property
    def arm_estop(self) -> str:
        return self._k("arm", "estop")

    @property
    def arm_motion_stats(self) -> str:
        return self._k("arm", "motion_stats")

    @property
    def arm_enable(self) -> str:
        return self._k("arm", "enable")

    @property
    def arm_disable(self) -> str:
        return self._k("arm", "disable")

    # recognition daemon
    @property
    def recognize(self) -> str:
        return self._k("recognize")

    @property
    def progress(self) -> str:
        return self._k("progress")

    @property
    def cancel(self) -> str:
        return self._k("cancel")

    @property
    def status(self) -> str:
        return self._k("status")

    @property
    def estop(self) -> str:
        return self._k("estop")

    # the twin's extra (simulation only)
    @property
    def sim_place(self) -> str:
        return self._k("sim", "place")

    # liveliness
    def alive(self, node: str) -> str:
        """Liveliness token key of node `node` (hand, arm, daemon, ...)."""
        return self._k("alive", validate_node(node))

    def health(self, node: str) -> str:
        """A device node's `DeviceHealth`: connected, waiting or lost, and why."""
        return self._k("health", validate_node(node))

    @property
    def health_all(self) -> str:
        return self._k("health", "*")

    def requester(self, session_id: str) -> str:
        """Liveliness token a client holds while it waits for recognition `session_id`: the
        daemon cancels the recognition when it drops (ConfigError for an id that is not one
        key chunk)."""
        return self._k("requests", _check_chunk(session_id, "session id"))

    @property
    def alive_all(self) -> str:
        """Matches every node's liveliness token of this robot."""
        return self._k("alive", "*")

    @staticmethod
    def node_of_alive_key(key: str) -> str:
        """The node name of a liveliness key (its last chunk)."""
        return str(key).rsplit("/", 1)[-1]
