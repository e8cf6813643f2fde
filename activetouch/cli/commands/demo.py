"""`activetouch demo`: the main job for a new user, in the twin.

Trains on the paper's 7 simulated objects when no model exists, recognises one object with
live progress through the recognition daemon (`activetouch serve --sim` started as a
subprocess on a free loopback port, asked over Zenoh, stopped by SIGTERM), then evaluates
tree / greedy / random on every object in-process and writes the report."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console
from rich.rule import Rule

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import load_config
from activetouch.objects.library import PAPER_SIM_OBJECTS, ObjectLibrary
from activetouch.pipelines.evaluation import parse_seeds
from activetouch.session.local import check_request, load_trained, model_path
from activetouch.session.loop import display_label
from activetouch.transport.messages import RecognizeRequest


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser("demo", help="train (if needed), recognise an object, write a report")
    p.add_argument("--object", default="mug", help="object to recognise live (default: mug)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seeds", default="0-4", help="seeds of the evaluation (default 0-4)")
    p.add_argument("--out", metavar="DIR", default=None, help="report directory")
    add_common_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # deferred: loads matplotlib, rich
    from activetouch.cli.commands.eval import evaluate

    # deferred: loads mcap
    from activetouch.cli.commands.recognize import format_progress

    # deferred: loads rich
    from activetouch.cli.commands.train import train

    # deferred: loads zenoh
    from activetouch.daemon.client import local_daemon, open_client, session_progress

    console = Console(soft_wrap=True)  # progress lines stay whole in logs
    root = paths.data_dir(args.data)
    cfg = load_config(args.config, args.overrides)
    seeds = parse_seeds(args.seeds)
    check_request("tree", cfg.session.max_moves, args.seed)
    library = ObjectLibrary(paths.objects_dir(root))
    library.ensure_builtins()
    library.get(args.object)  # an unknown object: say so before any work
    mdir = model_path(root, None)
    console.print(Rule("1. training in the twin"))
    if (mdir / "model.json").is_file():
        console.print(f"using the model at {mdir} (delete it to retrain)")
    else:
        train(root, list(PAPER_SIM_OBJECTS), args.config, args.overrides, None, None, None, console)
    load_trained(mdir)
    out = Path(args.out) if args.out else root / "reports" / "demo"
    out.mkdir(parents=True, exist_ok=True)

    console.print(Rule(f"2. recognising the {args.object} by touch, through the daemon (tree)"))
    serve_args = ["--model", str(mdir)]
    if args.config:
        serve_args += ["--config", str(args.config)]
    for item in args.overrides:
        serve_args += ["--set", item]
    log = out / "daemon.log"
    console.print("starting `python -m activetouch serve --sim` ...")
    with local_daemon(root, robot=cfg.service.robot, args=serve_args, log=log) as d:
        console.print(
            f"daemon pid {d.proc.pid} serving robot {d.robot} on {d.endpoint} (log: {log})"
        )
        with open_client([d.endpoint], d.robot, timeout=cfg.service.node_timeout_s) as client:
            res = client.recognize(
                RecognizeRequest(
                    policy="tree",
                    max_moves=cfg.session.max_moves,
                    seed=args.seed,
                    object=args.object,
                ),
                on_progress=lambda ev: console.print(
                    format_progress(session_progress(ev)), highlight=False
                ),
                timeout=cfg.service.request_timeout_s,
            )
        console.print(f"stopping the daemon (SIGTERM to pid {d.proc.pid}) ...")
    console.print(f"daemon exited with status {d.proc.returncode}")
    verdict = "[green]correct[/]" if res.label == args.object else "[red]wrong[/]"
    console.print(
        f"recognised: [bold]{display_label(res.label)}[/] (p = {res.probability:.2f}) "
        f"after {res.moves} grasps — {verdict}"
    )

    console.print(Rule("3. tree vs greedy vs random on every object"))
    evaluate(
        root,
        mdir,
        None,
        ["tree", "greedy", "random"],
        seeds,
        None,
        out,
        args.config,
        args.overrides,
        None,
        console,
        f"python -m activetouch demo --seeds {args.seeds}",
    )
    return 0
