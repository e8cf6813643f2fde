"""`activetouch bench planner [--json FILE]`: speed of the tree search (paper Sec. VI-C).

On a synthetic observation model with the paper's size (1064 pooled poses, so 1063 actions
per node, 7 classes, 1000-bin histograms, realistic sparsity: see `synthetic.py`) and its
linear one-vs-rest classifier kernel, for horizons T = 1, 5, 20:

- ``sims_per_s``: simulations per second inside trees of ``--sims`` simulations (median over
  ``--repeats`` trees from different roots);
- ``tree_ms_100_sims``: wall time of one whole 100-simulation search as the planner calls it
  (argument checks, tree reset, simulations, path extraction), median over 20 trees;
- ``peak_tree_bytes``: the preallocated tree arrays of the ``--sims`` tree plus the search's
  working copies (histogram, pose mask) — all the search allocates.

Numba compilation is excluded: every horizon is warmed up before it is timed (compiled code
is also cached on disk). Everything runs on one core (numba without parallel loops).
``--compare`` adds two measurements of what the implementation choices buy at T = 5: the same
search with a full ``kernel_proba`` for every p(y | h) instead of incremental scores, and the
same Python code with numba disabled (NUMBA_DISABLE_JIT=1, in a subprocess).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from activetouch.planning.mcts import TreeSearch
from activetouch.planning.policies import OBJECTIVES
from activetouch.planning.synthetic import SyntheticProblem, synthetic_problem

# Paper Sec. VI-C (3.6 GHz Xeon, 1063 actions per node): seconds per simulation.
PAPER_SECONDS_PER_SIM = {1: 0.02, 5: 0.1, 20: 0.5}
HORIZONS = (1, 5, 20)


def make_problem(n_poses: int, n_classes: int, seed: int) -> SyntheticProblem:
    return synthetic_problem(n_poses, n_classes, rng=np.random.default_rng(seed))


def _root(pr: SyntheticProblem, pose: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    counts, cells = pr.observe(pose)
    return np.array([pose], dtype=np.int64), counts, cells


def measure_rate(
    ts: TreeSearch,
    pr: SyntheticProblem,
    horizon: int,
    sims: int,
    repeats: int,
    rng: np.random.Generator,
) -> tuple[float, dict[str, Any]]:
    """Median simulations per second over `repeats` trees from random roots."""
    rates = []
    sources = np.zeros(3, dtype=np.int64)
    res = None
    for pose in rng.choice(pr.model.n_poses, repeats, replace=False):
        visited, counts, cells = _root(pr, int(pose))
        t0 = time.perf_counter()
        res = ts.search(
            int(pose), visited, counts, cells, horizon=horizon, simulations=sims, rng=rng
        )
        rates.append(sims / (time.perf_counter() - t0))
        sources += res.observation_sources
    assert res is not None
    info = {
        "nodes": res.n_nodes,
        "observation_sources": dict(
            zip(
                ("tally", "marginal", "none"),
                (sources / sources.sum()).round(3).tolist(),
                strict=True,
            )
        ),
    }
    return statistics.median(rates), info


def measure_tree_ms(
    ts: TreeSearch,
    pr: SyntheticProblem,
    horizon: int,
    sims: int,
    rounds: int,
    rng: np.random.Generator,
) -> float:
    times = []
    for pose in rng.choice(pr.model.n_poses, rounds, replace=False):
        visited, counts, cells = _root(pr, int(pose))
        t0 = time.perf_counter()
        ts.search(int(pose), visited, counts, cells, horizon=horizon, simulations=sims, rng=rng)
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def pure_python_rate(
    n_poses: int, n_classes: int, seed: int, horizon: int, sims: int, objective: str
) -> float:
    """Simulations per second of this search with numba disabled (run in a subprocess)."""
    code = (
        "import sys; from activetouch.planning.bench import _pure_child; "
        f"print(_pure_child({n_poses}, {n_classes}, {seed}, {horizon}, {sims}, {objective!r}))"
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return float(out.stdout.strip().splitlines()[-1])


def _pure_child(
    n_poses: int, n_classes: int, seed: int, horizon: int, sims: int, objective: str
) -> float:
    pr = make_problem(n_poses, n_classes, seed)
    ts = TreeSearch(pr.model, pr.kernel, objective=objective)
    visited, counts, cells = _root(pr, 0)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    ts.search(0, visited, counts, cells, horizon=horizon, simulations=sims, rng=rng)
    return sims / (time.perf_counter() - t0)


def run(args: argparse.Namespace, console: Console) -> dict[str, Any]:
    t0 = time.perf_counter()
    pr = make_problem(args.poses, args.classes, args.seed)
    m = pr.model
    build_rss = peak_rss_bytes()
    deg = np.diff(m.edge_ptr)
    console.print(
        f"synthetic model: {m.n_poses} poses, {int(deg.max())} actions per node "
        f"({m.n_actions} distinct actions), {m.n_classes} classes, {m.n_bins} bins, "
        f"{len(m.tally_key)} tally rows, {len(m.marg_key)} marginal rows "
        f"({time.perf_counter() - t0:.1f} s to build)"
    )
    ts = TreeSearch(m, pr.kernel, objective=args.objective)
    rng = np.random.default_rng(args.seed)
    visited, counts, cells = _root(pr, 0)
    t0 = time.perf_counter()
    for horizon in HORIZONS:  # warm-up: numba compilation / cache load, excluded from timings
        ts.search(0, visited, counts, cells, horizon=horizon, simulations=100, rng=rng)
    console.print(f"warm-up (numba compile or cache load): {time.perf_counter() - t0:.2f} s")

    results = []
    for horizon in HORIZONS:
        rate, info = measure_rate(ts, pr, horizon, args.sims, args.repeats, rng)
        tree_ms = measure_tree_ms(ts, pr, horizon, 100, 20, rng)
        ts.search(0, visited, counts, cells, horizon=horizon, simulations=args.sims, rng=rng)
        peak = ts._tree_for(args.sims).nbytes + m.n_bins * 8 + m.n_poses
        paper = PAPER_SECONDS_PER_SIM[horizon]
        results.append(
            {
                "horizon": horizon,
                "actions": int(deg.max()),
                "classes": m.n_classes,
                "sims_per_s": round(rate, 1),
                "tree_ms_100_sims": round(tree_ms, 3),
                "peak_tree_bytes": int(peak),
                "sims_per_tree": args.sims,
                "paper_s_per_sim": paper,
                "speedup_vs_paper": round(rate * paper, 1),
                "observation_sources": info["observation_sources"],
            }
        )
    out: dict[str, Any] = {
        "results": results,
        "model": {
            "poses": m.n_poses,
            "actions_per_node": int(deg.max()),
            "distinct_actions": m.n_actions,
            "classes": m.n_classes,
            "bins": m.n_bins,
            "tally_rows": len(m.tally_key),
            "marginal_rows": len(m.marg_key),
            # What a robot PC holds to plan: the model's arrays (its edges grow as poses^2)
            # and the search's index of them (rows re-keyed by action, cell, class).
            "array_bytes": model_bytes(m),
            "search_index_bytes": int(sum(a.nbytes for a in m.rows_by_action)),
        },
        # Process peaks: after building the synthetic model (a training-time cost on a real
        # library), and at the end, planning included.
        "peak_rss_bytes_after_build": build_rss,
        "peak_rss_bytes": peak_rss_bytes(),
        "objective": args.objective,
        "notes": "numba compile time excluded (warm-up); one core; synthetic model seed "
        f"{args.seed}",
    }
    if args.compare:
        full = TreeSearch(m, pr.kernel, incremental=False, objective=args.objective)
        full.search(0, visited, counts, cells, horizon=5, simulations=100, rng=rng)
        rate_full, _ = measure_rate(full, pr, 5, args.sims, args.repeats, rng)
        rate_inc = next(r["sims_per_s"] for r in results if r["horizon"] == 5)
        py_sims = 200
        rate_py = pure_python_rate(args.poses, args.classes, args.seed, 5, py_sims, args.objective)
        out["compare_T5"] = {
            "numba_incremental_sims_per_s": rate_inc,
            "numba_full_kernel_proba_sims_per_s": round(rate_full, 1),
            "pure_python_sims_per_s": round(rate_py, 2),
            "pure_python_sims": py_sims,
        }
    return out


def model_bytes(model: object) -> int:
    """Bytes of the numpy arrays an observation model holds."""
    return int(sum(v.nbytes for v in vars(model).values() if isinstance(v, np.ndarray)))


def peak_rss_bytes() -> int:
    """This process's peak resident memory so far (Linux reports KiB, macOS bytes)."""

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def print_results(out: dict[str, Any], console: Console) -> None:
    table = Table(title="MCTS planner speed (synthetic model, one core)")
    for col in ("T", "acts", "K", "sims/s", "100-sim tree", "tree arrays", "paper", "speed-up"):
        table.add_column(col, justify="right")
    for r in out["results"]:
        table.add_row(
            str(r["horizon"]),
            str(r["actions"]),
            str(r["classes"]),
            f"{r['sims_per_s']:,.0f}",
            f"{r['tree_ms_100_sims']:.2f} ms",
            f"{r['peak_tree_bytes'] / 1024:,.0f} KiB",
            f"{r['paper_s_per_sim']} s/sim",
            f"{r['speedup_vs_paper']:,.0f}x",
        )
    console.print(table)
    console.print(
        f"acts: actions per node; K: classes; sims/s inside "
        f"{out['results'][0]['sims_per_tree']}-simulation trees; 100-sim tree: one whole search "
        "of 100 simulations; paper: Sec. VI-C. Numba compilation excluded (warmed up first)."
    )
    mb = 1024 * 1024
    console.print(
        f"memory: model arrays {out['model']['array_bytes'] / mb:,.0f} MiB (search index "
        f"{out['model']['search_index_bytes'] / mb:,.0f} MiB more); process peak "
        f"{out['peak_rss_bytes_after_build'] / mb:,.0f} MiB after building the synthetic model, "
        f"{out['peak_rss_bytes'] / mb:,.0f} MiB at the end"
    )
    src = ", ".join(
        f"T={r['horizon']}: "
        + "/".join(f"{r['observation_sources'][k]:.2f}" for k in ("tally", "marginal", "none"))
        for r in out["results"]
    )
    console.print(f"Eq. 4 steps answered by a tally row / a marginal row / nothing: {src}")
    if "compare_T5" in out:
        c = out["compare_T5"]
        console.print(
            f"T = 5: numba + incremental scores {c['numba_incremental_sims_per_s']:,.0f} sims/s, "
            f"numba + full kernel_proba {c['numba_full_kernel_proba_sims_per_s']:,.0f} sims/s, "
            f"pure Python (NUMBA_DISABLE_JIT) {c['pure_python_sims_per_s']:,.1f} sims/s"
        )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="activetouch bench planner", description=__doc__.split("\n")[0]
    )
    p.add_argument("--json", metavar="FILE", default=None, help="also write the figures as JSON")
    p.add_argument("--sims", type=int, default=1000, help="simulations per tree for sims/s")
    p.add_argument("--repeats", type=int, default=5, help="trees per horizon for sims/s")
    p.add_argument("--poses", type=int, default=1064, help="pooled poses (actions per node + 1)")
    p.add_argument("--classes", type=int, default=7)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--objective",
        choices=OBJECTIVES,
        default="anytime",
        help="recognition term: anytime (the default planner), final (the paper's Eq. 1) or "
        "info_gain",
    )
    p.add_argument(
        "--compare",
        action="store_true",
        help="also measure T = 5 without incremental scores and without numba",
    )
    args = p.parse_args(argv)
    console = Console()
    out = run(args, console)
    print_results(out, console)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
        console.print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
