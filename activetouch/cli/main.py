"""`activetouch` / `python -m activetouch`: the command-line entry point.

Each command lives in its own module that exposes `register(subparsers)`; the module adds its
parser and sets `func(args) -> int`. Modules are imported lazily so `--help` stays fast.
User mistakes (`ActiveTouchError`) print one line and exit 2; they never show a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from rich.console import Console
from rich.markup import escape

from activetouch import __version__
from activetouch.config import PROFILES
from activetouch.errors import ActiveTouchError

# Modules that register sub-commands, in the order `--help` lists them.
COMMAND_MODULES: tuple[str, ...] = (
    "activetouch.cli.commands.demo",
    "activetouch.cli.commands.bench",
    "activetouch.cli.commands.objects",
    "activetouch.cli.commands.train",
    "activetouch.cli.commands.recognize",
    "activetouch.cli.commands.recordings",
    "activetouch.cli.commands.view",
    "activetouch.cli.commands.eval",
    "activetouch.cli.commands.serve",
    "activetouch.cli.commands.emulate",
    "activetouch.cli.commands.calibrate",
    "activetouch.cli.commands.hardware",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="activetouch",
        description="Recognise objects by touch: ReFlex hand, MCTS pose selection, PyBullet twin.",
    )
    parser.add_argument("--version", action="version", version=f"activetouch {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def add_common_options(p: argparse.ArgumentParser) -> None:
    """Options every command that touches stored data takes."""
    p.add_argument(
        "--data",
        metavar="DIR",
        default=None,
        help="data directory (default: $ACTIVETOUCH_HOME or the user data directory)",
    )
    p.add_argument("--config", metavar="FILE", default=None, help="TOML configuration file")
    p.add_argument(
        "--set",
        metavar="SECTION.KEY=VALUE",
        action="append",
        default=[],
        dest="overrides",
        help="override one configuration value (repeatable)",
    )
    p.add_argument(
        "--profile",
        choices=list(PROFILES),
        default=None,
        help="the named set of settings to start from: robust (the default, measured best) "
        "or paper (the paper's method); --config and --set still win",
    )


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # for reports that quote the command
    if getattr(args, "profile", None):
        # first, so a later --set profile=... still wins; subprocesses get it with the rest
        args.overrides = [f"profile={args.profile}", *args.overrides]
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ActiveTouchError as e:
        # escape: a message may hold brackets (e.g. 'activetouch[ray]') that are not markup
        err = escape(str(e))
        Console(stderr=True, soft_wrap=True).print(f"[bold red]error:[/] {err}", highlight=False)
        return 2
    except OSError as e:
        # A path the user gave is missing, not a directory, read-only, full...: one line.
        where = f": {e.filename}" if e.filename else ""
        msg = escape(f"{e.strerror or e}{where}")
        Console(stderr=True, soft_wrap=True).print(f"[bold red]error:[/] {msg}", highlight=False)
        return 2
    except KeyboardInterrupt:
        Console(stderr=True).print("interrupted")
        return 130


if __name__ == "__main__":
    sys.exit(main())
