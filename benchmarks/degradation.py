"""How recognition degrades under the real robot's errors: object placement error and tactile
sensor faults (issue 15), each level against the error-free twin, paired by (object, seed).

    ACTIVETOUCH_HOME=DIR python benchmarks/degradation.py --seeds 0-2 --workers 2 \\
        --policies tree,greedy --json degradation.json
    python benchmarks/degradation.py --from-json degradation.json   # the table again

Each level is a set of `sim.*` error settings (docs/benchmark.md); a run's placement error and
faulty sensors are drawn from its seed, so every policy meets the same errors. Protocol as in
docs/results/: no early stop, 15 grasps, moves to first correct with "never" = budget + 1. The
model is trained without errors (the planner and the classifier believe the nominal twin).
"""

from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

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
from activetouch.pipelines.journal import RunJournal
from activetouch.session.local import load_trained, model_path
from activetouch.storage import atomic_write_text

# name -> (what it is, settings). The placement levels are the bounds (2 cm, 15 deg),
# half of them and the larger ones (3 cm, 30 deg: the pose belief's grid); sensor levels are
# single faults of plausible size (threshold 20 units, the twin's own noise 2 units), then
# everything at once.
LEVELS: dict[str, tuple[str, list[str]]] = {
    "none": ("the nominal twin", []),
    "place_1cm_5deg": (
        "placement +-1 cm, +-5 deg",
        ["sim.placement_error_m=0.01", "sim.placement_error_deg=5"],
    ),
    "place_2cm_15deg": (
        "placement +-2 cm, +-15 deg",
        ["sim.placement_error_m=0.02", "sim.placement_error_deg=15"],
    ),
    "place_3cm_30deg": (
        "placement +-3 cm, +-30 deg",
        ["sim.placement_error_m=0.03", "sim.placement_error_deg=30"],
    ),
    "noise_5": ("pressure noise +5 units", ["sim.fault_noise_std=5"]),
    "noise_10": ("pressure noise +10 units", ["sim.fault_noise_std=10"]),
    "dead_4": ("4 of 38 sensors dead", ["sim.fault_dead=4"]),
    "stuck_1": ("1 sensor stuck on", ["sim.fault_stuck=1"]),
    "spurious_2pct": ("2 % spurious contacts", ["sim.fault_spurious=0.02"]),
    # Errors the paper's twin did not have: a free-standing object, calibration gone stale.
    "nudge_1cm": ("the object nudged, up to 1 cm per grasp", ["sim.nudge_max_m=0.01"]),
    "drift_fingers": (
        "finger angles off by up to +-0.05 rad",
        ["sim.fault_finger_offset_rad=0.05"],
    ),
    "drift_sensors": (
        "sensor zeros drifting up to +-1 unit per grasp",
        ["sim.fault_sensor_drift=1"],
    ),
    "all": (
        "placement 2 cm/15 deg + noise 5 + 4 dead + 1 stuck + 2 % spurious",
        [
            "sim.placement_error_m=0.02",
            "sim.placement_error_deg=15",
            "sim.fault_noise_std=5",
            "sim.fault_dead=4",
            "sim.fault_stuck=1",
            "sim.fault_spurious=0.02",
        ],
    ),
    "all_3cm_30deg": (
        "placement 3 cm/30 deg + noise 5 + 4 dead + 1 stuck + 2 % spurious",
        [
            "sim.placement_error_m=0.03",
            "sim.placement_error_deg=30",
            "sim.fault_noise_std=5",
            "sim.fault_dead=4",
            "sim.fault_stuck=1",
            "sim.fault_spurious=0.02",
        ],
    ),
    "all_nudge_drift": (
        "all + nudged 1 cm + fingers +-0.05 rad + sensor drift +-1/grasp",
        [
            "sim.placement_error_m=0.02",
            "sim.placement_error_deg=15",
            "sim.fault_noise_std=5",
            "sim.fault_dead=4",
            "sim.fault_stuck=1",
            "sim.fault_spurious=0.02",
            "sim.nudge_max_m=0.01",
            "sim.fault_finger_offset_rad=0.05",
            "sim.fault_sensor_drift=1",
        ],
    ),
}


