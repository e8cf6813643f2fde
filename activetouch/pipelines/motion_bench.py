"""Baxter motion benchmark: IK success and time, collision check time, ruckig time, training-grid
reachability at the default placement, planning time and robot seconds per grasp-to-grasp move.

    .venv/bin/python -m activetouch bench motion [--targets 1000] [--moves 100] [--json FILE]

IK targets are the hand poses of random collision-free configurations (reachable by
construction); the grid is the shared training grid of the paper's 7 objects, each object at
the default Baxter placement. Moves go between random pairs of each object's reachable grid
poses, executed on an in-memory arm; every executed trajectory is re-checked (robot and hand
against themselves and the table) at 1 kHz: `colliding_executions` counts those that touch.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from activetouch.config import GridConfig
from activetouch.errors import UnreachableError
from activetouch.fakes.memory_arm import MemoryArm
from activetouch.interfaces import Pose
from activetouch.objects.library import PAPER_SIM_OBJECTS, ObjectLibrary
from activetouch.planning.grid import shared_grid
from activetouch.planning.motion.baxter import (
    BAXTER_TABLE_CENTER,
    BAXTER_TABLE_SIZE,
    BaxterWristMotion,
    baxter_placement,
)
from activetouch.planning.motion.collision import CollisionScene
from activetouch.planning.motion.ik import IKSolver, SeedTable
from activetouch.planning.motion.robot import load_arm
from activetouch.planning.motion.timing import rest_to_rest


def pct(a: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(a), q)) if a else float("nan")


def random_free(scene: CollisionScene, n: int, rng: np.random.Generator) -> np.ndarray:
    arm = scene.arm
    out = []
    while len(out) < n:
        q = rng.uniform(arm.lower, arm.upper)
        if not scene.in_collision(q, True):
            out.append(q)
    return np.array(out)


def object_specs(names: tuple[str, ...]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (extents, hull points of all collision meshes) of the builtin objects."""
    # deferred: trimesh takes 0.8 s to import
    import trimesh

    root = Path(tempfile.gettempdir()) / "activetouch-bench-objects"
    lib = ObjectLibrary(root)
    lib.ensure_builtins(list(names))
    out = {}
    for n in names:
        spec = lib.get(n)
        pts = np.vstack([trimesh.load(p, force="mesh").vertices for p in spec.collision_meshes])
        out[n] = (spec.extents, pts * spec.scale)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--targets", type=int, default=1000)
    ap.add_argument("--moves", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=str, default="")
    ap.add_argument(
        "--objects",
        default=",".join(PAPER_SIM_OBJECTS),
        help="builtin objects whose shared grid is checked (default: the paper's 7)",
    )
    args = ap.parse_args(argv)
    # deferred: pinocchio only for arm kinematics and motion
    import pinocchio as pin

    rng = np.random.default_rng(args.seed)
    t = time.perf_counter()
    model = load_arm()
    load_s = time.perf_counter() - t
    scene = CollisionScene(model, BAXTER_TABLE_CENTER, BAXTER_TABLE_SIZE)

    # Collision check time over random configurations (free ones: the full query).
    qs = random_free(scene, 2000, rng)
    coll_us = []
    for q in qs:
        t = time.perf_counter()
        scene.in_collision(q, True)
        coll_us.append((time.perf_counter() - t) * 1e6)

    # IK on FK targets of random collision-free configurations, warm start at the ready pose.
    seeds = SeedTable.random(model, 20000, seed=args.seed)
    ik = IKSolver(model, seeds)
    data = model.model.createData()
    targets = []
    for q in random_free(scene, args.targets, rng):
        pin.forwardKinematics(model.model, data, q)
        targets.append(pin.updateFramePlacement(model.model, data, model.hand_frame).copy())
    ik_ms, ik_ok, attempts = [], 0, []
    for tg in targets:
        t = time.perf_counter()
        sol = ik.solve(tg, model.ready)
        ik_ms.append((time.perf_counter() - t) * 1e3)
        attempts.append(ik.stats.attempts)
        ik_ok += sol is not None
    ik_cold = IKSolver(model, None)
    cold_ok, cold_ms = 0, []
    for tg in targets[:200]:
        t = time.perf_counter()
        cold_ok += ik_cold.solve(tg, model.ready) is not None
        cold_ms.append((time.perf_counter() - t) * 1e3)

    # ruckig.
    ruck_us = []
    for a, b in zip(qs[:500], qs[500:1000], strict=True):
        t = time.perf_counter()
        rest_to_rest(a, b, model.velocity, np.full(7, 1.5), np.full(7, 10.0))
        ruck_us.append((time.perf_counter() - t) * 1e6)

    # Grid reachability and grasp-to-grasp moves, per object at the default placement.
    names = tuple(n.strip() for n in args.objects.split(",") if n.strip())
    unknown = sorted(set(names) - set(PAPER_SIM_OBJECTS))
    if unknown or not names:
        print(
            f"error: --objects: not builtin objects: {unknown or args.objects!r}", file=sys.stderr
        )
        return 2
    specs = object_specs(names)
    grid = shared_grid({n: s[0] for n, s in specs.items()}, GridConfig())
    arm = MemoryArm(model.joint_names, model.limits(1.5), model.ready)
    reach: dict[str, int] = {}
    reach_s: dict[str, float] = {}
    plan_ms, robot_s, rrt, lift, unreachable, colliding, moves = [], [], 0, 0, 0, 0, 0
    # Planned duration over the planner's travel-time estimate (1: a straight move).
    travel_ratio: list[float] = []
    per_obj = max(1, args.moves // len(specs))
    for name, (ext, hull) in specs.items():
        pl = baxter_placement(float(ext[2]))
        wm = BaxterWristMotion(arm, pl, model=model, object_extents=ext, object_hull=hull)
        t = time.perf_counter()
        ok = wm.reachable(grid.poses)
        reach_s[name] = time.perf_counter() - t
        reach[name] = int(ok.sum())
        idx = np.nonzero(ok)[0]
        if len(idx) < 2:
            continue
        arm.set_q(model.ready)
        wm.move_to(_pose(grid.poses[idx[0]]))
        at = int(idx[0])
        for _ in range(per_obj):
            j = int(rng.choice(idx))
            t = time.perf_counter()
            try:
                plan = wm.plan(_pose(grid.poses[j]))
            except UnreachableError:
                unreachable += 1
                continue
            plan_ms.append((time.perf_counter() - t) * 1e3)
            est = float(wm.travel_times(grid.poses[[at, j]])[0, 1])
            if j != at and est > 0:
                travel_ratio.append(plan.duration_s / est)
            arm.execute(plan.trajectory)
            at = j
            moves += 1
            robot_s.append(plan.duration_s)
            rrt += plan.used_rrt
            lift += int(plan.stages.get("via_lift", 0.0))
            colliding += _collides(scene, plan)
    out = {
        "model_load_s": load_s,
        "ik_targets": len(targets),
        "ik_success_rate": ik_ok / len(targets),
        "ik_ms_median": pct(ik_ms, 50),
        "ik_ms_p95": pct(ik_ms, 95),
        "ik_attempts_mean": float(np.mean(attempts)),
        "ik_no_seed_table_success_rate": cold_ok / len(cold_ms),
        "ik_no_seed_table_ms_median": pct(cold_ms, 50),
        "collision_us_median": pct(coll_us, 50),
        "collision_us_p95": pct(coll_us, 95),
        "ruckig_us_median": pct(ruck_us, 50),
        "grid_poses": len(grid),
        "grid_reachable": reach,
        "grid_reachable_fraction": {k: v / len(grid) for k, v in reach.items()},
        "grid_reachability_s": reach_s,
        "moves": moves,
        "moves_unreachable": unreachable,
        "moves_rrt": rrt,
        "moves_via_lift": lift,
        "plan_ms_median": pct(plan_ms, 50),
        "plan_ms_p95": pct(plan_ms, 95),
        "robot_s_per_move_median": pct(robot_s, 50),
        "robot_s_per_move_p95": pct(robot_s, 95),
        "travel_estimate_ratio_median": pct(travel_ratio, 50),
        "travel_estimate_ratio_p95": pct(travel_ratio, 95),
        "travel_estimate_exact_share": (
            float(np.mean(np.abs(np.array(travel_ratio) - 1.0) < 1e-6)) if travel_ratio else None
        ),
        "colliding_executions": colliding,
    }
    print(json.dumps(out, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


def _pose(p: np.ndarray):

    return Pose.from_array(p)


def _collides(scene: CollisionScene, plan) -> bool:
    """Re-check an executed trajectory at 1 kHz with no clearance (robot, hand, table; not the
    object, which the approach must touch)."""
    segs = plan.trajectory
    times = np.arange(0.0, float(segs.times[-1]), 0.001)
    pos = np.array([np.interp(times, segs.times, segs.positions[:, j]) for j in range(7)]).T
    return any(scene.in_collision(q, False) for q in pos)


if __name__ == "__main__":
    raise SystemExit(main())
