"""`BaxterWristMotion`: an object-frame wrist pose -> IK -> collision-checked path -> ruckig-timed
`JointTrajectory` -> `Arm.execute`.

A move from the current configuration to a grasp pose has up to three parts:

1. retreat: back off along the hand's -z by `approach_m` (the object is ignored: the hand may
   still touch it; the table and the robot are not);
2. transit to the goal's pre-grasp (the goal backed off by `approach_m`), with the object as an
   obstacle; a straight joint-space segment if it is free, else OMPL RRT-Connect;
3. approach the goal (object ignored again: the grasp touches it).

Every segment is checked densely (`check_step_rad`, `check_step_m`) and timed by ruckig as a
phase-synchronised rest-to-rest motion, so the timed motion is the checked one.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field

import numpy as np

from activetouch.errors import MotionBlockedError, UnreachableError
from activetouch.interfaces import Arm, JointTrajectory, Pose
from activetouch.planning.motion.base import Placement, WristMotion
from activetouch.planning.motion.collision import CollisionScene
from activetouch.planning.motion.ik import IKSolver, SeedTable
from activetouch.planning.motion.paths import rrt_connect, segment_free
from activetouch.planning.motion.robot import (
    BAXTER_OBJECT_XY,
    BAXTER_TABLE_CENTER,
    BAXTER_TABLE_SIZE,
    ArmModel,
    BaxterMotionConfig,
    load_arm,
    pose_to_se3,
)

__all__ = ["BAXTER_OBJECT_XY", "BAXTER_TABLE_CENTER", "BAXTER_TABLE_SIZE", "BaxterWristMotion"]
from activetouch.planning.motion.timing import sample, straight_duration, time_path

SEED_TABLE_SIZE = 20000


def table_top(
    center: np.ndarray | tuple[float, ...], size: np.ndarray | tuple[float, ...]
) -> float:
    return float(center[2]) + float(size[2]) / 2


def offset_along_z(target, distance: float):
    """The SE3 `target` moved by `distance` along its own z axis (negative: backwards)."""
    # deferred: pinocchio only for arm kinematics and motion
    import pinocchio as pin

    return target * pin.SE3(np.eye(3), np.array([0.0, 0.0, distance]))


@dataclass
class MotionPlan:
    """A planned move: waypoints, the timed trajectory and what it cost to find."""

    waypoints: np.ndarray  # (m, 7)
    trajectory: JointTrajectory
    duration_s: float
    planning_s: float
    used_rrt: bool
    stages: dict[str, float] = field(default_factory=dict)
    pre_grasp: np.ndarray | None = None  # the goal's pre-grasp: the next move's retreat

    @property
    def goal(self) -> np.ndarray:
        return self.waypoints[-1]


class BaxterWristMotion(WristMotion):
    """Moves a Baxter arm's hand frame to object-frame poses, collision-free."""

    def __init__(
        self,
        arm: Arm,
        placement: Placement,
        table_center: tuple[float, ...] | np.ndarray = BAXTER_TABLE_CENTER,
        table_size: tuple[float, ...] | np.ndarray = BAXTER_TABLE_SIZE,
        cfg: BaxterMotionConfig | None = None,
        model: ArmModel | None = None,
        object_extents: np.ndarray | None = None,
        object_hull: np.ndarray | None = None,
        sample_dt: float = 0.01,
    ) -> None:
        self.cfg = cfg or BaxterMotionConfig()
        self.arm = arm
        self.model = model or load_arm(self.cfg)
        if tuple(arm.joint_names) != self.model.joint_names:
            missing = set(self.model.joint_names) - set(arm.joint_names)
            if missing:
                raise UnreachableError(f"the arm lacks joints {sorted(missing)}")
        self.placement = placement
        self.scene = CollisionScene(
            self.model,
            table_center,
            table_size,
            placement,
            object_hull,
            object_extents,
            clearance_m=self.cfg.clearance_m,
        )
        self.seeds = SeedTable.random(self.model, SEED_TABLE_SIZE, seed=self.cfg.seed)
        self.ik = IKSolver(
            self.model,
            self.seeds,
            tol=self.cfg.ik_tol,
            restarts=self.cfg.ik_restarts,
            seed=self.cfg.seed,
        )
        # A second solver for the nested pre-grasp IK (the goal's solver is mid-search then);
        # few restarts: the pre-grasp is near the goal's solution.
        self.ik_inner = IKSolver(
            self.model, self.seeds, tol=self.cfg.ik_tol, restarts=3, seed=self.cfg.seed + 1
        )
        n = self.model.nq
        self.velocity = self.model.velocity
        self.acceleration = np.full(n, self.cfg.acceleration)
        self.jerk = np.full(n, self.cfg.jerk)
        self.sample_dt = sample_dt
        self.last_plan: MotionPlan | None = None
        # Goal IK per base-frame pose for the current scene: (goal, pre-grasp) or the reason it
        # is unreachable. Filled by `reachable()` and by planning; cleared when the scene changes.
        self._goals: dict[bytes, tuple[np.ndarray, np.ndarray] | str] = {}
        # Robot time spent by this motion layer: executed trajectories (seconds of trajectory
        # time, as the robot takes them) and planning (wall seconds). Readers take differences.
        self.robot_seconds = 0.0
        self.planning_seconds = 0.0
        self.moves = 0
        self.last_motion_s = 0.0  # the last move_to alone (0 if it did not complete)
        self.last_planning_s = 0.0

    # ---- placement and obstacles -------------------------------------------------------

    def set_placement(self, placement: Placement) -> None:
        if same_placement(placement, getattr(self, "placement", None)):
            return  # nothing moved: keep the scene and the solved goals
        self.placement = placement
        self.scene.set_object(placement, self.scene.object_hull, self.scene.object_extents)
        self._goals.clear()
        self.last_plan = None

    def set_object(self, extents: np.ndarray | None = None, hull: np.ndarray | None = None) -> None:
        """The object's shape (box extents or hull points in the object frame)."""
        self.scene.set_object(self.placement, hull, extents)
        self._goals.clear()
        self.last_plan = None

    # ---- planning -----------------------------------------------------------------------

    def current_q(self) -> np.ndarray:
        st = self.arm.joint_state()
        index = {n: i for i, n in enumerate(st.names)}
        return np.array([st.position[index[n]] for n in self.model.joint_names], dtype=np.float64)

    def solve_goal(
        self, pose_base: Pose, q_near: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """IK for a grasp pose (base frame): a configuration that is collision-free with the
        object ignored and has a pre-grasp (`_pre_grasp`); returns (goal, pre-grasp)."""
        target = pose_to_se3(pose_base)
        why = {"collision": 0, "approach": 0}
        pre: dict[int, np.ndarray] = {}

        def accept(q: np.ndarray) -> bool:
            if self.scene.in_collision(q, False):
                why["collision"] += 1
                return False
            p = self._pre_grasp(target, q)
            if p is None:
                why["approach"] += 1
                return False
            pre[id(q)] = p
            return True

        q = self.ik.solve(target, q_near, accept=accept, max_solutions=2)
        if q is None:
            st = self.ik.stats
            if why["approach"]:
                raise UnreachableError(
                    f"no collision-free pre-grasp pose with a free approach for the "
                    f"{why['approach']} collision-free IK solutions "
                    f"({why['collision']} more touch something)"
                )
            if st.converged:
                raise UnreachableError(
                    f"collision at the goal: all {st.converged} IK solutions touch something"
                )
            raise UnreachableError(f"no IK solution ({st.attempts} starts)")
        return q, pre[id(q)]

    def goal_for(self, pose_base: Pose, q_near: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """`solve_goal`, remembered per pose while the scene stays the same (an unreachable
        pose raises its first reason again at once)."""
        key = pose_key(pose_base)
        hit = self._goals.get(key)
        if isinstance(hit, str):
            raise UnreachableError(hit)
        if hit is not None:
            return hit
        try:
            found = self.solve_goal(pose_base, q_near)
        except UnreachableError as e:
            self._goals[key] = str(e)
            raise
        self._goals[key] = found
        return found

    def reachable(self, poses_object: np.ndarray) -> np.ndarray:
        """(n,) bool: which object-frame poses (n, 7) have a collision-free goal and pre-grasp.
        Their solutions are kept for planning (and join the seed table)."""
        ok = np.zeros(len(poses_object), dtype=bool)
        found = []
        q_near = self.model.ready
        for i, p in enumerate(np.atleast_2d(poses_object)):
            base = self.placement.to_base(Pose.from_array(p))
            try:
                q, pre = self.goal_for(base, q_near)
            except UnreachableError:
                continue
            ok[i] = True
            found.extend([q, pre])
        if found:
            self.seeds.add(np.array(found))
        return ok

    def travel_times(self, poses_object: np.ndarray) -> np.ndarray:
        """(n, n) estimated seconds of the move from grasp pose i to grasp pose j (object
        frame, (n, 7)), before planning: the retreat from i's goal to its pre-grasp, a straight
        joint-space transit between the pre-grasps, the approach to j's goal, each timed in
        closed form as ruckig times it (`straight_duration`). NaN where either pose is
        unreachable (call `reachable` first: solutions are reused, not solved here). A path
        that must go round something (a lift, OMPL) takes longer than estimated."""
        poses = np.atleast_2d(poses_object)
        n, nq = len(poses), self.model.nq
        goal, pre = np.full((n, nq), np.nan), np.full((n, nq), np.nan)
        for i, p in enumerate(poses):
            hit = self._goals.get(pose_key(self.placement.to_base(Pose.from_array(p))))
            if hit is not None and not isinstance(hit, str):
                goal[i], pre[i] = hit
        limits = (self.velocity, self.acceleration, self.jerk)
        ends = straight_duration(goal - pre, *limits)  # retreat = approach, reversed
        out = np.empty((n, n))
        for i in range(n):  # row by row: (n, nq) at a time, not (n, n, nq)
            out[i] = ends[i] + straight_duration(pre - pre[i], *limits) + ends
        ok = np.isfinite(goal).all(axis=1)
        out[~ok, :] = np.nan
        out[:, ~ok] = np.nan
        np.fill_diagonal(out, 0.0)
        return out

    def _pre_grasp(self, target, q_goal: np.ndarray) -> np.ndarray | None:
        """The goal backed off along -z, collision-free with the object, near `q_goal`, and
        joined to it by a free straight segment (object ignored)."""
        cfg = self.cfg

        def accept(q: np.ndarray) -> bool:
            return (
                not self.scene.in_collision(q, True)
                and segment_free(
                    self.scene, q, q_goal, False, cfg.check_step_rad, cfg.check_step_m
                )[0]
            )

        for frac in (1.0, 0.5):
            pre = offset_along_z(target, -cfg.approach_m * frac)
            ik = self.ik_inner
            q = ik.solve(pre, q_goal, accept=accept)
            if q is not None:
                return q
        return None

    def plan(self, pose: Pose, q_start: np.ndarray | None = None) -> MotionPlan:
        """Plan a move of the hand to `pose` (object frame) from `q_start` (default: now)."""

        t0 = time.perf_counter()
        cfg = self.cfg
        q0 = self.current_q() if q_start is None else np.asarray(q_start, dtype=np.float64)
        stages: dict[str, float] = {}
        base = self.placement.to_base(pose)
        q_goal, q_pre = self.goal_for(base, q0)
        stages["ik_s"] = time.perf_counter() - t0

        # Retreat from where the hand is now, if possible; else the transit starts here.
        if self.scene.in_collision(q0, False):
            raise UnreachableError(
                f"the start configuration is in collision: {self.scene.colliding_pairs(q0, False)}"
            )
        q_ret = self._retreat(q0)
        stages["ends_s"] = time.perf_counter() - t0

        used_rrt = False
        ok, _ = segment_free(self.scene, q_ret, q_pre, True, cfg.check_step_rad, cfg.check_step_m)
        transit = np.array([q_ret, q_pre]) if ok else self._via_lift(q_ret, q_pre)
        if transit is not None:
            stages["via_lift"] = float(len(transit) > 2)
        else:
            remaining = max(0.05, cfg.ompl_time_s)
            transit = rrt_connect(
                self.scene,
                q_ret,
                q_pre,
                self.model.lower,
                self.model.upper,
                remaining,
                cfg.check_step_rad,
                cfg.check_step_m,
            )
            used_rrt = True
            if transit is None:
                raise UnreachableError(
                    f"no collision-free path to the pre-grasp within {cfg.ompl_time_s:g} s"
                )
        stages["path_s"] = time.perf_counter() - t0
        waypoints = np.vstack([q0[None], transit, q_goal[None]])
        waypoints = _dedupe(waypoints)
        segments = time_path(waypoints, self.velocity, self.acceleration, self.jerk)
        if segments:
            times, pos, vel, acc = sample(segments, self.sample_dt)
        else:  # already there
            times, pos, vel, acc = (np.array([0.0]), q0[None], np.zeros((1, 7)), np.zeros((1, 7)))
        duration = float(times[-1])
        planning = time.perf_counter() - t0
        traj = JointTrajectory(
            names=self.model.joint_names,
            times=times,
            positions=pos,
            velocities=vel,
            accelerations=acc,
            meta={
                "duration_s": duration,
                "planning_s": planning,
                "waypoints": waypoints,
                "rrt": used_rrt,
            },
        )
        plan = MotionPlan(waypoints, traj, duration, planning, used_rrt, stages, q_pre)
        self.last_plan = plan
        return plan

    def _lift(self, q: np.ndarray) -> np.ndarray | None:
        """`q` with the hand raised by `lift_m` in the base frame, orientation kept (IK warm
        started at `q`), collision-free with the object."""
        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        pin.forwardKinematics(self.model.model, self.ik.data, q)
        m = pin.updateFramePlacement(self.model.model, self.ik.data, self.model.hand_frame).copy()
        m.translation = m.translation + np.array([0.0, 0.0, self.cfg.lift_m])
        return self.ik_inner.solve(m, q, accept=lambda c: not self.scene.in_collision(c, True))

    def _via_lift(self, q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray | None:
        """A transit over the top: up from `q_a`, across, down to `q_b` (each straight in joint
        space and checked densely, object counted); None if any part collides. Tried before
        RRT-Connect: most blocked transits are blocked by the object or the table below."""
        if self.cfg.lift_m <= 0:
            return None
        cfg = self.cfg
        up_a = self._lift(q_a)
        up_b = self._lift(q_b) if up_a is not None else None
        if up_a is None or up_b is None:
            return None
        path = np.array([q_a, up_a, up_b, q_b])
        for a, b in itertools.pairwise(path):
            if not segment_free(self.scene, a, b, True, cfg.check_step_rad, cfg.check_step_m)[0]:
                return None
        return path

    def _retreat(self, q0: np.ndarray) -> np.ndarray:
        """Where the move leaves the current grasp for: the hand backed off along -z. Right
        after a planned move that is the goal's pre-grasp (already checked); else solved now.
        Returns `q0` itself when no retreat is needed or possible from a free configuration."""
        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        cfg = self.cfg
        last = self.last_plan
        if (
            last is not None
            and last.pre_grasp is not None
            and np.allclose(q0, last.goal, atol=1e-6)
        ):
            return last.pre_grasp
        if last is not None:
            # Stopped part way along the last move's approach or retreat (a contact the
            # object-blind check could not see): back along that checked line to its free end.
            wp = last.waypoints
            for a, b in ((wp[-1], wp[-2]), (wp[0], wp[1])) if len(wp) >= 2 else ():
                if on_segment(q0, a, b) and not self.scene.in_collision(b, True):
                    return b
        pin.forwardKinematics(self.model.model, self.ik.data, q0)
        now = pin.updateFramePlacement(self.model.model, self.ik.data, self.model.hand_frame)
        back = offset_along_z(now.copy(), -cfg.approach_m)
        q_r = self.ik.solve(back, q0, accept=lambda q: not self.scene.in_collision(q, True))
        if (
            q_r is not None
            and segment_free(self.scene, q0, q_r, False, cfg.check_step_rad, cfg.check_step_m)[0]
        ):
            return q_r
        if self.scene.in_collision(q0, True):
            raise UnreachableError("cannot retreat from the current grasp without a collision")
        return q0

    def move_to(self, pose: Pose) -> None:
        """Plan, then execute on the arm (`StoppedError` from the arm passes through). Counts
        planning seconds always and robot seconds for completed motions."""
        t0 = time.perf_counter()
        self.last_motion_s = 0.0
        try:
            plan = self.plan(pose)
        finally:
            self.last_planning_s = time.perf_counter() - t0
            self.planning_seconds += self.last_planning_s
        try:
            self.arm.execute(plan.trajectory)
        except MotionBlockedError as e:  # the arm moved until the contact: robot time spent
            self.robot_seconds += e.executed_s
            raise
        self.last_motion_s = plan.duration_s
        self.robot_seconds += plan.duration_s
        self.moves += 1


def on_segment(q: np.ndarray, a: np.ndarray, b: np.ndarray, tol: float = 1e-6) -> bool:
    """True if `q` lies on the joint-space segment a -> b (within `tol` rad)."""
    d = b - a
    n2 = float(d @ d)
    if n2 < 1e-18:
        return bool(np.max(np.abs(q - a)) <= tol)
    u = float(np.clip((q - a) @ d / n2, 0.0, 1.0))
    return bool(np.max(np.abs(a + u * d - q)) <= tol)


def pose_key(pose: Pose) -> bytes:
    """A dictionary key for a pose (to 1e-9)."""
    return np.round(pose.as_array(), 9).tobytes()


def same_placement(a: Placement | None, b: Placement | None) -> bool:
    if a is None or b is None:
        return a is b
    return bool(np.array_equal(a.xyz, b.xyz) and a.yaw_rad == b.yaw_rad)


def _dedupe(wp: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    keep = [0] + [i for i in range(1, len(wp)) if np.max(np.abs(wp[i] - wp[i - 1])) > tol]
    return wp[keep]


def baxter_placement(
    object_height: float,
    xy: tuple[float, float] = BAXTER_OBJECT_XY,
    yaw: float = 0.0,
    table_center: tuple[float, ...] = BAXTER_TABLE_CENTER,
    table_size: tuple[float, ...] = BAXTER_TABLE_SIZE,
) -> Placement:
    """The object frame of an object `object_height` tall standing on the Baxter table."""
    z = table_top(table_center, table_size) + object_height / 2
    return Placement(np.array([xy[0], xy[1], z]), yaw)
