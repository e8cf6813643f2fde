"""The Baxter twin: arm type ``twin-baxter`` (activetouch.devices).

A joint-level `Arm` with Baxter's seven joints that carries the twin's ReFlex hand. The hand
lives in the shared twin world (`sim.devices.TwinRig`, the same one the ``twin`` hand grasps
in): at every checked sample of an executed trajectory the arm computes the ReFlex base pose by
forward kinematics (pinocchio, the motion layer's model and hand mount) and poses the world's
hand there, so a grasp happens where Baxter's hand is.

Checks while executing, at every sample (at most `sample_dt` s of trajectory time apart,
subdivided so that no joint moves more than ``motion.check_step_rad`` and the hand no more
than ``motion.check_step_m`` between samples):

- the robot's links and the hand against themselves and the table, and the robot's links
  (not the hand) against the object: the motion layer's `CollisionScene` (coal), no margin;
- the hand against the table and the real object mesh: the twin world (PyBullet), with the
  same tolerance as the floating twin (``sim.wrist_penetration_tol_m``).

A contact stops the arm at the last free sample and raises `UnreachableError` naming the
pair and the time. A trajectory outside the joint limits (position or velocity), or starting
away from where the arm is, is refused before anything moves. `stop()` from any thread ends
`execute` within one sample with `StoppedError`, and stays in force until `clear_stop()`.

The workcell must put the table and the object where Baxter reaches them (the default
``[workcell]``, object at the origin, is inside Baxter): see ``deploy/baxter-twin.toml``.

This module is light to import (the config class is read by `load_config`): pinocchio, coal
and PyBullet load when a device is made.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from activetouch.clock import SYSTEM_CLOCK, Clock
from activetouch.device_types import ArmConfig
from activetouch.devices import DeviceContext
from activetouch.errors import ActiveTouchError, ConfigError, MotionBlockedError, UnreachableError
from activetouch.interfaces import (
    Arm,
    JointLimits,
    JointState,
    JointTrajectory,
    Pose,
    StopLatch,
)
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.motion.base import Placement
from activetouch.planning.motion.baxter import BaxterWristMotion
from activetouch.planning.motion.collision import CollisionScene
from activetouch.planning.motion.robot import (
    BAXTER_OBJECT_XY,
    BAXTER_TABLE_CENTER,
    BAXTER_TABLE_SIZE,
    BaxterMotionConfig,
    fk,
    hand_pose,
    load_arm,
)
from activetouch.sim.devices import PacedArm, twin_rig

if TYPE_CHECKING:
    from activetouch.config import WorkcellConfig
    from activetouch.planning.motion.base import Placement, WristMotion
    from activetouch.planning.motion.baxter import BaxterWristMotion, MotionPlan
    from activetouch.planning.motion.collision import CollisionScene
    from activetouch.planning.motion.robot import ArmModel
    from activetouch.sim.world import SimWorld

log = logging.getLogger(__name__)

BAXTER_MODEL = "baxter-model"  # shared resource: the pinocchio model (loading takes seconds)
MIN_OBJECT_DISTANCE_M = 0.35  # an object closer to the base frame's z axis is inside Baxter
# The open ReFlex's farthest point from its base frame origin is ~0.2 m (fingertips): beyond
# this from the object's bounding sphere the hand cannot touch it, and the world check is skipped.
HAND_REACH_M = 0.25


@dataclass
class TwinBaxterArmConfig(ArmConfig):
    """``[arm] type = "twin-baxter"``: one Baxter arm in the twin, carrying the twin's hand.
    Its motion settings are ``[arm.motion]`` (`BaxterMotionConfig`); the table and the object
    are the ``[workcell]`` (see ``deploy/baxter-twin.toml``)."""

    simulated: ClassVar[bool] = True

    motion: BaxterMotionConfig = field(default_factory=BaxterMotionConfig)
    # Wall seconds per trajectory second (1: real time); 0 runs as fast as it can.
    time_scale: float = 0.0
    # Trajectory seconds between checked samples (issue 11: at most 10 ms).
    sample_dt: float = 0.01
    # The trajectory's first point may be this far (rad, any joint) from where the arm is.
    start_tolerance_rad: float = 0.05

    def check(self) -> None:
        self.motion.check()
        if not (np.isfinite(self.time_scale) and self.time_scale >= 0):
            raise ConfigError(f"arm.time_scale must be >= 0, got {self.time_scale}")
        if not 0 < self.sample_dt <= 0.01:
            raise ConfigError(f"arm.sample_dt must be in (0, 0.01] s, got {self.sample_dt}")
        if not self.start_tolerance_rad > 0:
            raise ConfigError("arm.start_tolerance_rad must be positive")

    def default_workcell(self) -> dict[str, Any]:
        """The motion layer's measured Baxter workcell (deploy/baxter-twin.toml): the default
        one has the table at the base frame's origin, inside Baxter."""
        top = BAXTER_TABLE_CENTER[2] + BAXTER_TABLE_SIZE[2] / 2
        return {
            "table_center": list(BAXTER_TABLE_CENTER),
            "table_size": list(BAXTER_TABLE_SIZE),
            "object_xyz": [*BAXTER_OBJECT_XY, top + 0.05],  # z: a 0.1 m object's centre
            "object_yaw_deg": 0.0,
        }

    def make(self, ctx: DeviceContext) -> Arm:

        self.check()
        check_object_xy(ctx.cfg.workcell)  # before seconds of loading
        rig = twin_rig(ctx)
        model = baxter_model(ctx, self.motion)
        check_workcell(ctx.cfg.workcell, model)
        arm = TwinBaxterArm(rig.world, model, self, ObjectShapes(rig.library_root))
        # Every `sim/place` also brings the arm home (a fresh twin's state), so a recognition
        # repeats an in-process run exactly.
        rig.after_place.append(arm.home)
        return PacedArm(arm, ctx.cfg.service.sim_motion_delay_s)

    def make_wrist(self, arm: Arm, ctx: DeviceContext) -> WristMotion:

        rig = twin_rig(ctx)
        return make_twin_wrist(
            arm,
            rig.world,
            baxter_model(ctx, self.motion),
            self.motion,
            ObjectShapes(rig.library_root),
        )