def degradation_rows(
    runs: list[dict[str, Any]], levels: list[str], policies: list[str], budget: int
) -> list[dict[str, Any]]:
    """Per (level, policy): accuracy, grasps, contacts, and the paired change against 'none'."""
    by = {(r["level"], r["policy"], r["object"], r["seed"]): r for r in runs}
    rows = []
    for level in levels:
        for p in policies:
            rs = [r for r in runs if r["level"] == level and r["policy"] == p]
            if not rs:
                continue
            base = [by.get(("none", p, r["object"], r["seed"])) for r in rs]
            pairs = [(r, b) for r, b in zip(rs, base, strict=True) if b is not None]
            # Positive: the errors cost grasps (errors - nominal).
            d = np.array(
                [moves_capped(r, budget) - moves_capped(b, budget) for r, b in pairs], dtype=float
            )
            acc_d = np.array([float(r["final_correct"]) - b["final_correct"] for r, b in pairs])
            st = paired_stats(d, np.random.default_rng(0))
            acc_st = paired_stats(acc_d, np.random.default_rng(0))
            moves = np.array([moves_capped(r, budget) for r in rs], dtype=float)
            rows.append(
                {
                    "level": level,
                    "policy": p,
                    "runs": len(rs),
                    "final_accuracy": float(np.mean([r["final_correct"] for r in rs])),
                    "accuracy_change": acc_st["mean"],
                    "accuracy_change_ci95": acc_st["ci95"],
                    "mean_first_correct": float(moves.mean()),
                    "median_first_correct": float(np.median(moves)),
                    "extra_grasps": st["mean"],
                    "extra_grasps_ci95": st["ci95"],
                    "mean_contacts": float(np.mean([r["mean_contacts"] for r in rs])),
                }
            )
    return rows


