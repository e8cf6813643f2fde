"""`activetouch view [--connect ENDPOINT] [--robot NAME] [--port N]`: a live 3-D view of the
daemon's recognitions in Rerun's web viewer, served on 127.0.0.1 only (docs/api.md, "Live 3-D
view"). It shows what the daemon publishes (no second physics): the table, the object at its
placement, the hand at each grasp's wrist goal with its contacts, the wrist goals so far and
the belief per class."""

from __future__ import annotations

import argparse
import signal
import threading
from contextlib import suppress

from rich.console import Console

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import load_config
from activetouch.errors import ConfigError

DEFAULT_WEB_PORT = 9090
INSTALL_HINT = "the live view needs Rerun: pip install 'activetouch[view]' (rerun-sdk)"


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "view",
        help="a live 3-D view (Rerun, in a browser on 127.0.0.1) of the daemon's recognitions",
        description="Serve Rerun's web viewer on 127.0.0.1 and show every recognition the "
        "daemon runs: the table, the object, the hand and its contacts at each grasp, the "
        "wrist goals and the belief per class. Open the printed address in a browser.",
    )
    p.add_argument(
        "--connect",
        metavar="ENDPOINT",
        action="append",
        default=None,
        help="the daemon's Zenoh endpoint (repeatable; default tcp/127.0.0.1:7457)",
    )
    p.add_argument("--robot", default=None, help="robot name (service.robot)")
    p.add_argument(
        "--port",
        type=int,
        default=DEFAULT_WEB_PORT,
        help=f"port of the web viewer on 127.0.0.1 (default {DEFAULT_WEB_PORT})",
    )
    p.add_argument(
        "--grpc-port",
        type=int,
        default=None,
        help="port of Rerun's data proxy on 127.0.0.1 (default: a free one)",
    )
    add_common_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # deferred: loads numba, scipy, zenoh
    from activetouch.daemon.client import client_settings

    # deferred: loads mcap, numba, scipy, zenoh
    from activetouch.daemon.process import check_service_config

    # deferred: loads zenoh
    from activetouch.transport.zenoh_session import ZenohSession, loopback_endpoint

    try:  # optional: the `view` extra
        # optional: rerun-sdk is the [view] extra
        import rerun as rr

        # optional: view.scene imports rerun at its top (and loads scipy)
        from activetouch.view.scene import SceneLogger, library_meshes
    except ImportError:
        raise ConfigError(INSTALL_HINT) from None
    # deferred: loads scipy, zenoh
    from activetouch.view.live import ProgressFeed, RerunServer

    cfg = load_config(args.config, args.overrides)
    svc = cfg.service
    if args.robot:
        svc.robot = args.robot
    check_service_config(svc)
    connect = list(args.connect or [loopback_endpoint()])
    console = Console(stderr=True)
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        # SIGTERM (systemd, kill) ends the view as Ctrl-C does: the Rerun server stops too.
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with RerunServer(args.port, args.grpc_port) as server:
        rec = rr.RecordingStream("activetouch", recording_id=f"activetouch-{svc.robot}")
        rec.connect_grpc(server.grpc_url)
        scene = SceneLogger(
            rec, cfg.workcell, library_meshes(paths.objects_dir(paths.data_dir(args.data)))
        )
        scene.start()
        settings = client_settings(connect, svc.zenoh_config or None)
        with ZenohSession(settings) as zs:
            feed = ProgressFeed(zs.session, svc.robot, scene.on_progress)
            console.print(
                f"live view of robot {svc.robot} via {', '.join(connect)}: open "
                f"{server.viewer_url}  (Ctrl-C ends)",
                highlight=False,
                soft_wrap=True,
            )
            try:
                feed.run(stop)
            except KeyboardInterrupt:
                stop.set()
            finally:
                feed.close()
                with suppress(Exception):  # the server may be gone already (killed with us)
                    rec.flush()
                    rec.disconnect()
    return 0