def baxter_model(ctx: DeviceContext, cfg: BaxterMotionConfig) -> ArmModel:
    """The arm model, loaded once per process and configuration (seconds of mesh loading
    that every recognition of an `eval` would pay again), shared by the context's devices."""
    return ctx.shared(BAXTER_MODEL, lambda: _load_arm(json.dumps(dataclasses.asdict(cfg))))


@functools.lru_cache(maxsize=4)
def _load_arm(cfg_json: str) -> ArmModel:

    return load_arm(BaxterMotionConfig(**json.loads(cfg_json)))


# Solved goals per scene (object, placement, table, motion settings), kept for the process:
# an evaluation places the same object at the same spot run after run.
_GOALS: dict[str, dict] = {}


def check_object_xy(workcell: WorkcellConfig) -> None:
    """ConfigError if the workcell's object stands inside Baxter (the default workcell's does)."""
    xy = np.asarray(workcell.object_xyz[:2], dtype=np.float64)
    if float(np.linalg.norm(xy)) < MIN_OBJECT_DISTANCE_M:
        raise ConfigError(
            f"workcell.object_xyz {list(workcell.object_xyz)} is inside Baxter (within "
            f"{MIN_OBJECT_DISTANCE_M} m of its base frame's z axis): the twin-baxter arm needs a "
            "Baxter workcell, e.g. `--config deploy/baxter-twin.toml`"
        )


def check_workcell(workcell: WorkcellConfig, model: ArmModel) -> None:
    """ConfigError if the workcell cannot be Baxter's: the object inside the robot, or the
    table through the arm at its ready pose."""

    check_object_xy(workcell)
    scene = CollisionScene(model, workcell.table_center, workcell.table_size)
    if scene.in_collision(model.ready, False):
        pairs = scene.colliding_pairs(model.ready, False)
        raise ConfigError(
            f"the workcell's table touches Baxter at its ready pose ({pairs[:3]}): move "
            "workcell.table_center / table_size (see deploy/baxter-twin.toml)"
        )


# ---------------------------------------------------------------------------- the object


