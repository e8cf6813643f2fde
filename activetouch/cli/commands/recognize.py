"""`activetouch recognize`: recognise one object in the twin, with live progress.

In-process by default; with `--connect ENDPOINT` the recognition runs on the daemon
(`activetouch serve`) over Zenoh, with the same progress lines and --json output."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys

from rich.console import Console

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import Config, load_config, profile_line
from activetouch.errors import ActiveTouchError, ConfigError
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.policies import POLICY_NAMES
from activetouch.recordings.writer import close_recorder, open_recorder
from activetouch.session.local import (
    check_request,
    load_trained,
    model_path,
    recognize_in_twin,
    result_record,
)
from activetouch.session.loop import Progress, RecognitionResult, display_label
from activetouch.transport.messages import RecognizeRequest


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "recognize", help="recognise an object by touch (in the twin, or via a daemon)"
    )
    p.add_argument(
        "--object",
        default=None,
        help="object to place on the table (required unless the daemon drives a real robot)",
    )
    p.add_argument("--policy", default=None, help=f"one of {', '.join(POLICY_NAMES)}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-moves", type=int, default=None, help="grasp budget")
    p.add_argument("--model", metavar="DIR", default=None, help="model directory")
    p.add_argument("--json", action="store_true", help="print one JSON object with the result")
    p.add_argument(
        "--connect",
        metavar="ENDPOINT",
        action="append",
        default=None,
        help="recognise through the daemon at this Zenoh endpoint (repeatable), "
        "e.g. tcp/127.0.0.1:7457",
    )
    p.add_argument("--robot", default=None, help="robot name with --connect (service.robot)")
    p.add_argument(
        "--timeout",
        type=float,
        default=None,
        help="with --connect: seconds the recognition may take (service.request_timeout_s)",
    )
    p.add_argument(
        "--detach",
        action="store_true",
        help="with --connect: let the recognition run on if this client goes away (by default "
        "the daemon cancels it when its requester is gone)",
    )
    p.add_argument(
        "--no-record",
        dest="record",
        action="store_false",
        help="write no recording of this recognition (default: recording.enabled, an MCAP file "
        "under <data>/recordings/; with --connect the daemon is asked not to record)",
    )
    add_common_options(p)
    p.set_defaults(func=run)


def format_progress(ev: Progress) -> str:
    top = "  ".join(f"{name} {p:.2f}" for name, p in ev.top) or "nothing felt yet"
    skipped = f"  ({ev.skipped} skipped)" if ev.skipped else ""
    moved = f"  robot {ev.motion_s:.1f} s" if ev.motion_s > 0 else ""
    return (
        f"move {ev.move:>2}  pose {ev.pose_id:>4}  contacts {ev.n_contacts}  |  {top}{skipped}"
        f"{moved}"
    )


def result_json(res: RecognitionResult, obj: str | None, policy: str, seed: int | None) -> dict:
    return {
        "profile": res.profile,
        "settings": res.settings,
        "object": obj,
        "policy": policy,
        "seed": seed,
        "label": res.label,
        "probability": res.probability,
        "correct": res.label == obj if obj is not None else None,
        "labels": res.labels,
        "moves": res.moves,
        "skipped": res.skipped,
        "stop_reason": res.stop_reason,
        "elapsed_s": res.elapsed_s,
        "pose_ids": res.pose_ids,
        # Robot time (docs/motion.md): moving (trajectory seconds), grasping, planning (the
        # search plus motion planning), and their total.
        "motion_s": res.motion_s,
        "grasp_s": res.grasp_s,
        "planning_s": res.planning_s,
        "search_s": res.search_s,
        "motion_planning_s": res.motion_planning_s,
        "total_s": res.total_s,
        "unreachable": res.unreachable,
        "reachability_s": res.reachability_s,
        "masked_sensors": res.masked_sensors,
        "masked_reasons": {str(i): w for i, w in res.masked_reasons.items()},
        "pose_estimate": res.pose_estimate,
    }


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config, args.overrides)
    policy = args.policy or cfg.planner.policy
    root = paths.data_dir(args.data)
    # With --json, stdout carries only the JSON object; progress goes to stderr.
    console = Console(stderr=args.json, soft_wrap=True)  # progress lines stay whole in logs
    if args.connect:
        if args.config or args.overrides:
            console.print(
                "[yellow]note:[/] --config / --set apply to this client only; the daemon "
                "plans and stops with its own configuration (serve --config)",
                highlight=False,
            )
        return run_remote(args, cfg, policy, console)
    if not args.object:
        raise ConfigError("--object is required: the twin needs the object to place")
    budget = args.max_moves if args.max_moves is not None else cfg.session.max_moves
    check_request(policy, budget, args.seed)
    console.print(f"profile {profile_line(cfg, policy)}", highlight=False)
    model = load_trained(model_path(root, args.model, cfg.hand.family))
    library = ObjectLibrary(paths.objects_dir(root))
    library.get(args.object)  # an unknown object fails here, before anything runs
    if args.object not in model.class_names:
        console.print(
            f"[yellow]note:[/] {args.object} is not one of the model's classes "
            f"({', '.join(model.class_names)}): the answer can only be the nearest of those",
            highlight=False,
        )
    console.print(
        f"recognising [bold]{args.object}[/] with the {policy} policy "
        f"({model.n_classes} known objects, seed {args.seed})"
    )
    recorder = None
    if args.record:
        # deferred: loads zenoh
        from activetouch.daemon.client import new_session_id

        recorder = open_recorder(
            root,
            cfg,
            session_id=new_session_id(),
            source="recognize",
            policy=policy,
            max_moves=budget,
            seed=args.seed,
            object_name=args.object,
            model=model,
            model_dir=model_path(root, args.model, cfg.hand.family),
        )
    try:
        res = recognize_in_twin(
            model,
            library,
            args.object,
            policy,
            args.seed,
            cfg,
            max_moves=args.max_moves,
            on_progress=lambda ev: console.print(format_progress(ev), highlight=False),
            recorder=recorder,
        )
    except BaseException as e:
        close_recorder(recorder, root, cfg, error=e)
        raise
    recorded = close_recorder(recorder, root, cfg, result=result_record(res))
    _report(args, res, args.object, policy, args.seed, console)
    if recorded is not None:  # with --json on stderr, beside the progress
        console.print(f"recorded: {recorded}", highlight=False)
    return 0


def _report(
    args: argparse.Namespace,
    res: RecognitionResult,
    obj: str | None,
    policy: str,
    seed: int | None,
    console: Console,
) -> None:
    if args.json:
        json.dump(result_json(res, obj, policy, seed), sys.stdout)
        sys.stdout.write("\n")
        return
    if obj is None:
        verdict = ""
    else:
        verdict = " — [green]correct[/]" if res.label == obj else " — [red]wrong[/]"
    console.print(
        f"recognised: [bold]{display_label(res.label)}[/] (p = {res.probability:.2f}) "
        f"after {res.moves} grasps, {res.skipped} poses skipped, "
        f"stopped: {res.stop_reason}{verdict}"
    )
    unreachable = (
        f"; {res.unreachable} poses out of the arm's reach (checked in {res.reachability_s:.1f} s)"
        if res.unreachable
        else ""
    )
    if res.masked_reasons:
        console.print(
            "sensors ignored: " + "; ".join(f"{i} {w}" for i, w in res.masked_reasons.items()),
            highlight=False,
        )
    console.print(
        f"robot time: {res.total_s:.1f} s = moving {res.motion_s:.1f} s + grasping "
        f"{res.grasp_s:.1f} s + planning {res.planning_s + res.motion_planning_s:.1f} s "
        f"(search {res.planning_s:.2f} s, motion {res.motion_planning_s:.2f} s){unreachable}",
        highlight=False,
    )


def run_remote(args: argparse.Namespace, cfg: Config, policy: str, console: Console) -> int:
    """The recognition on the daemon at --connect, with live progress."""
    # deferred: loads zenoh
    from activetouch.daemon.client import (
        new_session_id,
        open_client,
        session_progress,
        session_result,
    )

    # deferred: loads zenoh
    from activetouch.daemon.process import check_service_config

    svc = cfg.service
    if args.robot:
        svc.robot = args.robot
    check_service_config(svc)
    timeout = args.timeout if args.timeout is not None else svc.request_timeout_s
    if not timeout > 0:
        raise ConfigError(f"--timeout must be > 0, got {timeout}")
    request = RecognizeRequest(
        policy=policy,  # validated by the daemon, which names a bad value
        max_moves=args.max_moves if args.max_moves is not None else cfg.session.max_moves,
        seed=args.seed,
        object=args.object,
        session_id=new_session_id(),
        record=None if args.record else False,
    )
    with open_client(
        args.connect, svc.robot, timeout=svc.node_timeout_s, zenoh_config=svc.zenoh_config or None
    ) as client:
        console.print(
            f"recognising [bold]{args.object or 'the object on the table'}[/] with the {policy} "
            f"policy on robot {svc.robot} via {', '.join(args.connect)} (seed {args.seed})"
        )
        try:
            msg = client.recognize(
                request,
                on_progress=lambda ev: console.print(
                    format_progress(session_progress(ev)), highlight=False
                ),
                timeout=timeout,
                detached=args.detach,
            )
        except KeyboardInterrupt:
            # Do not leave the robot working for nobody.
            with contextlib.suppress(ActiveTouchError):
                client.cancel(request.session_id)
            raise
    _report(args, session_result(msg), args.object, policy, msg.seed, console)
    return 0
