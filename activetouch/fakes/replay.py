"""The ``fake`` hand and arm device types (activetouch.device_types): in memory, no physics.

A whole CLI (serve, recognize, status) runs on them without PyBullet. They are also the worked
example of a device type (docs/architecture.md, "Adding a device type").

How the fake hand produces grasps: it replays a training dataset. ``sim/place`` picks the
object (it must be in the dataset); the fake arm is a floating wrist (six joints: the hand pose
in the base frame); a guarded close looks up the current wrist pose in the object frame and
returns that object's stored grasp at the nearest training pose (within `match_m` and
`match_deg`), or an empty grasp (felt nothing) when no stored pose is that close. So a
recognition on the fakes sees exactly what training saw, at the poses the planner chose.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from activetouch import paths
from activetouch.device_types import ArmConfig, HandConfig
from activetouch.devices import DeviceContext
from activetouch.errors import ConfigError, DataError
from activetouch.fakes.memory_arm import MemoryArm
from activetouch.interfaces import (
    N_FINGERS,
    N_SENSORS,
    Arm,
    Grasp,
    Hand,
    HandState,
    JointLimits,
    Placed,
    Pose,
    StopLatch,
    extents_of,
)
from activetouch.planning.motion.base import Placement
from activetouch.planning.motion.floating import (
    WRIST_JOINTS,
    floating_limits,
    wrist_joints_to_pose,
)
from activetouch.recognition.dataset import Dataset

if TYPE_CHECKING:
    from activetouch.recognition.dataset import ObjectGrasps

FAKE = "fake"


@dataclass
class FakeHandConfig(HandConfig):
    """Replays the grasps of a training dataset (see the module)."""

    simulated: ClassVar[bool] = True

    dataset: str = ""  # dataset directory; "" the data directory's default dataset
    close_s: float = 0.0  # seconds a guarded close takes (a stop cuts it short)
    match_m: float = 0.01  # a stored grasp counts as "at" the wrist pose within these
    match_deg: float = 5.0

    def check(self) -> None:
        for name in ("close_s", "match_m", "match_deg"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"hand.{name} must be >= 0, got {getattr(self, name)}")

    def make(self, ctx: DeviceContext) -> Hand:
        return FakeHand(fake_rig(ctx), self)


@dataclass
class FakeArmConfig(ArmConfig):
    """A floating wrist in memory: trajectories are checked against the limits and end at
    their last point, after `time_scale` x their duration."""

    simulated: ClassVar[bool] = True

    time_scale: float = 0.0  # 0: motions take no time; 1: real time

    def check(self) -> None:
        if not self.time_scale >= 0:
            raise ConfigError(f"arm.time_scale must be >= 0, got {self.time_scale}")

    def make(self, ctx: DeviceContext) -> Arm:
        rig = fake_rig(ctx)
        rig.arm.time_scale = self.time_scale
        return rig.arm


def fake_arm(limits: JointLimits) -> MemoryArm:
    """The fake arm: a floating wrist (six joints, the hand pose in the base frame) in memory,
    starting 1 m above the base."""
    return MemoryArm(WRIST_JOINTS, limits, np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))


class FakeRig:
    """The fake arm, the dataset the fake hand replays, and the object on the fake table."""

    def __init__(self, ctx: DeviceContext) -> None:
        self.ctx = ctx
        self.workcell = ctx.cfg.workcell
        self.arm = fake_arm(floating_limits(self.workcell))
        self.placement = Placement(np.asarray(self.workcell.object_xyz, dtype=np.float64))
        self.object: ObjectGrasps | None = None
        self._dataset: Any = None
        self._lock = threading.Lock()

    def dataset(self, path: str) -> Any:

        with self._lock:
            if self._dataset is None:
                where = path or paths.default_dataset(paths.data_dir(self.ctx.data))
                self._dataset = Dataset.open(where)
            return self._dataset

    def place(self, obj: str, seed: int | None = None) -> Placed:
        """Put `obj` on the fake table: its grasps in the dataset are what the hand replays
        (`seed` is accepted for the twin's signature; the replay has no noise)."""
        hand_cfg = self.ctx.cfg.hand
        ds = self.dataset(getattr(hand_cfg, "dataset", ""))
        if obj not in ds.object_names():
            raise DataError(
                f"the fake hand has no grasps of {obj!r} in {ds.path} "
                f"(has: {', '.join(ds.object_names()) or 'none'})"
            )
        extents = ds.attrs(obj).get("extents")
        if not (isinstance(extents, list) and len(extents) == 3):
            raise DataError(f"{ds.path}: object {obj!r} has no extents in its attrs")
        self.object = ds.read(obj)
        wc = self.workcell
        xyz = [wc.object_xyz[0], wc.object_xyz[1], wc.table_top_z + float(extents[2]) / 2]
        self.placement = Placement(np.array(xyz, dtype=np.float64))
        return Placed(obj, extents_of(extents))

    def wrist_in_object(self) -> Pose:
        base = wrist_joints_to_pose(self.arm.joint_state().position)
        return self.placement.to_object(base)


def fake_rig(ctx: DeviceContext) -> FakeRig:
    def make() -> FakeRig:
        rig = FakeRig(ctx)
        ctx.add_place(rig.place, lambda: rig.placement)
        ctx.lock(FAKE)
        return rig

    return ctx.shared(FAKE, make)


def nearest_grasp(grasps: ObjectGrasps, pose: Pose, match_m: float, match_deg: float) -> int | None:
    """Index of the stored grasp whose wrist pose is nearest `pose`, if within the bounds."""
    if grasps.n_grasps == 0:
        return None
    poses = np.asarray(grasps.poses, dtype=np.float64).reshape(-1, 7)
    d = np.linalg.norm(poses[:, :3] - pose.xyz, axis=1)
    dots = np.clip(np.abs(poses[:, 3:] @ pose.quat), 0.0, 1.0)
    ang = np.degrees(2 * np.arccos(dots))
    ok = (d <= match_m) & (ang <= match_deg)
    if not ok.any():
        return None
    score = np.where(ok, d / max(match_m, 1e-9) + ang / max(match_deg, 1e-9), np.inf)
    return int(np.argmin(score))


class FakeHand(Hand):
    def __init__(self, rig: FakeRig, cfg: FakeHandConfig) -> None:
        self.rig, self.cfg = rig, cfg
        self.stop_latch = StopLatch()
        self._preshape = 0.0
        self._closed = False
        self.closes = 0
        self.closing = threading.Event()  # set once a guarded close is under way (for tests)

    def connect(self) -> None:
        pass

    def disconnect(self) -> None:
        pass

    def open(self) -> None:
        self._closed = False

    def preshape(self, angle: float) -> None:
        self.stop_latch.check("preshape")
        a = float(angle)
        if not 0.0 <= a <= 1.6:
            raise ValueError(f"preshape {a} rad is outside 0..1.6")
        self._preshape = a

    def guarded_close(self) -> Grasp:
        self.stop_latch.check("guarded close")
        self.closing.set()
        if self.cfg.close_s > 0 and self.stop_latch.wait(self.cfg.close_s):
            self.stop_latch.check("guarded close")
        self.closes += 1
        self._closed = True
        obj = self.rig.object
        i = None
        if obj is not None:
            i = nearest_grasp(obj, self.rig.wrist_in_object(), self.cfg.match_m, self.cfg.match_deg)
        if obj is None or i is None:
            return Grasp(
                np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros(N_FINGERS), self._preshape
            )
        g = obj.grasps[i]
        return Grasp(g.sensor_ids, g.xyz, g.pressures, g.finger_angles, self._preshape)

    def state(self) -> HandState:
        return HandState(
            pressures=np.zeros(N_SENSORS),
            contact=np.zeros(N_SENSORS, dtype=bool),
            finger_angles=np.zeros(N_FINGERS),
            preshape=self._preshape,
            stamp=time.monotonic(),
        )

    def stop(self) -> None:
        self.stop_latch.set()

    def clear_stop(self) -> None:
        self.stop_latch.clear()