def print_table(runs: list[dict[str, Any]], levels: list[str], policies: list[str], budget: int):
    seeds = sorted({r["seed"] for r in runs})
    objects = sorted({r["object"] for r in runs})
    print(
        f"\n{len(objects)} objects x {len(seeds)} seeds ({seeds[0]}-{seeds[-1]}), budget {budget}"
        f" grasps, never = {budget + 1}; changes paired by (object, seed) against 'none'\n"
    )
    print(
        "| errors | policy | final accuracy | change (95 % CI) | mean grasps to first correct | "
        "median | extra grasps (95 % CI) | contacts per grasp |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in degradation_rows(runs, levels, policies, budget):
        what = LEVELS[r["level"]][0] if r["level"] in LEVELS else r["level"]
        alo, ahi = r["accuracy_change_ci95"]
        glo, ghi = r["extra_grasps_ci95"]
        unpaired = r["level"] == "none" or np.isnan(r["accuracy_change"])
        change = "" if unpaired else f"{r['accuracy_change']:+.1%} [{alo:+.1%}, {ahi:+.1%}]"
        extra = "" if unpaired else f"{r['extra_grasps']:+.2f} [{glo:+.2f}, {ghi:+.2f}]"
        print(
            f"| {what} | {r['policy']} | {r['final_accuracy']:.1%} | {change} | "
            f"{r['mean_first_correct']:.2f} | {r['median_first_correct']:g} | {extra} | "
            f"{r['mean_contacts']:.1f} |"
        )


def headroom_rows(runs: list[dict[str, Any]], levels: list[str], budget: int) -> list[dict]:
    """Per level, tree against greedy paired by (object, seed), and how much any planner could
    save at all: both arms share the first (random) grasp, so a pair right after it ties
    whatever is planned, and in the others the best a second grasp can do is be right (2)."""
    by = {(r["level"], r["policy"], r["object"], r["seed"]): r for r in runs}
    rows = []
    for level in levels:
        keys = sorted({(o, sd) for lv, p, o, sd in by if lv == level and p == "greedy"})
        pairs = [
            (by[(level, "tree", o, sd)], by[(level, "greedy", o, sd)])
            for o, sd in keys
            if (level, "tree", o, sd) in by
        ]
        if not pairs:
            continue
        t = np.array([moves_capped(a, budget) for a, _ in pairs], dtype=float)
        g = np.array([moves_capped(b, budget) for _, b in pairs], dtype=float)
        st = paired_stats(g - t, np.random.default_rng(0))
        open_ = g > 1
        rows.append(
            {
                "level": level,
                "pairs": len(pairs),
                "decided_by_first": int((~open_).sum()),
                "greedy_open": float(g[open_].mean()) if open_.any() else float("nan"),
                "tree_open": float(t[open_].mean()) if open_.any() else float("nan"),
                "oracle_saving": float(np.maximum(g - 2, 0).sum() / len(pairs)),
                "saved": st,
            }
        )
    return rows


def print_headroom(runs: list[dict[str, Any]], levels: list[str], budget: int) -> None:
    rows = headroom_rows(runs, levels, budget)
    if not rows:
        return
    print(
        "\nWhere a planner can matter: tree against greedy (grasps to first correct saved, "
        "paired), and the most any second grasp could save\n"
    )
    print(
        "| errors | pairs | right after the shared first grasp | the others: greedy / tree "
        "grasps | tree saves (95 % CI) | fewer / ties / more | most a planner could save |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        what = LEVELS[r["level"]][0] if r["level"] in LEVELS else r["level"]
        st = r["saved"]
        lo, hi = st["ci95"]
        print(
            f"| {what} | {r['pairs']} | {r['decided_by_first']} | {r['greedy_open']:.2f} / "
            f"{r['tree_open']:.2f} | {st['mean']:+.2f} [{lo:+.2f}, {hi:+.2f}] | "
            f"{st['wins']} / {st['ties']} / {st['losses']} | {r['oracle_saving']:.2f} |"
        )


def print_per_object(runs: list[dict[str, Any]], levels: list[str], policies: list[str]) -> None:
    """Final accuracy per object (rows) for every (level, policy), the objects under 80 %
    and the median robot seconds to the first correct label (a run never right: its whole)."""
    cols = [(lv, p) for lv in levels for p in policies]
    cols = [c for c in cols if any(r["level"] == c[0] and r["policy"] == c[1] for r in runs)]
    if not cols:
        return
    objects = sorted({r["object"] for r in runs})
    acc: dict[tuple[str, str, str], float] = {}
    for lv, p in cols:
        for o in objects:
            rs = [r for r in runs if (r["level"], r["policy"], r["object"]) == (lv, p, o)]
            if rs:
                acc[(lv, p, o)] = float(np.mean([r["final_correct"] for r in rs]))
    print("\nPer object, final accuracy\n")
    print("| object | " + " | ".join(f"{lv}, {p}" for lv, p in cols) + " |")
    print("|---|" + "---|" * len(cols))
    for o in objects:
        cells = [f"{acc[(lv, p, o)]:.0%}" if (lv, p, o) in acc else "" for lv, p in cols]
        print(f"| {o} | " + " | ".join(cells) + " |")
    under, robot = [], []
    for lv, p in cols:
        low = [o for o in objects if acc.get((lv, p, o), 1.0) < 0.8]
        under.append(f"{len(low)}" + (f" ({', '.join(low)})" if 0 < len(low) <= 4 else ""))
        rs = [r for r in runs if r["level"] == lv and r["policy"] == p]
        t = [
            r["robot_s_to_first_correct"]
            if r.get("robot_s_to_first_correct") is not None
            else r.get("total_s", np.nan)
            for r in rs
        ]
        robot.append(f"{np.nanmedian(np.asarray(t, dtype=float)):.1f}")
    print("| objects under 80 % | " + " | ".join(under) + " |")
    print("| median robot s to first correct | " + " | ".join(robot) + " |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--levels", default=",".join(LEVELS), help="comma list of: " + ", ".join(LEVELS)
    )
    ap.add_argument("--policies", default="tree,greedy")
    ap.add_argument("--objects", default=None, help="comma-separated (default: the model's)")
    ap.add_argument("--seeds", default="0-2")
    ap.add_argument("--max-moves", type=int, default=15)
    ap.add_argument("--set", action="append", default=[], help="override for every level")
    ap.add_argument("--model", default=None)
    ap.add_argument("--data", default=None)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--executor", choices=("local", "ray"), default="local")
    ap.add_argument("--address", default=None, help="--executor ray: the cluster")
    ap.add_argument("--json", default=None, help="write the runs here")
    ap.add_argument("--from-json", default=None, help="comma list of saved runs: table only")
    ap.add_argument(
        "--no-nominal",
        action="store_true",
        help="do not add the nominal level (no paired change against it is printed)",
    )
    args = ap.parse_args(argv)
    policies = [p.strip() for p in args.policies.split(",") if p.strip()]

    if args.from_json:
        runs: list[dict[str, Any]] = []
        levels: list[str] = []
        for f in args.from_json.split(","):
            if not Path(f).is_file():
                ap.error(f"--from-json: no file {f}")
            raw = Path(f).read_bytes()
            doc = json.loads(gzip.decompress(raw) if f.endswith(".gz") else raw)
            runs += doc["runs"]
            levels += [lv for lv in doc["levels"] if lv not in levels]
            args.max_moves = doc["max_moves"]
        pols = list(dict.fromkeys(r["policy"] for r in runs))
        print_table(runs, levels, pols, args.max_moves)
        print_headroom(runs, levels, args.max_moves)
        print_per_object(runs, levels, pols)
        return 0

    levels = [lv.strip() for lv in args.levels.split(",") if lv.strip()]
    unknown = [lv for lv in levels if lv not in LEVELS]
    if unknown:
        ap.error(f"unknown levels {unknown}; choose from {', '.join(LEVELS)}")
    if "none" not in levels and not args.no_nominal:
        levels.insert(0, "none")  # the reference every level is paired with
    root = paths.data_dir(args.data)
    family = load_config(None, args.set).hand.family  # the hand's own default model
    model_dir = model_path(root, args.model, family)
    model = load_trained(model_dir)
    objects = args.objects.split(",") if args.objects else list(model.class_names)
    seeds = parse_seeds(args.seeds)
    jobs: list[Job] = []
    owner: list[str] = []
    for level in levels:
        cfg = load_config(None, ["session.confidence=2", *args.set, *LEVELS[level][1]])
        js = make_jobs(
            model_dir, paths.objects_dir(root), objects, policies, seeds, args.max_moves, cfg
        )
        jobs += js
        owner += [level] * len(js)
    # With --json, each run is kept beside it as it finishes: the same command resumes.
    journal = RunJournal(Path(args.json + ".runs.jsonl")) if args.json else None
    if journal is not None and len(journal):
        print(f"resuming: {len(journal)} runs already in {journal.path}", file=sys.stderr)
    runs = run_all(
        jobs,
        args.workers,
        lambda i, n: print(f"\r{i}/{n} runs", end="", file=sys.stderr, flush=True),
        args.executor,
        args.address,
        journal,
    )
    print(file=sys.stderr)
    public = [
        {"level": lv, **{k: v for k, v in r.items() if not k.startswith("_")}}
        for r, lv in zip(runs, owner, strict=True)
    ]
    if args.json:
        doc = {"levels": levels, "max_moves": args.max_moves, "argv": argv or sys.argv[1:]}
        atomic_write_text(Path(args.json), json.dumps({**doc, "runs": public}) + "\n")
        if journal is not None:
            journal.remove()
    print_table(public, levels, policies, args.max_moves)
    print_headroom(public, levels, args.max_moves)
    print_per_object(public, levels, policies)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
