"""`activetouch bench TARGET`: benchmarks that print figures (and optionally write JSON).

Each target is a `main(argv) -> int` in the part it measures, imported only when asked for.
"""

from __future__ import annotations

import argparse
import importlib

BENCHES: dict[str, str] = {
    "recognition": "activetouch.recognition.bench",
    "planner": "activetouch.planning.bench",
    "sim": "activetouch.sim.bench",
    "train": "activetouch.pipelines.training_bench",
    "service": "activetouch.pipelines.service_bench",
    "motion": "activetouch.pipelines.motion_bench",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its figures")
    p.add_argument("target", choices=sorted(BENCHES), help="what to measure")
    p.add_argument(
        "rest", nargs=argparse.REMAINDER, metavar="OPTIONS", help="options of that benchmark"
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    module = importlib.import_module(BENCHES[args.target])
    return int(module.main(args.rest) or 0)
