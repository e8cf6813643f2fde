"""The ReFlex and the BarrettHand BH8 side by side from stored degradation runs
(`benchmarks/degradation.py --json`): per hand, error level and policy, final accuracy, mean
and median grasps to first correct ("never" = budget + 1), median robot seconds to first
correct (runs that never got it right left out, their count shown), the objects under 80 %
and contacts per grasp.

    python benchmarks/hands_table.py --hand ReFlex=a.json,b.json --hand BH8=c.json [--seeds 0-9]

(also `benchmarks/hard_eval.py` runs, .json or .json.gz: their arms are the policies).
"""

from __future__ import annotations

import argparse
import gzip
import json
from pathlib import Path
from typing import Any

import numpy as np


def load_runs(files: str, seeds: set[int] | None = None) -> list[dict[str, Any]]:
    runs: list[dict[str, Any]] = []
    for f in files.split(","):
        raw = Path(f).read_bytes()
        doc = json.loads(gzip.decompress(raw) if f.endswith(".gz") else raw)
        runs += [r for r in doc["runs"] if seeds is None or r["seed"] in seeds]
    return runs


def rows(hand: str, runs: list[dict[str, Any]], budget: int, level: str = "none") -> list[str]:
    out = []
    for r in runs:  # hard_eval.py's runs name their arm, not a level: `level` then
        r.setdefault("level", level)
        if "arm" in r:
            r["policy"] = r["arm"].split(":")[0]
    levels = list(dict.fromkeys(r["level"] for r in runs))
    policies = list(dict.fromkeys(r["policy"] for r in runs))
    for level in levels:
        for pol in policies:
            rs = [r for r in runs if r["level"] == level and r["policy"] == pol]
            if not rs:
                continue
            seen = {(r["object"], r["seed"]) for r in rs}
            acc = np.mean([r["final_correct"] for r in rs])
            first = np.array([r["moves_to_first_correct"] or budget + 1 for r in rs], dtype=float)
            secs = [r["robot_s_to_first_correct"] for r in rs if r["moves_to_first_correct"]]
            never = len(rs) - len(secs)
            contacts = np.mean([r["mean_contacts"] for r in rs])
            per_obj: dict[str, list[bool]] = {}
            for r in rs:
                per_obj.setdefault(r["object"], []).append(bool(r["final_correct"]))
            low = sorted((float(np.mean(v)), k) for k, v in per_obj.items() if np.mean(v) < 0.8)
            weak = f"{len(low)}" + (
                " ("
                + ", ".join(f"{k} {a:.0%}" for a, k in low[:3])
                + (", ..." if len(low) > 3 else "")
                + ")"
                if low
                else ""
            )
            out.append(
                f"| {hand} | {level} | {pol} | {len(seen)} | {acc:.1%} | {weak} | "
                f"{first.mean():.2f} | "
                f"{np.median(first):.0f} | {np.median(secs):.1f} ({never} never) | {contacts:.1f} |"
            )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--hand",
        action="append",
        required=True,
        help="NAME[@LEVEL]=run.json[,run.json] (LEVEL names the errors of runs without one)",
    )
    ap.add_argument("--budget", type=int, default=15)
    ap.add_argument("--seeds", default=None, help="only these seeds, e.g. 0-9")
    args = ap.parse_args(argv)
    seeds = None
    if args.seeds:
        lo, _, hi = args.seeds.partition("-")
        seeds = set(range(int(lo), int(hi or lo) + 1))
    print(
        "| hand | errors | policy | runs (object, seed) | final accuracy | objects under 80 % | "
        "mean grasps to first correct | median | median robot s to first correct | contacts "
        "per grasp |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for item in args.hand:
        name, _, files = item.partition("=")
        name, _, level = name.partition("@")
        for line in rows(name, load_runs(files, seeds), args.budget, level or "none"):
            print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
