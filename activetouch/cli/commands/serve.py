"""`activetouch serve` (the daemon) and its small clients `status`, `cancel`, `estop`.

`activetouch recognize --connect ...` (commands/recognize.py) is the recognition client.
Clients find the daemon at `--connect ENDPOINT` (repeatable), or else at the endpoints the
daemon of the same configuration listens on (``service.listen``, default tcp/127.0.0.1:7457;
with ``service.zenoh_mode = "client"`` the router it joined, ``service.connect``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import msgspec
from rich.console import Console

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import Config, load_config, set_devices
from activetouch.device_types import DEFAULT_ARM, DEFAULT_HAND
from activetouch.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "serve",
        help="run the recognition daemon (Zenoh API, docs/api.md)",
        description=(
            "Run the recognition daemon. The robot's hand and arm are made from the [hand] and "
            "[arm] configuration (default: the PyBullet twin) and served as Zenoh nodes; "
            "recognitions run on them through Zenoh. Stops cleanly on SIGTERM / SIGINT."
        ),
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--sim",
        dest="mode",
        action="store_const",
        const="sim",
        help="the twin: shorthand for hand.type=twin, arm.type=twin-floating (simulated types "
        "already configured are kept)",
    )
    mode.add_argument(
        "--hardware",
        dest="mode",
        action="store_const",
        const="hardware",
        help="the real robot: the configured hand and arm types must be real devices",
    )
    p.set_defaults(mode=None)
    p.add_argument(
        "--role",
        choices=("all", "nodes", "daemon"),
        default="all",
        help="all: nodes and recognition service in this process (default); nodes: only the "
        "hand/arm(/sim) nodes; daemon: only the service, reaching nodes served elsewhere",
    )
    _client_options(p, serving=True)
    p.add_argument("--model", metavar="DIR", default=None, help="model directory")
    p.add_argument("--log-format", choices=("logfmt", "json"), default="logfmt")
    p.add_argument("--log-level", default="info", help="debug | info | warning | error")
    add_common_options(p)
    p.set_defaults(func=run_serve)

    for name, helptext, fn in (
        ("status", "show the daemon's status (nodes, session, model)", run_status),
        ("cancel", "cancel the running recognition", run_cancel),
        ("estop", "emergency stop: abort the recognition, stop the arm, open the hand", run_estop),
    ):
        q = sub.add_parser(name, help=helptext)
        _client_options(q, serving=False)
        if name == "cancel":
            q.add_argument("--session", default=None, help="session id (default: the current)")
        if name == "estop":
            q.add_argument("--reason", default="", help="recorded in the daemon's log")
        q.add_argument("--json", action="store_true", help="print the reply as JSON")
        add_common_options(q)
        q.set_defaults(func=fn)

    a = sub.add_parser(
        "arm",
        help="enable or disable the arm's motors (robots that have such a state, e.g. Baxter)",
        description="Talks to the arm node directly (on the robot PC: the nodes' keys are not "
        "reachable remotely under the shipped access control). The daemon never enables the "
        "arm by itself.",
    )
    a.add_argument("action", choices=("enable", "disable"))
    _client_options(a, serving=False)
    add_common_options(a)
    a.set_defaults(func=run_arm)


def _client_options(p: argparse.ArgumentParser, serving: bool) -> None:
    p.add_argument("--robot", default=None, help="robot name (default: service.robot)")
    if serving:
        p.add_argument(
            "--listen",
            metavar="ENDPOINT",
            action="append",
            default=None,
            help="Zenoh endpoint to listen on (repeatable; default service.listen, "
            "tcp/127.0.0.1:7457)",
        )
    p.add_argument(
        "--connect",
        metavar="ENDPOINT",
        action="append",
        default=None,
        help="Zenoh endpoint to connect to (repeatable)"
        + ("" if serving else "; default: the daemon's service.listen"),
    )
    if not serving:
        p.add_argument(
            "--timeout", type=float, default=None, help="seconds (default service.node_timeout_s)"
        )


def service_config(args: argparse.Namespace) -> Config:
    """The configuration with the command line's --robot / --listen / --connect applied."""
    # deferred: loads mcap, numba, scipy, zenoh
    from activetouch.daemon.process import check_service_config

    if args.config:  # errors of the file name the file; those of --set name the key
        try:
            check_service_config(load_config(args.config).service)
        except ConfigError as e:
            text = str(e)
            raise ConfigError(
                text if str(args.config) in text else f"{args.config}: {text}"
            ) from None
    cfg = load_config(args.config, args.overrides)
    svc = cfg.service
    if args.robot:
        svc.robot = args.robot
    if getattr(args, "listen", None):
        svc.listen = list(args.listen)
    if args.connect:
        svc.connect = list(args.connect)
    return cfg


