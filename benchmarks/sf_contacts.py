"""Recognition with the ReFlex SF's contacts (issue 12): the SF has no tactile sensors, so a
grasp reports one contact per finger that stalled against the object, at its distal sensor
site (drivers/reflex/sf.py), at most one triangle per grasp. The twin reports the same with
`sim.sensing = "stall"`. Both hands are trained and evaluated on the paper's 7 objects with the
same seeds and protocol (docs/results/: 15 grasps, no early stop).

    ACTIVETOUCH_HOME=DIR python benchmarks/sf_contacts.py --seeds 0-29 --out docs/results/sf
    python benchmarks/sf_contacts.py --out docs/results/sf --readme-only
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path

import numpy as np

from activetouch import paths
from activetouch.cli.main import main as cli
from activetouch.pipelines.evaluation import moves_capped, paired_stats

HANDS = {
    "takktile": ("ReFlex TakkTile: 38 pressure sensors", []),
    "sf": ("ReFlex SF: one contact per stalled finger", ["sim.sensing=stall"]),
}


def run(argv: list[str]) -> None:
    print("$ python -m activetouch " + shlex.join(argv), flush=True)
    if cli(argv) != 0:
        raise SystemExit(f"failed: {argv}")


def write_readme(args: argparse.Namespace, out: Path) -> None:
    docs = {h: json.loads((out / h / "results.json").read_text()) for h in HANDS}
    budget = int(args.max_moves)
    command = "python benchmarks/sf_contacts.py " + shlex.join(
        a for a in sys.argv[1:] if a != "--readme-only"
    )
    seeds = sorted({r["seed"] for r in docs["sf"]["runs"]})
    lines = [
        "# Recognition with the ReFlex SF's contacts, in the twin",
        "",
        f"Produced by `{command}`. The paper's 7 objects, seeds {seeds[0]}-{seeds[-1]}, "
        f"{budget} grasps per run, no early stop. Each hand has its own model, trained in the "
        "twin with its own sensing (`sim.sensing=stall` for the SF: a finger that stopped "
        "against the object reports one contact at its distal sensor site 6, so a grasp "
        "makes at most one triangle).",
        "",
        "| hand | policy | runs correct at the end | mean grasps to first correct (never = "
        f"{budget + 1}) | never correct | mean contacts per grasp |",
        "|---|---|---|---|---|---|",
    ]
    for h, (what, _) in HANDS.items():
        for p in docs[h]["summary"]["policies"]:
            rs = [r for r in docs[h]["runs"] if r["policy"] == p]
            lines.append(
                f"| {what} | {p} | {np.mean([r['final_correct'] for r in rs]):.0%} | "
                f"{np.mean([moves_capped(r, budget) for r in rs]):.2f} | "
                f"{sum(r['moves_to_first_correct'] is None for r in rs)} | "
                f"{np.mean([r['mean_contacts'] for r in rs]):.1f} |"
            )
    lines += [
        "",
        "Runs correct at the end, per object (tree):",
        "",
        "| object | TakkTile | SF |",
        "|---|---|---|",
    ]
    table = {h: docs[h]["summary"]["table"] for h in HANDS}
    for o in docs["sf"]["summary"]["objects"]:
        n = table["sf"][o]["tree"]["runs"]
        lines.append(
            f"| {o} | {table['takktile'][o]['tree']['final_correct']} of {n} | "
            f"{table['sf'][o]['tree']['final_correct']} of {n} |"
        )
    by = {(r["policy"], r["object"], r["seed"]): r for r in docs["takktile"]["runs"]}
    pairs = [(r, by[(r["policy"], r["object"], r["seed"])]) for r in docs["sf"]["runs"]]
    d = np.array(
        [moves_capped(sf, budget) - moves_capped(tt, budget) for sf, tt in pairs], dtype=float
    )
    st = paired_stats(d, np.random.default_rng(0))
    lines += [
        "",
        f"Paired by policy, object and seed ({len(pairs)} pairs), the SF needs "
        f"{st['mean']:+.2f} grasps to first correct against the TakkTile (95 % CI "
        f"[{st['ci95'][0]:+.2f}, {st['ci95'][1]:+.2f}]; SF more in {st['wins']}, fewer in "
        f"{st['losses']}, sign test p = {st['sign_p']:.3g}).",
        "",
    ]
    (out / "README.md").write_text("\n".join(lines))
    print((out / "README.md").read_text())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/results/sf")
    ap.add_argument("--seeds", default="0-29")
    ap.add_argument("--max-moves", default="15")
    ap.add_argument("--readme-only", action="store_true")
    args = ap.parse_args()
    out = Path(args.out)
    if not args.readme_only:
        root = paths.data_dir(os.environ.get("ACTIVETOUCH_HOME"))
        for h, (_, settings) in HANDS.items():
            sets = [x for s in settings for x in ("--set", s)]
            model = str(paths.models_dir(root) / f"hand-{h}")
            run(["train", *sets, "--out", model])
            ev = ["--seeds", args.seeds, "--max-moves", args.max_moves, "--model", model]
            run(["eval", *sets, *ev, "--out", str(out / h)])
    write_readme(args, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