@functools.lru_cache(maxsize=64)
def library_hull(root: str, name: str, extents: tuple[float, ...]) -> np.ndarray | None:
    """Hull points (object frame) of a library object's collision meshes; None if it is not a
    library object (a primitive, a body placed by hand). `extents` only keys the cache (an
    object re-imported under the same name has other extents)."""
    try:
        # deferred: trimesh takes 0.8 s to import
        import trimesh

        spec = ObjectLibrary(Path(root)).get(name)
        pts = [trimesh.load(p, force="mesh").vertices for p in spec.collision_meshes]
        return np.vstack(pts) * float(spec.scale)
    except Exception:  # not in the library, unreadable: the box of its extents stands in
        log.debug("no hull for %r", name, exc_info=True)
        return None


class ObjectShapes:
    """What the motion layer knows of the object the world placed: its shape (the convex hull of
    its collision meshes, or its bounding box) and where it stands."""

    def __init__(self, library_root: Path | str | None) -> None:
        self.library_root = None if library_root is None else str(library_root)

    def of(self, world: SimWorld) -> tuple[Any, np.ndarray | None, np.ndarray | None]:
        """(key, hull points or None, extents or None) of `world`'s object; key changes when
        the object does."""
        obj = world.object
        if obj is None:
            return None, None, None
        size = tuple(float(v) for v in obj.extents)
        root = self.library_root
        hull = None if root is None else library_hull(root, obj.name, size)
        key = (obj.body, obj.name, size, tuple(obj.origin))
        return key, hull, obj.extents.copy()


def world_placement(world: SimWorld) -> Placement:

    return Placement(world.object_origin)


# ---------------------------------------------------------------------------- the arm


