"""The recognition daemon process (`activetouch serve`): the Zenoh API of docs/api.md.

One process, up to two roles (``--role``):

- **nodes**: the robot's devices, made from the ``[hand]`` and ``[arm]`` configuration
  (activetouch.devices), served as Zenoh nodes (`DeviceNodes`: hand, arm, and ``sim/place``
  for simulated devices). ``--sim`` is shorthand for the twin's device types.
- **daemon**: the recognition service (`recognition_service.RecognitionService`), which reaches
  the devices only through Zenoh, whether the nodes live in this process (role ``all``, the
  default) or in another one (role ``daemon``).

This module names no device type. Its parts: `systemd` (readiness, watchdog), `logs`
(structured logging), `recognition_service`, `nodes`.

Shutdown (SIGTERM / SIGINT): the daemon token and queryables go first, queued requests get an
error, the running recognition is aborted like an e-stop and joined, the nodes close (an arm
node closing mid-motion stops the arm), then the Zenoh session closes.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from activetouch.config import Config, ServiceConfig
from activetouch.daemon.device_nodes import DeviceNodes
from activetouch.daemon.logs import JsonFormatter, LogfmtFormatter, setup_logging
from activetouch.daemon.recognition_service import RecognitionService
from activetouch.daemon.ros2_face import Ros2Face
from activetouch.daemon.supervision import LinkSettings
from activetouch.daemon.systemd import sd_notify, watchdog_period
from activetouch.devices import make_devices
from activetouch.errors import ConfigError
from activetouch.transport.keys import validate_robot
from activetouch.transport.zenoh_session import (
    ZenohSession,
    ZenohSettings,
    validate_endpoint,
)

log = logging.getLogger("activetouch.daemon")

MODES = ("sim", "hardware")
ROLES = ("all", "nodes", "daemon")

__all__ = [
    "Daemon",
    "DaemonOptions",
    "JsonFormatter",
    "LogfmtFormatter",
    "check_service_config",
    "listen_endpoints",
    "sd_notify",
    "serve",
    "setup_logging",
    "watchdog_period",
    "zenoh_settings",
]


# --------------------------------------------------------------------------- configuration


def check_service_config(svc: ServiceConfig) -> None:
    """ConfigError naming the ``service.*`` key that is wrong."""

    try:
        validate_robot(svc.robot)
    except ConfigError as e:
        raise ConfigError(f"service.robot: {e}") from None
    for name in ("listen", "connect"):
        for ep in getattr(svc, name):
            try:
                validate_endpoint(ep)
            except ConfigError as e:
                raise ConfigError(f"service.{name}: {e}") from None
    positive = (
        "node_timeout_s",
        "motion_timeout_s",
        "request_timeout_s",
        "device_retry_s",
        "device_check_s",
        "device_lost_after_s",
    )
    non_negative = (
        "node_wait_s",
        "state_hz",
        "max_queued",
        "shutdown_timeout_s",
        "sim_motion_delay_s",
        "max_plan_s",
    )
    for name in positive:
        if not getattr(svc, name) > 0:
            raise ConfigError(f"service.{name} must be > 0, got {getattr(svc, name)}")
    for name in non_negative:
        if not getattr(svc, name) >= 0:
            raise ConfigError(f"service.{name} must be >= 0, got {getattr(svc, name)}")
    if svc.zenoh_mode == "client" and not svc.connect:
        raise ConfigError(
            "service.zenoh_mode=client joins a Zenoh router: name it in service.connect, "
            'e.g. service.connect=["tcp/127.0.0.1:7447"] for a local rmw_zenohd'
        )
    if svc.zenoh_config and not Path(svc.zenoh_config).is_file():
        raise ConfigError(f"service.zenoh_config: {svc.zenoh_config} does not exist")


def exposed_endpoints(svc: ServiceConfig) -> list[str]:
    """Listen endpoints reachable from other machines and not protected by TLS."""
    out: list[str] = []
    for ep in listen_endpoints(svc):
        proto, _, rest = ep.partition("/")
        host = rest.rsplit(":", 1)[0].strip("[]")
        local = host in ("localhost", "::1") or host.startswith("127.")
        if proto != "tls" and not local and proto != "unixsock-stream":
            out.append(ep)
    return out


def listen_endpoints(svc: ServiceConfig) -> list[str]:
    """What the daemon listens on: `svc.listen` in peer mode, nothing in client mode."""
    return [] if svc.zenoh_mode == "client" else list(svc.listen)


def zenoh_settings(svc: ServiceConfig) -> ZenohSettings:
    """The daemon's session, scouting off. Peer mode (default): listens on `svc.listen` and
    connects to `svc.connect`. Client mode: a client of the Zenoh router at `svc.connect`
    (e.g. the lab's rmw_zenohd), listening on nothing."""
    return ZenohSettings(
        listen=tuple(listen_endpoints(svc)),
        connect=tuple(svc.connect),
        mode=svc.zenoh_mode,
        config_file=Path(svc.zenoh_config) if svc.zenoh_config else None,
    )


@dataclass(frozen=True)
class DaemonOptions:
    mode: str  # sim | hardware
    role: str  # all | nodes | daemon
    data: Path  # data directory (object library, models)
    model_dir: Path
    cfg: Config

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"mode {self.mode!r} is invalid: use one of {', '.join(MODES)}")
        if self.role not in ROLES:
            raise ConfigError(f"role {self.role!r} is invalid: use one of {', '.join(ROLES)}")
        check_service_config(self.cfg.service)
        if self.cfg.ros2.enabled and self.role == "nodes":
            raise ConfigError(
                "ros2.enabled: the ROS 2 face is the recognition service's; run it with "
                "--role all or --role daemon (this process serves only the nodes)"
            )
        if self.role != "daemon":
            hand, arm = self.cfg.hand, self.cfg.arm
            simulated = hand.simulated and arm.simulated
            if self.mode == "sim" and not simulated:
                raise ConfigError(
                    f"--sim runs simulated devices, not hand {hand.type!r} with arm {arm.type!r}"
                )
            if self.mode == "hardware" and simulated:
                raise ConfigError(
                    "--hardware needs real devices: set hand.type (reflex-takktile | "
                    "reflex-sf) and arm.type (baxter); a real hand may ride a fake arm"
                )


