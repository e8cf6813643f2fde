"""`activetouch bench service [--json FILE]`: what going through the daemon costs.

For each object x seed, the same recognition twice, interleaved:

- **in-process**: `recognize_in_twin` (a fresh twin per run, hand and arm called directly);
- **in-process, reused twin**: the same session on one twin kept across runs (the object
  placed as the daemon's sim node places it): the in-process run without the cost of building
  a twin, so daemon minus this is what Zenoh and the daemon add;
- **daemon**: ``activetouch serve --sim`` started as a subprocess on a free 127.0.0.1 port
  with the same data directory and configuration, asked over Zenoh by `DaemonClient` (the
  daemon places the object in its one twin and drives hand and arm through their nodes).

Figures per run: request-to-first-progress latency (the call until the first grasp's
progress arrives) and end-to-end time (the call until the result is in the caller's hands),
plus whether all runs made the same grasps and gave the same answer (they should: same
seed). The overhead is the daemon's total time over the in-process total, in per cent
(target <= 5 %); the transport overhead is the daemon's over the reused-twin run's. One
warm-up run of each precedes the measurements (numba caches, imports); each object x seed is
run ``--repeat`` times (interleaved) and the fastest of each kind kept, since other processes
on the machine only ever add time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from activetouch import paths
from activetouch.config import load_config
from activetouch.errors import ConfigError
from activetouch.objects.library import ObjectLibrary
from activetouch.pipelines.evaluation import parse_seeds
from activetouch.planning.policies import POLICY_NAMES
from activetouch.session.local import load_trained, model_path, recognize_in_twin
from activetouch.session.loop import RecognitionSession, policy_for
from activetouch.transport.messages import RecognizeRequest

TARGET_OVERHEAD_PCT = 5.0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="activetouch bench service", description=__doc__)
    p.add_argument("--data", metavar="DIR", default=None, help="data directory (with a model)")
    p.add_argument("--model", metavar="DIR", default=None, help="model directory")
    p.add_argument("--config", metavar="FILE", default=None)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="S.K=V")
    p.add_argument("--objects", default=None, help="comma-separated (default: the model's)")
    p.add_argument("--seeds", default="0-2", help="e.g. 0-4 or 1,3 (default 0-2)")
    p.add_argument("--policy", default="tree", choices=POLICY_NAMES)
    p.add_argument("--max-moves", type=int, default=None)
    p.add_argument("--repeat", type=int, default=3, help="runs per object and seed (best kept)")
    p.add_argument("--json", metavar="FILE", default=None, help="also write the figures as JSON")
    return p


def _best(runs: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        **runs[0],
        "first_s": min(r["first_s"] for r in runs),
        "total_s": min(r["total_s"] for r in runs),
    }


def _median(xs: list[float]) -> float:
    return float(statistics.median(xs)) if xs else float("nan")


def main(argv: list[str] | None = None) -> int:
    # deferred: loads zenoh
    from activetouch.daemon.client import local_daemon, open_client

    # deferred: loads pybullet
    from activetouch.sim.twin import open_twin

    args = _parser().parse_args(argv)
    console = Console(stderr=True)
    cfg = load_config(args.config, args.overrides)
    root = paths.data_dir(args.data)
    mdir = model_path(root, args.model, cfg.hand.family)
    model = load_trained(mdir)  # "no model ... train one first" before anything starts
    library = ObjectLibrary(paths.objects_dir(root))
    objects = args.objects.split(",") if args.objects else list(model.class_names)
    for name in objects:
        library.get(name)  # unknown object: DataError now, not in the middle
    seeds = parse_seeds(args.seeds)
    if args.repeat < 1:
        raise ConfigError(f"--repeat must be >= 1, got {args.repeat}")
    max_moves = args.max_moves or cfg.session.max_moves
    if max_moves < 1:
        raise ConfigError(f"--max-moves must be >= 1, got {max_moves}")

    def local(obj: str, seed: int) -> dict[str, Any]:
        first: list[float] = []
        t0 = time.perf_counter()
        res = recognize_in_twin(
            model,
            library,
            obj,
            args.policy,
            seed,
            cfg,
            max_moves=max_moves,
            on_progress=lambda _ev: first or first.append(time.perf_counter() - t0),
        )
        total = time.perf_counter() - t0
        return {"first_s": first[0], "total_s": total, "labels": res.labels, "poses": res.pose_ids}

    def reused(twin: Any, obj: str, seed: int) -> dict[str, Any]:
        spec = library.get(obj)
        first: list[float] = []
        t0 = time.perf_counter()
        twin.place(spec, seed)
        policy = policy_for(model, args.policy, cfg.planner, cfg.recognition)
        session_cfg = dataclasses.replace(cfg.session, max_moves=max_moves)
        res = RecognitionSession(
            twin.hand,
            twin.wrist,
            model,
            policy,
            session_cfg,
            np.random.default_rng(seed),
            lambda _ev: first or first.append(time.perf_counter() - t0),
            support_z=twin.support_z,
            recognition=cfg.recognition,
            library=library,
        ).run()
        total = time.perf_counter() - t0
        return {"first_s": first[0], "total_s": total, "labels": res.labels, "poses": res.pose_ids}

    def remote(client: Any, obj: str, seed: int) -> dict[str, Any]:
        first: list[float] = []
        # Not recorded: the in-process runs it is compared with write no recording either
        # (docs/recordings.md measures what recording costs).
        req = RecognizeRequest(
            policy=args.policy, max_moves=max_moves, seed=seed, object=obj, record=False
        )
        t0 = time.perf_counter()
        res = client.recognize(
            req,
            on_progress=lambda _ev: first or first.append(time.perf_counter() - t0),
            timeout=cfg.service.request_timeout_s,
        )
        total = time.perf_counter() - t0
        return {
            "first_s": first[0] if first else float("nan"),
            "total_s": total,
            "labels": list(res.labels),
            "poses": list(res.pose_ids),
        }

    serve_args = ["--model", str(mdir)]
    if args.config:
        serve_args += ["--config", args.config]
    for o in args.overrides:
        serve_args += ["--set", o]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        console.print(f"starting the daemon (data {root}) ...")
        with (
            local_daemon(root, args=serve_args, log=Path(tmp) / "daemon.log") as d,
            open_client([d.endpoint], d.robot, timeout=cfg.service.node_timeout_s) as client,
            open_twin(None, cfg.sim, workcell=cfg.workcell) as twin,
        ):
            console.print(f"daemon pid {d.proc.pid} on {d.endpoint}; warming up ...")
            local(objects[0], seeds[0])
            reused(twin, objects[0], seeds[0])
            remote(client, objects[0], seeds[0])
            for obj in objects:
                for seed in seeds:
                    # Best of --repeat, interleaved: other processes on the machine only
                    # ever add time, so the minimum is the least disturbed measurement.
                    runs = [
                        (local(obj, seed), reused(twin, obj, seed), remote(client, obj, seed))
                        for _ in range(args.repeat)
                    ]
                    a, c, b = (_best([r[i] for r in runs]) for i in range(3))
                    same = all(
                        x["labels"] == runs[0][0]["labels"] and x["poses"] == runs[0][0]["poses"]
                        for r in runs
                        for x in r
                    )
                    rows.append(
                        {
                            "object": obj,
                            "seed": seed,
                            "grasps": len(a["labels"]),
                            "same_result": same,
                            "in_process_first_s": a["first_s"],
                            "reused_twin_first_s": c["first_s"],
                            "daemon_first_s": b["first_s"],
                            "in_process_total_s": a["total_s"],
                            "reused_twin_total_s": c["total_s"],
                            "daemon_total_s": b["total_s"],
                        }
                    )
                    console.print(
                        f"  {obj:<12} seed {seed:<3} {rows[-1]['grasps']:>2} grasps  "
                        f"in-process {a['total_s'] * 1e3:7.1f} ms  reused twin "
                        f"{c['total_s'] * 1e3:7.1f} ms  daemon {b['total_s'] * 1e3:7.1f} ms",
                        highlight=False,
                    )
    sum_local = sum(r["in_process_total_s"] for r in rows)
    sum_reused = sum(r["reused_twin_total_s"] for r in rows)
    sum_remote = sum(r["daemon_total_s"] for r in rows)
    overhead = 100.0 * (sum_remote - sum_local) / sum_local
    transport = 100.0 * (sum_remote - sum_reused) / sum_reused
    n_grasps = max(1, sum(r["grasps"] for r in rows))
    per_grasp_ms = 1e3 * (sum_remote - sum_reused) / n_grasps
    summary = {
        "runs": len(rows),
        "policy": args.policy,
        "max_moves": max_moves,
        "all_same_result": all(r["same_result"] for r in rows),
        "median_first_ms": {
            k: 1e3 * _median([r[f"{k}_first_s"] for r in rows])
            for k in ("in_process", "reused_twin", "daemon")
        },
        "median_total_ms": {
            k: 1e3 * _median([r[f"{k}_total_s"] for r in rows])
            for k in ("in_process", "reused_twin", "daemon")
        },
        "sum_total_s": {"in_process": sum_local, "reused_twin": sum_reused, "daemon": sum_remote},
        "overhead_pct": overhead,
        "transport_overhead_pct": transport,
        "transport_ms_per_grasp": per_grasp_ms,
        "target_overhead_pct": TARGET_OVERHEAD_PCT,
        "meets_target": overhead <= TARGET_OVERHEAD_PCT,
    }
    out = Console()
    table = Table(title=f"recognition through the daemon vs in-process ({args.policy} policy)")
    table.add_column("figure")
    kinds = ("in_process", "reused_twin", "daemon")
    for head in ("in-process", "reused twin", "daemon"):
        table.add_column(head, justify="right")
    table.add_row(
        "request -> first progress, median (ms)",
        *(f"{summary['median_first_ms'][k]:.1f}" for k in kinds),
    )
    table.add_row(
        "end to end per recognition, median (ms)",
        *(f"{summary['median_total_ms'][k]:.1f}" for k in kinds),
    )
    table.add_row(
        f"end to end, sum over {len(rows)} runs (s)",
        *(f"{summary['sum_total_s'][k]:.3f}" for k in kinds),
    )
    out.print(table)
    verdict = "meets" if summary["meets_target"] else "MISSES"
    out.print(
        f"daemon vs in-process: {overhead:+.1f} % — {verdict} the <= {TARGET_OVERHEAD_PCT:g} % "
        f"target. Daemon vs reused twin (Zenoh + daemon alone): {transport:+.1f} %, "
        f"{per_grasp_ms:+.2f} ms per grasp. Same grasps and answers in every run: "
        f"{summary['all_same_result']}",
        highlight=False,
    )
    if args.json:
        text = json.dumps({"summary": summary, "runs": rows}, indent=2) + "\n"
        if args.json == "-":
            sys.stdout.write(text)
        else:
            Path(args.json).write_text(text)
            out.print(f"wrote {args.json}")
    return 0
