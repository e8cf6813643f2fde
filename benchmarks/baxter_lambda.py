"""Does planning over travel time pay? Tree, greedy and random on the Baxter twin, in grasps and
in robot seconds to first correct, with the movement weight lam = 0 (grasps only) and lam = 0.5
with c_m the arm's move duration (`planner.movement_cost = "travel_time"`), issue 11.

    ACTIVETOUCH_HOME=DIR python -m activetouch train --set arm.type=twin-baxter \\
        --out DIR/models/baxter
    ACTIVETOUCH_HOME=DIR python benchmarks/baxter_lambda.py --model DIR/models/baxter \\
        --seeds 0-29 --out docs/results/baxter
    python benchmarks/baxter_lambda.py --out docs/results/baxter --readme-only

Every run stops at the session's confidence rule (as a robot would: a Baxter move takes
seconds), budget `--max-moves` grasps; robot seconds are the session's `robot_s` when the label
was first right (moving + grasping + planning), a run never right counting its whole time.
The random policy has no movement term: its lam = 0 runs stand for both.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

from activetouch.cli.main import main as cli
from activetouch.pipelines.evaluation import moves_capped, paired_stats, robot_s_capped

BAXTER = ["--set", "arm.type=twin-baxter"]
# name -> (what it is, policies, settings)
STUDIES: dict[str, tuple[str, str, list[str]]] = {
    "lam0": ("lam = 0: grasps only", "tree,greedy,random", ["planner.lam=0"]),
    "lam0.5_travel": (
        "lam = 0.5, c_m = the arm's move duration over the longest",
        "tree,greedy",
        ["planner.lam=0.5", "planner.movement_cost=travel_time"],
    ),
}


def run(argv: list[str]) -> None:
    print("$ python -m activetouch " + shlex.join(argv), flush=True)
    if cli(argv) != 0:
        raise SystemExit(f"failed: {argv}")


def load_runs(out: Path) -> dict[str, list[dict[str, Any]]]:
    return {k: json.loads((out / k / "results.json").read_text())["runs"] for k in STUDIES}


def policy_rows(runs: list[dict[str, Any]], budget: int) -> list[str]:
    rows = []
    for p in dict.fromkeys(r["policy"] for r in runs):
        rs = [r for r in runs if r["policy"] == p]
        moves = sum(r["moves"] for r in rs)
        rows.append(
            f"| {p} | {np.mean([r['final_correct'] for r in rs]):.0%} | "
            f"{sum(r['moves_to_first_correct'] is None for r in rs)} | "
            f"{np.mean([moves_capped(r, budget) for r in rs]):.2f} | "
            f"{np.mean([robot_s_capped(r) for r in rs]):.1f} | "
            f"{np.median([robot_s_capped(r) for r in rs]):.1f} | "
            f"{sum(r['motion_s'] for r in rs) / max(moves, 1):.2f} | "
            f"{np.mean([r['total_s'] for r in rs]):.1f} |"
        )
    return rows


def paired_row(
    name: str, a: list[dict[str, Any]], b: list[dict[str, Any]], budget: int
) -> str | None:
    """`a` against `b` paired by (object, seed); positive: `a` needed less."""
    by = {(r["object"], r["seed"]): r for r in b}
    pairs = [(r, by[(r["object"], r["seed"])]) for r in a if (r["object"], r["seed"]) in by]
    if not pairs:
        return None
    rng = np.random.default_rng(0)
    g = paired_stats(
        np.array([moves_capped(y, budget) - moves_capped(x, budget) for x, y in pairs]), rng
    )
    s = paired_stats(np.array([robot_s_capped(y) - robot_s_capped(x) for x, y in pairs]), rng)
    return (
        f"| {name} | {len(pairs)} | {g['mean']:+.2f} [{g['ci95'][0]:+.2f}, {g['ci95'][1]:+.2f}] "
        f"| {g['sign_p']:.3f} | {s['mean']:+.1f} [{s['ci95'][0]:+.1f}, {s['ci95'][1]:+.1f}] | "
        f"{s['wins']} / {s['losses']} | {s['sign_p']:.3f} |"
    )


def write_readme(args: argparse.Namespace, out: Path) -> None:
    runs = load_runs(out)
    budget = int(args.max_moves)
    pol = {
        (k, p): [r for r in rs if r["policy"] == p]
        for k, rs in runs.items()
        for p in ("tree", "greedy", "random")
    }
    pol[("lam0.5_travel", "random")] = pol[("lam0", "random")]
    command = "python benchmarks/baxter_lambda.py " + shlex.join(
        a for a in sys.argv[1:] if a != "--readme-only"
    )
    head = (
        "| policy | runs correct at the end | never correct | mean grasps to first correct "
        "(never = budget + 1) | mean robot s to first correct | median robot s to first "
        "correct | robot s moving per grasp | mean robot s per run |"
    )
    pair_head = (
        "| comparison (paired by object and seed) | pairs | grasps saved (95 % CI) | sign p | "
        "robot s saved (95 % CI) | faster / slower | sign p |"
    )
    objects = sorted({r["object"] for r in runs["lam0"]})
    seeds = sorted({r["seed"] for r in runs["lam0"]})
    lines = [
        "# The Baxter twin: grasps and robot seconds, lam 0 and 0.5",
        "",
        f"Produced by `{command}`, on the model `python -m activetouch train --set "
        "arm.type=twin-baxter` collected (only the grid poses Baxter reaches collision-free at "
        "the default Baxter workcell). "
        f"Objects: {', '.join(objects)}; seeds {seeds[0]}-{seeds[-1]}; each run stops at the "
        f"session's confidence rule, budget {budget} grasps. Robot seconds to first correct: "
        "moving (ruckig trajectory time) + grasping (the twin hand's modelled time: one 0.05 rad "
        "spool step per 25 ms, fingers at 5 rad/s) + planning (search and motion planning, wall "
        "time on this machine), up to the grasp after which the label was first right; a run "
        "never right counts its whole time. OMPL's random paths make the seconds vary a little "
        "between repeats of a seed (the labels do not).",
        "",
    ]
    for k, (what, _, settings) in STUDIES.items():
        lines += [f"## {what} (`{' '.join(settings)}`)", "", head, "|---" * 8 + "|"]
        lines += policy_rows([*runs[k], *(pol[("lam0", "random")] if k != "lam0" else [])], budget)
        lines += ["", pair_head, "|---" * 7 + "|"]
        for other in ("greedy", "random"):
            row = paired_row(f"tree vs {other}", pol[(k, "tree")], pol[(k, other)], budget)
            if row:
                lines.append(row)
        lines.append("")
    lines += ["## Does planning over travel time pay?", "", pair_head, "|---" * 7 + "|"]
    for p in ("tree", "greedy"):
        row = paired_row(
            f"{p}: lam 0.5 travel time vs lam 0",
            pol[("lam0.5_travel", p)],
            pol[("lam0", p)],
            budget,
        )
        if row:
            lines.append(row)
    lines.append("")
    (out / "README.md").write_text("\n".join(lines))
    print((out / "README.md").read_text())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=None, help="model trained on the Baxter twin")
    ap.add_argument("--data", default=None, help="data directory (default: ACTIVETOUCH_HOME)")
    ap.add_argument("--out", default="docs/results/baxter")
    ap.add_argument("--seeds", default="0-29")
    ap.add_argument("--max-moves", default="10")
    ap.add_argument("--workers", default=None)
    ap.add_argument("--studies", default=",".join(STUDIES), help="which of them to (re)run")
    ap.add_argument("--readme-only", action="store_true", help="rewrite README.md from --out")
    args = ap.parse_args()
    out = Path(args.out)
    if not args.readme_only:
        common = [*BAXTER, "--seeds", args.seeds, "--max-moves", args.max_moves]
        common += ["--stop-when-confident"]
        common += ["--model", args.model] if args.model else []
        common += ["--data", args.data] if args.data else []
        common += ["--workers", args.workers] if args.workers else []
        for k in args.studies.split(","):
            if k not in STUDIES:
                raise SystemExit(f"--studies: {k!r} is not one of {', '.join(STUDIES)}")
            _, policies, settings = STUDIES[k]
            sets = [x for s in settings for x in ("--set", s)]
            run(["eval", *common, *sets, "--policies", policies, "--out", str(out / k)])
    write_readme(args, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