# --------------------------------------------------------------------------- the process


class Daemon:
    """Everything `activetouch serve` runs, opened by `start` and closed by `close`."""

    def __init__(self, opts: DaemonOptions) -> None:
        self.opts = opts
        self.zs: ZenohSession | None = None
        self.devices: Any = None
        self.nodes: DeviceNodes | None = None
        self.service: RecognitionService | None = None
        self.ros2: Any = None  # the ROS 2 face (ros2_face.Ros2Face) with [ros2] enabled

    def start(self) -> None:
        opts, svc = self.opts, self.opts.cfg.service
        try:
            self.zs = ZenohSession(zenoh_settings(svc))
            log.info(
                "zenoh session open",
                extra={
                    "mode": svc.zenoh_mode,
                    "listen": ",".join(listen_endpoints(svc)),
                    "connect": ",".join(svc.connect),
                },
            )
            for ep in exposed_endpoints(svc):
                log.warning(
                    "listening beyond this machine without TLS: anyone who reaches %s can move "
                    "the robot; use tls/ endpoints with deploy/zenoh-tls-acl.json5 "
                    "(service.zenoh_config)",
                    ep,
                )
            if opts.role in ("all", "nodes"):
                # Made now (a wrong setting fails here), connected as they appear: a robot
                # PC may boot before its robot, and a device may go and come back.
                self.devices = make_devices(opts.cfg, opts.data, connect=False)
                self.nodes = DeviceNodes(
                    self.devices,
                    self.zs.session,
                    svc.robot,
                    svc.state_hz,
                    links=LinkSettings(
                        retry_s=svc.device_retry_s,
                        check_s=svc.device_check_s,
                        lost_after_s=svc.device_lost_after_s,
                    ),
                )
            if opts.role in ("all", "daemon"):
                self.service = RecognitionService(
                    self.zs.session, svc.robot, opts.mode, opts.cfg, opts.model_dir, opts.data
                )
                self.service.start(svc.node_wait_s)
                if opts.cfg.ros2.enabled:
                    self.ros2 = Ros2Face(self.zs.session, self.service, opts.cfg)
                    self.ros2.start()
        except BaseException:
            self.close()
            raise

    def healthy(self) -> bool:
        return (self.service is None or self.service.healthy()) and (
            self.nodes is None or self.nodes.healthy()
        )

    def close(self) -> None:
        if self.ros2 is not None:
            self.ros2.close()
            self.ros2 = None
        if self.service is not None:
            self.service.close()
            self.service = None
        if self.nodes is not None:
            self.nodes.close()
            self.nodes = None
        if self.devices is not None:
            # A worker stuck in a device must not meet a closed device: wait for the lock.
            if self.devices.lock.acquire(timeout=1.0):
                try:
                    self.devices.close()
                finally:
                    self.devices.lock.release()
            self.devices = None
        if self.zs is not None:
            self.zs.close()
            self.zs = None
            log.info("zenoh session closed")


def serve(opts: DaemonOptions, stop: threading.Event | None = None) -> int:
    """Run the daemon until SIGTERM / SIGINT (or `stop` is set). Returns the exit code.

    A second signal while shutting down exits at once (status 1)."""
    stop = stop or threading.Event()
    received: list[int] = []
    old: dict[int, Any] = {}

    def on_signal(signum: int, _frame: Any) -> None:
        if stop.is_set() and received:
            os._exit(1)  # the operator insists: do not wait for a stuck shutdown
        received.append(signum)
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            old[sig] = signal.signal(sig, on_signal)
    daemon = Daemon(opts)
    try:
        daemon.start()
        sd_notify(f"READY=1\nSTATUS=serving robot {opts.cfg.service.robot}\nMAINPID={os.getpid()}")
        log.info(
            "ready",
            extra={"pid": os.getpid(), "role": opts.role, "mode": opts.mode},
        )
        period = watchdog_period()
        tick = min(0.5, period / 2) if period else 0.5
        last_ping = 0.0
        while not stop.wait(tick):
            if period and time.monotonic() - last_ping >= period / 2:
                if daemon.healthy():
                    sd_notify("WATCHDOG=1")
                    last_ping = time.monotonic()
                else:
                    log.error("a service thread died: no watchdog ping (systemd will restart)")
        t0 = time.monotonic()
        name = signal.Signals(received[0]).name if received else "stop"
        log.info("shutting down", extra={"signal": name})
        sd_notify("STOPPING=1")
        daemon.close()
        log.info("stopped", extra={"shutdown_s": round(time.monotonic() - t0, 3)})
        return 0
    finally:
        daemon.close()
        for sig, handler in old.items():
            signal.signal(sig, handler)
