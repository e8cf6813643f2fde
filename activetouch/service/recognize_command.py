"""`activetouch recognize`: recognise one object in the twin, with live progress."""

from __future__ import annotations

import argparse
import json
import sys

from rich.console import Console

from activetouch import paths
from activetouch.config import load_config
from activetouch.planning.policies import POLICY_NAMES
from activetouch.service.recognize import load_trained, model_path, recognize_in_twin
from activetouch.service.session import Progress, RecognitionResult
from activetouch.sim.objects import ObjectLibrary


def register(sub: argparse._SubParsersAction) -> None:
    from activetouch.service.cli import add_common_options

    p = sub.add_parser("recognize", help="recognise an object by touch (in the twin)")
    p.add_argument("--object", required=True, help="object to place on the table")
    p.add_argument("--policy", default=None, help=f"one of {', '.join(POLICY_NAMES)}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-moves", type=int, default=None, help="grasp budget")
    p.add_argument("--model", metavar="DIR", default=None, help="model directory")
    p.add_argument("--json", action="store_true", help="print one JSON object with the result")
    add_common_options(p)
    p.set_defaults(func=run)


def format_progress(ev: Progress) -> str:
    top = "  ".join(f"{name} {p:.2f}" for name, p in ev.top)
    skipped = f"  ({ev.skipped} skipped)" if ev.skipped else ""
    return f"move {ev.move:>2}  pose {ev.pose_id:>4}  contacts {ev.n_contacts}  |  {top}{skipped}"


def result_json(res: RecognitionResult, obj: str, policy: str, seed: int) -> dict:
    return {
        "object": obj,
        "policy": policy,
        "seed": seed,
        "label": res.label,
        "probability": res.probability,
        "correct": res.label == obj,
        "labels": res.labels,
        "moves": res.moves,
        "skipped": res.skipped,
        "stop_reason": res.stop_reason,
        "planning_s": res.planning_s,
        "elapsed_s": res.elapsed_s,
        "pose_ids": res.pose_ids,
    }


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config, args.overrides)
    policy = args.policy or cfg.planner.policy
    root = paths.data_dir(args.data)
    # With --json, stdout carries only the JSON object; progress goes to stderr.
    console = Console(stderr=args.json)
    model = load_trained(model_path(root, args.model))
    library = ObjectLibrary(paths.objects_dir(root))
    console.print(
        f"recognising [bold]{args.object}[/] with the {policy} policy "
        f"({model.n_classes} known objects, seed {args.seed})"
    )
    res = recognize_in_twin(
        model,
        library,
        args.object,
        policy,
        args.seed,
        cfg,
        max_moves=args.max_moves,
        on_progress=lambda ev: console.print(format_progress(ev), highlight=False),
    )
    if args.json:
        json.dump(result_json(res, args.object, policy, args.seed), sys.stdout)
        sys.stdout.write("\n")
    else:
        verdict = "[green]correct[/]" if res.label == args.object else "[red]wrong[/]"
        console.print(
            f"recognised: [bold]{res.label}[/] (p = {res.probability:.2f}) after {res.moves} "
            f"grasps, {res.skipped} poses skipped, stopped: {res.stop_reason} — {verdict}"
        )
    return 0
