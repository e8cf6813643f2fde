"""The ReFlex and the BarrettHand BH8 side by side from stored degradation runs
(`benchmarks/degradation.py --json`): per hand, error level and policy, final accuracy, mean
and median grasps to first correct ("never" = budget + 1), median robot seconds to first
correct (runs that never got it right left out, their count shown) and contacts per grasp.

    python benchmarks/hands_table.py --hand ReFlex=a.json,b.json --hand BH8=c.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np


def load_runs(files: str) -> list[dict[str, Any]]:
    runs: list[dict[str, Any]] = []
    for f in files.split(","):
        runs += json.loads(Path(f).read_text())["runs"]
    return runs


def rows(hand: str, runs: list[dict[str, Any]], budget: int) -> list[str]:
    out = []
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
            out.append(
                f"| {hand} | {level} | {pol} | {len(seen)} | {acc:.1%} | {first.mean():.2f} | "
                f"{np.median(first):.0f} | {np.median(secs):.1f} ({never} never) | {contacts:.1f} |"
            )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hand", action="append", required=True, help="NAME=run.json[,run.json]")
    ap.add_argument("--budget", type=int, default=15)
    args = ap.parse_args(argv)
    print(
        "| hand | errors | policy | runs (object, seed) | final accuracy | mean grasps to first "
        "correct | median | median robot s to first correct | contacts per grasp |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for item in args.hand:
        name, _, files = item.partition("=")
        for line in rows(name, load_runs(files), args.budget):
            print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
