"""Policy sweep in the twin: policies x settings x seeds, paired by seed, with 95 % CIs.

Every *arm* is a policy plus configuration overrides, e.g. ``tree`` or
``tree:planner.lam=0,planner.simulations=200``. Each arm runs every (object, seed) through
`activetouch.pipelines.evaluation.run_all` (the same recognition the `eval` command runs, in
parallel processes); runs are paired by (object, seed), which fixes the first random grasp
and the twin's noise. The figure is moves to first correct, with "never" counted as budget
+ 1 (as `eval`'s capped mean). For every arm against every baseline arm the table shows the
mean paired difference (baseline - arm: positive = the arm needs fewer moves) with a 95 %
percentile-bootstrap CI over the pairs, wins/ties/losses and a two-sided sign-test p-value.

Example (the lead's protocol: fixed number of moves, no early stop)::

    ACTIVETOUCH_HOME=/tmp/pq python benchmarks/policy_sweep.py --seeds 0-29 \\
        --arms random,greedy,tree,tree:planner.lam=0 --baselines random,greedy \\
        --objects teapot,mug,cup --set session.confidence=2 --max-moves 15

Tune settings on other seeds (e.g. 100-129) than the ones you report (e.g. 0-19).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from activetouch import paths
from activetouch.config import load_config
from activetouch.pipelines.evaluation import (
    Job,
    make_jobs,
    moves_capped,
    paired_stats,
    parse_seeds,
    run_all,
)
from activetouch.session.local import load_trained, model_path


@dataclass(frozen=True)
class Arm:
    label: str
    policy: str
    overrides: tuple[str, ...]


def parse_arm(text: str) -> Arm:
    """``policy`` or ``policy:section.key=value,section.key=value``."""
    policy, _, rest = text.partition(":")
    overrides = tuple(s.strip() for s in rest.split(",") if s.strip())
    return Arm(text, policy.strip(), overrides)


def moves_table(
    runs: list[dict[str, Any]], arms: list[Arm], budget: int
) -> dict[str, dict[tuple[str, int], int]]:
    """{arm label: {(object, seed): capped moves to first correct}}."""
    out: dict[str, dict[tuple[str, int], int]] = {a.label: {} for a in arms}
    for r in runs:
        out[r["arm"]][(r["object"], r["seed"])] = moves_capped(r, budget)
    return out


def paired_rows(
    table: dict[str, dict[tuple[str, int], int]],
    arms: list[Arm],
    baselines: list[str],
    objects: list[str] | None,
    rng: np.random.Generator,
) -> list[dict[str, Any]]:
    rows = []
    for arm in arms:
        for base in baselines:
            if base == arm.label:
                continue
            keys = sorted(k for k in table[arm.label] if objects is None or k[0] in objects)
            d = np.array([table[base][k] - table[arm.label][k] for k in keys], dtype=float)
            st = paired_stats(d, rng)
            rows.append(
                {
                    "arm": arm.label,
                    "baseline": base,
                    "pairs": len(d),
                    "mean_saved": st.pop("mean"),
                    **st,
                }
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--arms", default="random,greedy,tree", help="comma list of policy[:overrides]")
    ap.add_argument("--arm", action="append", default=[], help="one more arm (may hold commas)")
    ap.add_argument("--baselines", default="random,greedy", help="arm labels to pair against")
    ap.add_argument("--objects", default=None, help="comma-separated (default: the model's)")
    ap.add_argument("--hard", default="teapot,mug,cup", help="subset reported separately")
    ap.add_argument("--seeds", default="0-19")
    ap.add_argument("--max-moves", type=int, default=15)
    ap.add_argument("--set", action="append", default=[], help="override for every arm")
    ap.add_argument("--model", default=None)
    ap.add_argument("--data", default=None)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--json", default=None, help="write runs and the table here")
    args = ap.parse_args(argv)

    console = Console(width=150)
    root = paths.data_dir(args.data)
    model_dir = model_path(root, args.model)
    model = load_trained(model_dir)
    objects = args.objects.split(",") if args.objects else list(model.class_names)
    seeds = parse_seeds(args.seeds)
    # "--arms" splits on commas between arms: an arm's own overrides use ";" there.
    arms = [parse_arm(a.replace(";", ",")) for a in args.arms.split(",") if a.strip()]
    arms += [parse_arm(a) for a in args.arm]
    labels = [a.label for a in arms]
    if len(set(labels)) != len(labels):
        console.print(f"duplicate arms in {labels}")
        return 2
    baselines = [b.replace(";", ",") for b in args.baselines.split(",") if b.strip()]
    for b in baselines:
        if b not in labels:
            console.print(f"baseline {b!r} is not one of the arms {labels}")
            return 2

    jobs: list[Job] = []
    owner: list[str] = []
    for arm in arms:
        cfg = load_config(None, [*args.set, *arm.overrides])
        js = make_jobs(
            model_dir, paths.objects_dir(root), objects, [arm.policy], seeds, args.max_moves, cfg
        )
        jobs += js
        owner += [arm.label] * len(js)
    with Progress(console=console, transient=True) as prog:
        task = prog.add_task("recognitions", total=len(jobs))
        runs = run_all(jobs, args.workers, lambda i, n: prog.update(task, completed=i))
    for r, label in zip(runs, owner, strict=True):
        r["arm"] = label

    budget = args.max_moves
    table = moves_table(runs, arms, budget)
    rng = np.random.default_rng(0)

    summary = Table(title=f"moves to first correct ({len(seeds)} seeds, never = {budget + 1})")
    for col in ("arm", "objects", "mean", "median", "final correct", "never"):
        summary.add_column(col)
    hard = [o for o in args.hard.split(",") if o in objects] if args.hard else []
    subsets: list[tuple[str, list[str] | None]] = [("all", None)]
    if hard and set(hard) != set(objects):
        subsets.append(("hard", hard))
    for arm in arms:
        for name, subset in subsets:
            rs = [
                r
                for r in runs
                if r["arm"] == arm.label and (subset is None or r["object"] in subset)
            ]
            v = np.array([table[arm.label][(r["object"], r["seed"])] for r in rs], dtype=float)
            summary.add_row(
                arm.label,
                name,
                f"{v.mean():.2f}",
                f"{np.median(v):g}",
                f"{sum(r['final_correct'] for r in rs)}/{len(rs)}",
                str(int((v > budget).sum())),
            )
    console.print(summary)

    paired = Table(title="paired by (object, seed): baseline - arm moves (positive: arm faster)")
    for col in ("arm", "vs", "objects", "pairs", "mean saved", "95% CI", "W/T/L", "sign p"):
        paired.add_column(col)
    all_rows = []
    for name, subset in subsets:
        for row in paired_rows(table, arms, baselines, subset, rng):
            row["objects"] = name
            all_rows.append(row)
            lo, hi = row["ci95"]
            paired.add_row(
                row["arm"],
                row["baseline"],
                name,
                str(row["pairs"]),
                f"{row['mean_saved']:+.2f}",
                f"[{lo:+.2f}, {hi:+.2f}]",
                f"{row['wins']}/{row['ties']}/{row['losses']}",
                f"{row['sign_p']:.3f}",
            )
    console.print(paired)

    per_obj = Table(title="mean moves to first correct per object")
    per_obj.add_column("arm")
    for o in objects:
        per_obj.add_column(o)
    for arm in arms:
        cells = []
        for o in objects:
            v = [m for (oo, _s), m in table[arm.label].items() if oo == o]
            cells.append(f"{np.mean(v):.2f}")
        per_obj.add_row(arm.label, *cells)
    console.print(per_obj)
    given = sys.argv[1:] if argv is None else argv
    console.print(f"command: python benchmarks/policy_sweep.py {' '.join(given)}")

    if args.json:
        public = [{k: v for k, v in r.items() if not k.startswith("_")} for r in runs]
        Path(args.json).write_text(json.dumps({"runs": public, "paired": all_rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