def client_endpoints(args: argparse.Namespace, cfg: Config) -> list[str]:
    """--connect, else the endpoints a daemon with this configuration listens on (in
    ``service.zenoh_mode = "client"``: the router it joined, ``service.connect``)."""
    if args.connect:
        return list(args.connect)
    if cfg.service.zenoh_mode == "client":
        if cfg.service.connect:
            return list(cfg.service.connect)
        raise ConfigError(
            "service.zenoh_mode=client: the daemon is reached through its router; set "
            "service.connect or give --connect ENDPOINT"
        )
    eps = [e for e in cfg.service.listen if not e.endswith(":0")]  # port 0: not knowable
    if not eps:
        raise ConfigError("no endpoint to reach the daemon: give --connect ENDPOINT")
    return eps


def resolve_mode(flag: str | None, cfg: Config) -> str:
    """``sim`` or ``hardware``: from --sim / --hardware, else from the configured devices.
    --sim makes the devices the twin's, unless simulated types are configured already."""

    if flag == "sim":
        raw = {
            "hand": {"type": DEFAULT_HAND} if not cfg.hand.simulated else None,
            "arm": {"type": DEFAULT_ARM} if not cfg.arm.simulated else None,
        }
        for kind, section in raw.items():
            if section is not None:
                set_devices(cfg, {kind: section}, only=(kind,))
        return "sim"
    if flag == "hardware":
        return "hardware"
    # A real hand on a fake arm (a bench test of the hand) is a real robot: no placing.
    return "sim" if cfg.hand.simulated and cfg.arm.simulated else "hardware"


def run_serve(args: argparse.Namespace) -> int:
    # deferred: loads mcap, numba, scipy, zenoh
    from activetouch.daemon.process import DaemonOptions, serve, setup_logging

    # deferred: loads numba, scipy
    from activetouch.session.local import model_path

    cfg = service_config(args)
    root = paths.data_dir(args.data)
    opts = DaemonOptions(
        mode=resolve_mode(args.mode, cfg),
        role=args.role,
        data=root,
        model_dir=model_path(root, args.model, cfg.hand.family),
        cfg=cfg,
    )
    setup_logging(args.log_format, args.log_level)
    return serve(opts)


def _connect(args: argparse.Namespace):  # -> contextmanager[DaemonClient]
    # deferred: loads numba, scipy, zenoh
    from activetouch.daemon.client import open_client

    # deferred: loads mcap, numba, scipy, zenoh
    from activetouch.daemon.process import check_service_config

    cfg = service_config(args)
    check_service_config(cfg.service)
    svc = cfg.service
    timeout = args.timeout if args.timeout is not None else svc.node_timeout_s
    if not timeout > 0:
        raise ConfigError(f"--timeout must be > 0, got {timeout}")
    return open_client(
        client_endpoints(args, cfg),
        svc.robot,
        timeout=timeout,
        zenoh_config=svc.zenoh_config or None,
    )


def _print_json(msg: msgspec.Struct) -> None:
    json.dump(msgspec.to_builtins(msg), sys.stdout)
    sys.stdout.write("\n")


def run_status(args: argparse.Namespace) -> int:
    # deferred: loads numba, scipy, zenoh
    from activetouch.daemon.client import describe_status

    with _connect(args) as client:
        st = client.status()
    if args.json:
        _print_json(st)
    else:
        console = Console()
        for line in describe_status(st):
            console.print(line, highlight=False)
    return 0


def run_cancel(args: argparse.Namespace) -> int:
    with _connect(args) as client:
        res = client.cancel(args.session)
    if args.json:
        _print_json(res)
    elif res.cancelled:
        Console().print(f"cancelled recognition {res.session_id}", highlight=False)
    else:
        what = f"recognition {args.session}" if args.session else "recognition"
        Console().print(f"no {what} to cancel", highlight=False)
    return 0


def run_estop(args: argparse.Namespace) -> int:
    with _connect(args) as client:
        res = client.estop(args.reason)
    if args.json:
        _print_json(res)
    else:
        Console().print(
            f"emergency stop: arm {'stopped' if res.arm_stopped else 'NOT stopped'}, hand "
            f"{'opened' if res.hand_opened else 'NOT opened'}"
            + (f" ({'; '.join(res.errors)})" if res.errors else ""),
            highlight=False,
        )
    return 0 if res.arm_stopped and res.hand_opened else 1


def run_arm(args: argparse.Namespace) -> int:
    # deferred: loads scipy, zenoh
    from activetouch.daemon.remote import RemoteArm

    # deferred: loads zenoh
    from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings

    cfg = service_config(args)
    svc = cfg.service
    timeout = args.timeout if args.timeout is not None else svc.node_timeout_s
    if not timeout > 0:
        raise ConfigError(f"--timeout must be > 0, got {timeout}")
    settings = ZenohSettings.client(
        *client_endpoints(args, cfg),
        config_file=paths_or_none(svc.zenoh_config),
    )
    with ZenohSession(settings) as zs:
        arm = zs.closing(
            RemoteArm(zs.session, svc.robot, timeout, motion_timeout=svc.motion_timeout_s)
        )
        arm.connect()
        getattr(arm, args.action)()
    Console().print(f"arm of robot {svc.robot}: {args.action}d", highlight=False)
    return 0


def paths_or_none(path: str):  # -> Path | None

    return Path(path) if path else None
