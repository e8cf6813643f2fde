"""`activetouch bench sim [--json FILE]`: speed of the PyBullet twin, headless, one core.

Sections (each a function returning a dict of figures, run by `main` in `SECTIONS` order):
- grasps: guarded enclosure grasps per second at random wrist poses around one object (a
  primitive sphere by default, or a library object), palm towards its centre, random roll and
  preshape (0 or 0.8). Reports the close alone and the whole cycle (open, preshape, move_wrist
  with its collision check, close; unreachable poses included), contacts per grasp and
  collision queries per grasp.
- grid: contacts per grasp over the training grid (planning.grid, the [grid] config) of one
  object (`--grid-object`, default the paper's cup): unreachable fraction, mean / median /
  10th and 90th percentile contacts, share of grasps with >= 3 contacts (a triangle), fingers
  touching, the contact-count histogram, grasps per second over the grid.
Builtin library objects are generated into a temporary library unless --data is given.
Peak memory (resident set, getrusage) is reported for the whole run.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import resource
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from activetouch.config import GridConfig, SimConfig, load_config
from activetouch.errors import UnreachableError
from activetouch.interfaces import N_FINGER_SENSORS, SENSORS_PER_FINGER, Pose
from activetouch.objects.library import BUILTIN_OBJECTS, ObjectLibrary
from activetouch.paths import data_dir, objects_dir
from activetouch.planning.grid import look_at_quaternion, training_grid
from activetouch.sim.hand import SimHand
from activetouch.sim.twin import twin_wrist
from activetouch.sim.world import SimArm, SimWorld

PRIMITIVES = {
    "primitive:sphere": ("sphere", 0.06),
    "primitive:cylinder": ("cylinder", (0.04, 0.2)),
    "primitive:box": ("box", (0.07, 0.07, 0.2)),
}
PAD_HEIGHT = 0.0896  # palm pad above the hand frame origin


def random_wrist_poses(
    extents: np.ndarray, n: int, rng: np.random.Generator, max_gap_m: float = 0.05
) -> list[Pose]:
    """Poses on the upper hemisphere around an object with bounding box `extents`, palm
    (hand +z) towards its centre, pad 0..max_gap_m beyond the bounding ellipsoid."""
    ext = np.asarray(extents, dtype=np.float64)
    out: list[Pose] = []
    for _ in range(n):
        el, az = rng.uniform(np.deg2rad(15), np.pi / 2), rng.uniform(0, 2 * np.pi)
        d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        surface = d / np.sqrt(np.sum((d / (ext / 2)) ** 2))
        origin = surface + d * (PAD_HEIGHT + rng.uniform(0.0, max_gap_m))
        out.append(Pose(origin, look_at_quaternion(-d, rng.uniform(-np.pi, np.pi))))
    return out


@contextlib.contextmanager
def _library_root(data: str | None) -> Iterator[Path | None]:
    """The object library to use: the data directory's with --data, else a temporary one
    (builtins are generated there, nothing is written to the user's data)."""
    if data is not None:
        yield objects_dir(data_dir(data))
        return
    with tempfile.TemporaryDirectory(prefix="activetouch-bench-") as tmp:
        yield Path(tmp)


def _place(world: SimWorld, obj: str, data: str | None) -> str:
    if obj in PRIMITIVES:
        kind, size = PRIMITIVES[obj]
        world.place_primitive(kind, size)
        return obj

    with _library_root(data) as root:
        if obj in BUILTIN_OBJECTS:
            assert root is not None
            lib = ObjectLibrary(root)
            lib.ensure_builtins([obj])
        else:  # an imported object lives in the user's library
            lib = ObjectLibrary(objects_dir(data_dir(data)))
        world.place(lib.get(obj))  # loaded into the world: the files may go
    return obj


def contact_statistics(counts: np.ndarray, fingers: np.ndarray) -> dict[str, Any]:
    """Figures of the contacts per grasp (`counts`) and fingers touching per grasp."""
    c = np.asarray(counts, dtype=np.int64)
    if len(c) == 0:
        return {"mean_contacts": 0.0, "grasps_with_3plus_contacts": 0.0}
    return {
        "mean_contacts": float(c.mean()),
        "median_contacts": float(np.median(c)),
        "p10_contacts": float(np.percentile(c, 10)),
        "p90_contacts": float(np.percentile(c, 90)),
        "max_contacts": int(c.max()),
        "grasps_with_3plus_contacts": float(np.mean(c >= 3)),
        "grasps_without_contact": float(np.mean(c == 0)),
        "mean_fingers_touching": float(np.mean(fingers)),
        # grasps with 0, 1, 2, ... contacts
        "contacts_histogram": " ".join(str(int(v)) for v in np.bincount(c)),
    }


def fingers_touching(sensor_ids: np.ndarray) -> int:
    ids = np.asarray(sensor_ids)
    return len(np.unique(ids[ids < N_FINGER_SENSORS] // SENSORS_PER_FINGER))


def bench_grasps(
    cfg: SimConfig,
    obj: str = "primitive:sphere",
    n: int = 300,
    seed: int = 0,
    data: str | None = None,
) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    with SimWorld(cfg) as world:
        arm, hand = SimArm(world), SimHand(world)
        _place(world, obj, data)
        assert world.object is not None
        poses = random_wrist_poses(world.object.extents, n, rng)
        preshapes = rng.choice([0.0, 0.8], size=n)
        # Warm-up (first collision queries build Bullet's caches).
        hand.open()
        twin_wrist(arm).move_to(Pose([0.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0]))
        hand.guarded_close()
        close_s, contacts, queries, unreachable = 0.0, [], [], 0
        t0 = time.perf_counter()
        for pose, pre in zip(poses, preshapes, strict=True):
            hand.open()
            hand.preshape(float(pre))
            try:
                twin_wrist(arm).move_to(pose)
            except UnreachableError:
                unreachable += 1
                continue
            tc = time.perf_counter()
            g = hand.guarded_close()
            close_s += time.perf_counter() - tc
            contacts.append(g.n_contacts)
            assert hand.last_close is not None
            queries.append(hand.last_close.queries)
        total_s = time.perf_counter() - t0
    grasped = len(contacts)
    c = np.asarray(contacts, dtype=np.int64)
    return {
        "object": obj,
        "poses": n,
        "grasped": grasped,
        "unreachable": unreachable,
        "close_per_s": grasped / close_s if close_s > 0 else 0.0,
        "cycle_per_s": n / total_s,
        "grasped_cycle_per_s": grasped / total_s,
        "mean_contacts": float(c.mean()) if grasped else 0.0,
        "grasps_with_3plus_contacts": float(np.mean(c >= 3)) if grasped else 0.0,
        "mean_collision_queries": float(np.mean(queries)) if grasped else 0.0,
    }


def bench_grid(
    cfg: SimConfig,
    grid_cfg: GridConfig,
    obj: str = "cup",
    data: str | None = None,
) -> dict[str, Any]:
    """Training-collection loop (service/collect.py) over `obj`'s grid: contact figures."""
    with SimWorld(cfg) as world:
        arm, hand = SimArm(world), SimHand(world)
        _place(world, obj, data)
        assert world.object is not None
        grid = training_grid(world.object.extents, grid_cfg)
        counts, fingers, unreachable = [], [], 0
        t0 = time.perf_counter()
        for i in range(len(grid)):
            hand.open()
            hand.preshape(float(grid.preshapes[i]))
            try:
                twin_wrist(arm).move_to(Pose.from_array(grid.poses[i]))
            except UnreachableError:
                unreachable += 1
                continue
            g = hand.guarded_close()
            counts.append(g.n_contacts)
            fingers.append(fingers_touching(g.sensor_ids))
        total_s = time.perf_counter() - t0
    n = len(grid)
    return {
        "object": obj,
        "poses": n,
        "grasped": len(counts),
        "unreachable_fraction": unreachable / n if n else 0.0,
        **contact_statistics(np.asarray(counts), np.asarray(fingers)),
        "grasps_per_s": len(counts) / total_s if total_s > 0 else 0.0,
    }


# Sections of the benchmark: name -> function(args, cfg) -> figures. Others (e.g. training
# collection timing) add themselves here.
SECTIONS: dict[str, Callable[[argparse.Namespace, SimConfig], dict[str, Any]]] = {
    "grasps": lambda a, cfg: bench_grasps(cfg, a.object, a.grasps, a.seed, a.data),
    "grid": lambda a, cfg: bench_grid(
        cfg, load_config(a.config, a.set).grid, a.grid_object, a.data
    ),
}


def peak_rss_mb() -> float:
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / (1024.0 * 1024.0) if sys.platform == "darwin" else kb / 1024.0


def _table(results: dict[str, Any]) -> Table:
    table = Table(title="PyBullet twin (headless, one core)")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for section, figures in results.items():
        if not isinstance(figures, dict):
            table.add_row(
                section, f"{figures:,.1f}" if isinstance(figures, float) else str(figures)
            )
            continue
        for key, value in figures.items():
            shown = f"{value:,.2f}" if isinstance(value, float) else str(value)
            table.add_row(f"{section}.{key}", shown)
    return table


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="activetouch bench sim",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", metavar="FILE", type=Path, default=None, help="also write figures")
    p.add_argument("--grasps", type=int, default=300, help="random wrist poses to grasp at")
    p.add_argument(
        "--object",
        default="primitive:sphere",
        help=f"{', '.join(PRIMITIVES)} or a library object name (default primitive:sphere)",
    )
    p.add_argument(
        "--grid-object",
        default="cup",
        help="object of the grid section: a library object or primitive (default cup)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data", default=None, help="data directory (library objects)")
    p.add_argument(
        "--config", default=None, help="TOML config (its [sim] and [grid] sections are used)"
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a setting, e.g. sim.substeps=4",
    )
    p.add_argument("--only", default=None, help=f"comma-separated sections of {list(SECTIONS)}")
    args = p.parse_args(argv)
    cfg = load_config(args.config, args.set).sim
    wanted = list(SECTIONS) if args.only is None else [s.strip() for s in args.only.split(",")]
    unknown = [s for s in wanted if s not in SECTIONS]
    if unknown:
        p.error(f"unknown sections {unknown}; known: {list(SECTIONS)}")
    console = Console()
    results: dict[str, Any] = {}
    for name in wanted:
        with console.status(f"sim bench: {name}..."):
            results[name] = SECTIONS[name](args, cfg)
    results["peak_rss_mb"] = peak_rss_mb()
    console.print(_table(results))
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
        console.print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
