"""`activetouch hardware check`: the configured hand and arm walked step by step, what is
wrong and the command that fixes it (activetouch.pipelines.hardware_check)."""

from __future__ import annotations

import argparse
import json

from rich.console import Console
from rich.table import Table

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import load_config
from activetouch.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "hardware",
        help="bring-up: check the connected hand and arm, say what is wrong and how to fix it",
        description="Connect the configured devices (nothing moves), measure their streams, "
        "check their readings, calibrations, bridge and robot state. Exit 1 if a step fails.",
    )
    p.add_argument("what", choices=("check",))
    p.add_argument("--seconds", type=float, default=1.0, help="how long to measure each stream")
    p.add_argument("--json", action="store_true", help="print the steps as JSON")
    add_common_options(p)
    p.set_defaults(func=run)


STYLE = {"ok": "green", "warn": "yellow", "fail": "bold red", "skip": "dim"}


def run(args: argparse.Namespace) -> int:
    # deferred: loads scipy
    from activetouch.pipelines.hardware_check import FAIL, hardware_check

    if not args.seconds > 0:
        raise ConfigError(f"--seconds must be > 0, got {args.seconds}")
    cfg = load_config(args.config, args.overrides)
    steps = hardware_check(cfg, paths.data_dir(args.data), args.seconds)
    if args.json:
        print(json.dumps({"steps": [s.as_dict() for s in steps]}, indent=2))
    else:
        table = Table(title=f"hardware check: hand {cfg.hand.type}, arm {cfg.arm.type}")
        for col in ("device", "step", "", "what was found", "fix"):
            table.add_column(col, overflow="fold")
        for s in steps:
            table.add_row(s.device, s.name, f"[{STYLE[s.status]}]{s.status}[/]", s.detail, s.fix)
        Console(soft_wrap=True).print(table)
    return 1 if any(s.status == FAIL for s in steps) else 0
