"""`activetouch bench recognition [--json FILE]`: timings of the recognition core.

Measures, on synthetic contacts (12 shape classes, 1000-bin histograms):
- triangles and histogram counts per grasp of 27 contacts (2925 triangles);
- proba per call on one histogram and proba_many per call on 1000 histograms, for each
  classifier kind (numpy only, no scikit-learn at prediction time);
- the numba kernel_proba per call.
Each figure is per call (per histogram for proba_many, called on 1000 at once): the median and
the best of several rounds of many calls, after a warm-up.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from activetouch.recognition.classifiers import CLASSIFIER_NAMES, make_classifier
from activetouch.recognition.histogram import HistogramSpec
from activetouch.recognition.kernels import kernel_proba
from activetouch.recognition.synthetic import SYNTHETIC_SHAPES, synthetic_grasp
from activetouch.recognition.training import grasp_triangles, partial_histograms
from activetouch.recognition.triangles import triangle_params


def time_call(
    fn: Callable[[], object], min_seconds: float = 0.05, rounds: int = 5
) -> tuple[float, float]:
    """(median, best) seconds per call of fn over `rounds` rounds each lasting about min_seconds.

    The best round is the steadier figure on a shared machine; the median is the typical one."""
    fn()  # warm-up (and numba compilation)
    number = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        dt = time.perf_counter() - t0
        if dt >= min_seconds / 4 or number >= 1 << 20:
            break
        number *= 4
    number = max(1, int(number * min_seconds / max(dt, 1e-9)))
    per_call = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        per_call.append((time.perf_counter() - t0) / number)
    return statistics.median(per_call), min(per_call)


def run(seed: int = 0, quick: bool = False) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    shapes = SYNTHETIC_SHAPES[:12]
    n_grasps = 15 if quick else 40
    train = [
        grasp_triangles([synthetic_grasp(s, rng, (4, 9)) for _ in range(n_grasps)]) for s in shapes
    ]
    spec = HistogramSpec.fit(np.vstack([t for obj in train for t in obj]), bins=10)
    H, y = partial_histograms(train, spec, 50 if quick else 150, 1, 10, rng)
    min_s, rounds = (0.01, 3) if quick else (0.1, 7)

    grasp27 = synthetic_grasp("sphere_large", rng, 27, reach_m=None)
    tri27 = triangle_params(grasp27)
    results: dict[str, Any] = {
        "n_classes": len(shapes),
        "n_bins": spec.n_bins,
        "n_training_histograms": len(H),
        "contacts_per_grasp": 27,
        "triangles_per_grasp": len(tri27),
        "proba_many_batch": 1000,
        "us": {},
        "us_best": {},
    }
    us: dict[str, float] = results["us"]
    best: dict[str, float] = results["us_best"]

    def record(key: str, fn: Callable[[], object], per: int = 1) -> None:
        median, fastest = time_call(fn, min_s, rounds)
        us[key] = 1e6 * median / per
        best[key] = 1e6 * fastest / per

    record("triangles_per_grasp", lambda: triangle_params(grasp27))
    record("histogram_counts_per_grasp", lambda: spec.counts(tri27))
    record("triangles_plus_histogram_per_grasp", lambda: spec.counts(triangle_params(grasp27)))

    test = np.vstack(
        [
            spec.counts(np.vstack(grasp_triangles([synthetic_grasp(s, rng) for _ in range(3)])))
            for s in shapes
            for _ in range(84)
        ]
    )[:1000]
    h = test[0].copy()
    for name in CLASSIFIER_NAMES:
        clf = make_classifier(name).fit(H, y)
        k = clf.kernel()
        args = (k.kind, k.W, k.b, k.row_class, k.platt_a, k.platt_b, k.temperature, k.n_classes)
        record(f"{name}.proba", lambda clf=clf: clf.proba(h))
        record(f"{name}.proba_many_per_histogram", lambda clf=clf: clf.proba_many(test), len(test))
        record(f"{name}.kernel_proba", lambda args=args: kernel_proba(*args, h))
    return results


def _table(results: dict[str, Any]) -> Table:
    table = Table(
        title=(
            f"recognition core: {results['n_classes']} classes, {results['n_bins']} bins, "
            f"{results['contacts_per_grasp']} contacts = {results['triangles_per_grasp']} triangles"
        )
    )
    table.add_column("operation")
    table.add_column("median µs", justify="right")
    table.add_column("best µs", justify="right")
    for key, value in results["us"].items():
        table.add_row(key, f"{value:,.2f}", f"{results['us_best'][key]:,.2f}")
    return table


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="activetouch bench recognition", description=__doc__)
    p.add_argument("--json", metavar="FILE", type=Path, default=None, help="also write figures")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="smaller data, shorter timing rounds")
    args = p.parse_args(argv)
    console = Console()
    with console.status("training synthetic classifiers and timing..."):
        results = run(seed=args.seed, quick=args.quick)
    console.print(_table(results))
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
        console.print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
