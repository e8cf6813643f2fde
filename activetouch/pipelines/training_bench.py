"""`activetouch bench train`: time to collect and fit the paper's 7 objects in the twin.

Starts from an empty data directory each time (object generation, collection in parallel
processes, fitting), and reports the training grid's size and peak memory."""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from activetouch import paths
from activetouch.config import load_config
from activetouch.objects.library import PAPER_SIM_OBJECTS, ObjectLibrary
from activetouch.pipelines.training import collect, fit_and_save
from activetouch.planning.grid import object_grids

TARGET_S = 300.0  # issue target: collect and fit the 7 paper objects in under 5 minutes


def run(workers: int | None, overrides: list[str], names: list[str] | None = None) -> dict:
    cfg = load_config(None, overrides)
    names = names or list(PAPER_SIM_OBJECTS)
    with tempfile.TemporaryDirectory(prefix="activetouch-bench-") as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        lib = ObjectLibrary(paths.objects_dir(root))
        lib.ensure_builtins(names)
        t_objects = time.perf_counter() - t0
        grids = object_grids({n: lib.get(n).extents for n in names}, cfg.grid)
        grid_poses = sum(len(g) for g in grids.values())
        t1 = time.perf_counter()
        stats = collect(lib, paths.default_dataset(root), names, cfg, workers=workers)
        t_collect = time.perf_counter() - t1
        t2 = time.perf_counter()
        model = fit_and_save(paths.default_dataset(root), names, cfg, root / "model")
        t_fit = time.perf_counter() - t2
    total = time.perf_counter() - t0
    grasped = sum(s.grasped for s in stats)
    self_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    child_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return {
        "objects": len(names),
        "grid_poses": grid_poses,
        "grasped": grasped,
        "unreachable": sum(s.skipped for s in stats),
        "objects_s": t_objects,
        "collect_s": t_collect,
        "grasps_per_s_wall": grasped / t_collect if t_collect > 0 else 0.0,
        "fit_s": t_fit,
        "total_s": total,
        "target_s": TARGET_S,
        "pooled_poses": model.observation.n_poses,
        "actions": model.observation.n_actions,
        "peak_rss_mb_main": self_mb,
        "peak_rss_mb_largest_worker": child_mb,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="activetouch bench train", description=__doc__)
    p.add_argument("--workers", type=int, default=None, help="collection processes")
    p.add_argument("--objects", default=",".join(PAPER_SIM_OBJECTS), help="comma-separated")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    p.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = p.parse_args(argv)
    console = Console()
    with console.status("collecting and fitting from scratch"):
        fig = run(args.workers, args.set, [n for n in args.objects.split(",") if n])
    table = Table(title="training in the twin, from an empty data directory")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for k, v in fig.items():
        table.add_row(k, f"{v:,.2f}" if isinstance(v, float) else str(v))
    console.print(table)
    if args.json:
        args.json.write_text(json.dumps(fig, indent=2) + "\n")
    return 0
