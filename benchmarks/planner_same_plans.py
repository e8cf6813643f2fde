"""Plans of the tree search on fixed synthetic problems and seeds, to show that a change to
the planner's data layout leaves its plans as they were.

    python benchmarks/planner_same_plans.py --record plans.json   # before the change
    python benchmarks/planner_same_plans.py --check plans.json    # after it

Each case is a synthetic problem (poses x classes, `bench planner`'s model for that seed), an
objective, lam, the Eq. 4 reading and a root; the plan is the path of poses the search returns
and its value. `--check` prints how many plans are identical and which differ.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from activetouch.planning.bench import make_problem
from activetouch.planning.mcts import TreeSearch

SIZES = ((1064, 7), (5000, 100))
OBJECTIVES = ("final", "anytime", "info_gain")
LAMS = (0.0, 0.5)
ROOTS = 6


def plans(sizes: tuple[tuple[int, int], ...], sims: int) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for n_poses, n_classes in sizes:
        t0 = time.perf_counter()
        pr = make_problem(n_poses, n_classes, 0)
        print(f"{n_poses} poses x {n_classes} classes built in {time.perf_counter() - t0:.0f} s")
        roots = np.random.default_rng(1).choice(n_poses, ROOTS, replace=False)
        for objective in OBJECTIVES:
            ts = TreeSearch(pr.model, pr.kernel, objective=objective)
            for lam in LAMS:
                for per_class in (False, True):
                    for root in roots:
                        counts, cells = pr.observe(int(root))
                        rng = np.random.default_rng(int(root))
                        res = ts.search(
                            int(root),
                            np.array([int(root)]),
                            counts,
                            cells,
                            horizon=5,
                            simulations=sims,
                            rng=rng,
                            lam=lam,
                            per_class_backoff=per_class,
                        )
                        case = f"{objective}/lam{lam}/pc{int(per_class)}/{root}"
                        plan = {"poses": res.poses.tolist(), "value": res.value}
                        out[f"{n_poses}x{n_classes}/{case}"] = plan
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--record", metavar="FILE")
    g.add_argument("--check", metavar="FILE")
    p.add_argument("--sims", type=int, default=300)
    p.add_argument("--small", action="store_true", help="only the 1064 x 7 problem")
    args = p.parse_args(argv)
    sizes = SIZES[:1] if args.small else SIZES
    got = plans(sizes, args.sims)
    if args.record:
        Path(args.record).write_text(json.dumps(got, indent=1) + "\n")
        print(f"recorded {len(got)} plans in {args.record}")
        return 0
    want = json.loads(Path(args.check).read_text())
    keys = [k for k in got if k in want]
    same = [k for k in keys if got[k]["poses"] == want[k]["poses"]]
    value = [k for k in same if abs(got[k]["value"] - want[k]["value"]) > 1e-12]
    print(f"{len(same)} of {len(keys)} plans identical ({len(value)} of them differ in value)")
    for k in keys:
        if k not in same:
            print(f"  differs: {k}: {want[k]['poses']} -> {got[k]['poses']}")
    return 0 if len(same) == len(keys) and not value else 1


if __name__ == "__main__":
    sys.exit(main())