def trajectory_in_order(
    trajectory: JointTrajectory, names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(times, positions, velocities or None) with the columns in `names`' order; malformed
    trajectories raise ActiveTouchError."""
    got = tuple(trajectory.names)
    if sorted(got) != sorted(names) or len(got) != len(names):
        raise ActiveTouchError(f"a trajectory for this arm needs the joints {names}; got {got}")
    times = np.asarray(trajectory.times, dtype=np.float64).reshape(-1)
    pos = np.asarray(trajectory.positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape != (len(times), len(names)) or len(times) == 0:
        raise ActiveTouchError(
            f"trajectory positions of shape {pos.shape} do not match {len(times)} times "
            f"x {len(names)} joints"
        )
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(times))):
        raise ActiveTouchError("trajectory holds NaN or infinite values")
    if np.any(np.diff(times) < 0):
        raise ActiveTouchError("trajectory times go backwards")
    order = [got.index(n) for n in names]
    vel = None
    if trajectory.velocities is not None:
        vel = np.asarray(trajectory.velocities, dtype=np.float64).reshape(pos.shape)[:, order]
    return times, pos[:, order], vel


def limit_violations(
    limits: JointLimits, names: tuple[str, ...], q: np.ndarray, v: np.ndarray | None
) -> list[str]:
    """Position and (if given) velocity limit violations, for a refusal message."""
    bad = limits.violations(names, q)
    if v is not None:
        over = np.nonzero(np.any(np.abs(v) > limits.velocity * (1 + 1e-6) + 1e-9, axis=0))[0]
        bad += [f"{names[j]} velocity over its {limits.velocity[j]:.3g} rad/s limit" for j in over]
    return bad


def resample(
    times: np.ndarray, positions: np.ndarray, dt: float, step_rad: float
) -> Iterator[tuple[float, np.ndarray]]:
    """(t, q) along a timed trajectory: every `dt` s of trajectory time and at its end, by
    linear interpolation between its points, with extra samples so no joint moves more than
    `step_rad` between two. The last sample is the last point itself."""
    t_end = float(times[-1])
    grid = np.union1d(np.arange(float(times[0]), t_end, dt), times)
    qs = np.stack([np.interp(grid, times, positions[:, j]) for j in range(positions.shape[1])], 1)
    qs[-1] = positions[-1]
    yield float(grid[0]), qs[0]
    for i in range(1, len(grid)):
        n = max(1, int(np.ceil(np.max(np.abs(qs[i] - qs[i - 1])) / step_rad)))
        for k in range(1, n + 1):
            f = k / n
            q = qs[i] if k == n else qs[i - 1] + (qs[i] - qs[i - 1]) * f
            yield float(grid[i - 1] + (grid[i] - grid[i - 1]) * f), q


class TwinBaxterArm(Arm):
    """Baxter's arm in the twin: follows timed joint trajectories kinematically, checking every
    sample (module docstring), and keeps the twin world's hand at the arm's hand frame."""

    def __init__(
        self,
        world: SimWorld,
        model: ArmModel,
        cfg: TwinBaxterArmConfig | None = None,
        shapes: ObjectShapes | None = None,
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:

        self.world = world
        self.model = model
        self.cfg = cfg or TwinBaxterArmConfig()
        self.shapes = shapes or ObjectShapes(None)
        wc = world.workcell
        # No margin: the executed motion is judged on contact, not on the planner's clearance.
        self.scene: CollisionScene = CollisionScene(model, wc.table_center, wc.table_size)
        self._object_key: Any = None
        self._limits = model.limits(self.cfg.motion.acceleration)
        self._data = model.model.createData()
        self._q = model.ready.copy()
        self.clock: Clock = clock
        self.stop_latch = StopLatch(clock)
        self.samples_checked = 0
        self.world_checks = 0  # samples near the object, checked in the world too
        self.sync_hand()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.model.joint_names

    @property
    def limits(self) -> JointLimits:
        return self._limits

    def connect(self) -> None:
        self.sync_hand()

    def disconnect(self) -> None:
        pass  # the world owns the client

    def joint_state(self) -> JointState:
        q = self._q
        return JointState(self.joint_names, q.copy(), np.zeros(len(q)), self.clock.monotonic())

    # ---- the hand in the world ----------------------------------------------------------

    def hand_pose_base(self, q: np.ndarray | None = None) -> Pose:
        """The ReFlex base frame in the robot base frame at `q` (default: now), by pinocchio."""

        return hand_pose(self.model, self._data, self._q if q is None else q)

    def _pose_hand(self, q: np.ndarray) -> None:
        base = self.hand_pose_base(q)
        self.world.set_wrist(Pose(base.xyz - self.world.object_origin, base.quat))

    def sync_hand(self) -> None:
        """Put the world's hand where the arm's hand is (after the world moved it or the
        object)."""
        self._pose_hand(self._q)

    def home(self) -> None:
        """Back to the ready pose at once (a freshly made twin's state; `sim/place` does it)."""
        self._q = self.model.ready.copy()
        self.sync_hand()

    def sync_object(self) -> None:
        """Take the world's object into the collision scene if it changed."""
        key, hull, extents = self.shapes.of(self.world)
        if key != self._object_key:
            placement = world_placement(self.world) if key is not None else None
            self.scene.set_object(placement, hull, extents)
            self._object_key = key

    # ---- checks -------------------------------------------------------------------------

    def hand_xyz(self, q: np.ndarray) -> np.ndarray:
        """The hand frame's origin in the base frame at `q`."""

        return np.array(fk(self.model, self._data, q).translation)

    def near_object(self, hand_xyz: np.ndarray) -> bool:
        """Could the hand (fingers included) reach the object from `hand_xyz`?"""
        obj = self.world.object
        if obj is None:
            return False
        radius = float(np.linalg.norm(obj.extents)) / 2 + HAND_REACH_M
        return float(np.linalg.norm(hand_xyz - obj.origin)) < radius

    def collision_reason(self, q: np.ndarray) -> str | None:
        """Why the arm cannot be at `q` (None if it can): robot links and hand against each
        other and the table, and robot links against the object, by coal; near the object, the
        hand posed there against the table and the object mesh in the world (PyBullet)."""
        if self.scene.in_collision(q, True, hand_object=False):
            pairs = self.scene.colliding_pairs(q, True, hand_object=False)
            return "contact " + ", ".join(f"{a} / {b}" for a, b in pairs)
        if not self.near_object(self.hand_xyz(q)):
            return None
        self._pose_hand(q)
        self.world_checks += 1
        # The arm moves in steps of <= 1 cm: the table's contacts (exact) catch the hand before
        # it could be below it, so the bounding-box test meant for teleports is left out.
        return self.world.collision_reason(below_table=False)

    def execute(self, trajectory: JointTrajectory) -> None:
        """Follow `trajectory` (see the class); blocking."""
        self.stop_latch.check("arm motion")
        names = self.joint_names
        times, q, v = trajectory_in_order(trajectory, names)
        bad = limit_violations(self._limits, names, q, v)
        if bad:
            raise UnreachableError(f"trajectory outside the joint limits: {'; '.join(bad)}")
        gap = float(np.max(np.abs(q[0] - self._q)))
        if gap > self.cfg.start_tolerance_rad:
            raise UnreachableError(
                f"the trajectory starts {gap:.3f} rad from where the arm is "
                f"(tolerance {self.cfg.start_tolerance_rad} rad)"
            )
        self.sync_object()
        self._follow(times, q)

    def _follow(self, times: np.ndarray, q: np.ndarray) -> None:
        cfg = self.cfg
        step_m = cfg.motion.check_step_m
        wall0 = self.clock.monotonic()
        prev_q, prev_x = self._q, self.hand_xyz(self._q)
        done = float(times[0])  # trajectory time of the last free sample
        try:
            for t, qk in resample(times, q, cfg.sample_dt, cfg.motion.check_step_rad):
                if cfg.time_scale > 0:
                    due = wall0 + (t - float(times[0])) * cfg.time_scale - self.clock.monotonic()
                    if due > 0:
                        self.stop_latch.wait(due)  # a stop ends the wait at once
                self.stop_latch.check("arm motion")
                x = self.hand_xyz(qk)
                for qs in hand_steps(prev_q, prev_x, qk, x, step_m):
                    reason = self.collision_reason(qs)
                    self.samples_checked += 1
                    if reason is not None:
                        raise MotionBlockedError(
                            f"arm trajectory blocked at t = {t:.3f} s: {reason}",
                            done - float(times[0]),
                        )
                    self._q = qs
                prev_q, prev_x = qk, x
                done = t
        finally:
            self.sync_hand()  # the hand where the arm stopped (the last free sample)

    def stop(self) -> None:
        self.stop_latch.set()

    def clear_stop(self) -> None:
        self.stop_latch.clear()


def hand_steps(
    q0: np.ndarray, x0: np.ndarray, q1: np.ndarray, x1: np.ndarray, step_m: float
) -> list[np.ndarray]:
    """Configurations from `q0` (excluded) to `q1` (included) on the straight joint line, as
    many as keep the hand (at `x0`, `x1`) about `step_m` apart between two."""
    n = max(1, int(np.ceil(float(np.linalg.norm(x1 - x0)) / step_m)))
    if n == 1:
        return [q1]
    return [q0 + (q1 - q0) * (k / n) for k in range(1, n)] + [q1]


# ---------------------------------------------------------------------------- the wrist


def make_twin_wrist(
    arm: Arm,
    world: SimWorld,
    model: ArmModel,
    cfg: BaxterMotionConfig,
    shapes: ObjectShapes,
) -> BaxterWristMotion:
    """`BaxterWristMotion` on the twin's arm whose placement and object shape follow the twin
    world (whatever `sim/place` put on the table)."""

    wc = world.workcell

    class TwinBaxterWrist(BaxterWristMotion):
        """The object is where the world put it, with the shape of what it put there: a given
        placement is ignored (the world knows better), the scene follows the world."""

        def __init__(self) -> None:
            super().__init__(
                arm, world_placement(world), wc.table_center, wc.table_size, cfg, model
            )
            self.world = world
            self._object_key: Any = None
            self.sync_object()

        def set_placement(self, placement: Placement) -> None:
            self.sync_object()

        def sync_object(self) -> None:
            key, hull, extents = shapes.of(world)
            if key == self._object_key:
                return
            self._object_key = key
            self.placement = world_placement(world)
            self.scene.set_object(self.placement if key is not None else None, hull, extents)
            scene = (
                None if key is None else key[1:],  # the body id changes with every world
                self.placement.xyz.tolist(),
                self.placement.yaw_rad,
                list(wc.table_center),
                list(wc.table_size),
                dataclasses.asdict(cfg),
            )
            self._goals = _GOALS.setdefault(repr(scene), {})
            self.last_plan = None

        def plan(self, pose: Pose, q_start: np.ndarray | None = None) -> MotionPlan:
            self.sync_object()
            return super().plan(pose, q_start)

        def reachable(self, poses_object: np.ndarray) -> np.ndarray:
            """The motion layer's verdict, and the open hand at the pose clear of the table
            and the real object mesh (the floating twin's check: the motion layer sees the
            object's hull, and not at the goal, where a grasp touches it)."""
            self.sync_object()
            poses = np.atleast_2d(poses_object)
            ok = super().reachable(poses)
            for i in np.flatnonzero(ok):
                if world.check_hand_pose(Pose.from_array(poses[i])) is not None:
                    ok[i] = False
            return ok

    return TwinBaxterWrist()
