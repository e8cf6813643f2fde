"""`activetouch eval`: every object x policy x seed in the twin, then results.json + report.md."""

from __future__ import annotations

import argparse
import shlex
import time
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from activetouch import paths
from activetouch.cli.commands.train import parse_objects
from activetouch.cli.main import add_common_options
from activetouch.config import load_config
from activetouch.errors import ConfigError
from activetouch.objects.library import ObjectLibrary
from activetouch.pipelines.evaluation import (
    error_overrides,
    make_jobs,
    parse_seeds,
    robot_errors,
    run_all,
    summarise,
)
from activetouch.pipelines.executors import add_executor_options, check_executor
from activetouch.pipelines.journal import RunJournal
from activetouch.pipelines.report import write_report
from activetouch.planning.policies import POLICY_NAMES
from activetouch.session.local import check_request, load_trained, model_path

# In --out while an evaluation runs: each finished run (`RunJournal`); gone once the report is.
JOURNAL = "runs.jsonl"


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser("eval", help="evaluate policies against the paper in the twin")
    p.add_argument("--objects", default=None, help="comma-separated (default: the model's)")
    p.add_argument("--policies", default="tree,greedy,random")
    p.add_argument("--seeds", default="0-9", help="e.g. 0-9 or 0,3,5")
    p.add_argument("--max-moves", type=int, default=None, help="grasp budget per run")
    p.add_argument("--model", metavar="DIR", default=None, help="model directory")
    p.add_argument("--out", metavar="DIR", required=True, help="report directory")
    p.add_argument("--workers", type=int, default=None, help="parallel processes")
    p.add_argument(
        "--stop-when-confident",
        action="store_true",
        help="end runs at the session's confidence rule (default: every run uses the whole "
        "budget, the paper's protocol, so moves-until-correct compare policies fairly)",
    )
    p.add_argument(
        "--placement-error",
        metavar="M[,DEG]",
        default=None,
        help="the real robot's placement error: each run's object stands off the workcell's "
        "placement by up to +-M metres in x and y and +-DEG degrees about z (drawn from the "
        "seed) while the session believes the nominal one (sim.placement_error_m/_deg)",
    )
    p.add_argument(
        "--sensor-faults",
        metavar="noise=S,dead=N,stuck=N,spurious=P",
        default=None,
        help="tactile faults in the twin's hand: extra pressure noise (sensor units), dead and "
        "stuck sensors per run, per-grasp probability of a spurious contact (sim.fault_*)",
    )
    p.add_argument(
        "--nudge",
        metavar="M",
        default=None,
        help="the object stands free: each grasp's unbalanced push slides it by up to M metres "
        "(sim.nudge_max_m)",
    )
    p.add_argument(
        "--calibration-drift",
        metavar="fingers=RAD,sensors=U",
        default=None,
        help="calibration that no longer holds: each finger's angle reads off by up to +-RAD, "
        "each sensor's zero walks by up to +-U units per grasp (sim.fault_finger_offset_rad, "
        "sim.fault_sensor_drift)",
    )
    add_executor_options(p, "recognitions")
    add_common_options(p)
    p.set_defaults(func=run)


def evaluate(
    root: Path,
    model_dir: Path,
    objects: list[str] | None,
    policies: list[str],
    seeds: list[int],
    max_moves: int | None,
    out: Path,
    cfg_path: str | None,
    overrides: list[str],
    workers: int | None,
    console: Console,
    command: str,
    stop_when_confident: bool = False,
    executor: str = "local",
    address: str | None = None,
) -> dict:
    cfg = load_config(cfg_path, overrides)
    check_executor(executor, address)
    budget = max_moves if max_moves is not None else cfg.session.max_moves
    if not stop_when_confident:
        cfg.session.confidence = float("inf")  # no early stop: every run spends the budget
    for p in policies:
        check_request(p, budget)
    model = load_trained(model_dir)
    objects = objects or list(model.class_names)
    library = paths.objects_dir(root)
    # Everything that can be wrong is checked before hours of runs, not after.
    lib = ObjectLibrary(library)
    for o in objects:
        lib.get(o)
    for s in seeds:
        check_request(policies[0], budget, s)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    jobs = make_jobs(model_dir, library, objects, policies, seeds, budget, cfg)
    # Each run is kept as it finishes; the same command after a crash or Ctrl-C resumes.
    journal = RunJournal(out / JOURNAL)
    if len(journal):
        console.print(
            f"resuming: {len(journal)} runs of an evaluation cut short are in {journal.path}; "
            "those of these runs are not made again"
        )
    t0 = time.perf_counter()
    with Progress(
        TextColumn("recognitions"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
    ) as bar:
        task = bar.add_task("eval", total=len(jobs))
        runs = run_all(
            jobs,
            workers,
            lambda done, _: bar.update(task, completed=done),
            executor,
            address,
            journal,
        )
    summary = summarise(runs, budget)
    summary["seconds"] = time.perf_counter() - t0
    summary["stop_when_confident"] = stop_when_confident
    summary["robot_errors"] = robot_errors(cfg.sim)
    summary["executor"] = executor
    class_hist = {}
    if model.class_histograms is not None:
        class_hist = dict(zip(model.class_names, model.class_histograms, strict=True))
    report = write_report(out, runs, summary, command, class_hist, model.spec.bins)
    journal.remove()  # every run is in results.json now
    for p in policies:
        s = summary["per_policy"][p]
        console.print(
            f"{p:>7}: {s['objects_final_correct_majority']}/{len(objects)} objects correct at the "
            f"end, median moves to first correct {s['median_first_correct']}, "
            f"mean {s['mean_first_correct_capped']:.2f}; robot seconds to first correct, mean "
            f"{s['mean_robot_s_to_first_correct']:.1f}"
        )
    console.print(f"{len(jobs)} runs in {summary['seconds']:.0f} s; report: {report}")
    return summary


def run(args: argparse.Namespace) -> int:
    policies = [p.strip() for p in args.policies.split(",") if p.strip()]
    bad = [p for p in policies if p not in POLICY_NAMES]
    if bad or not policies:
        raise ConfigError(f"--policies: unknown {bad}; choose from {', '.join(POLICY_NAMES)}")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    overrides = [
        *args.overrides,
        *error_overrides(
            args.placement_error, args.sensor_faults, args.nudge, args.calibration_drift
        ),
    ]
    root = paths.data_dir(args.data)
    family = load_config(args.config, overrides).hand.family
    evaluate(
        root,
        model_path(root, args.model, family),
        parse_objects(args.objects) if args.objects else None,
        policies,
        parse_seeds(args.seeds),
        args.max_moves,
        Path(args.out),
        args.config,
        overrides,
        args.workers,
        Console(),
        "python -m activetouch " + shlex.join(args.argv),
        args.stop_when_confident,
        args.executor,
        args.address,
    )
    return 0
