"""No port clash with a ROS 2 robot (issue 25): the default endpoints stay off rmw_zenohd's
7447, and the daemon can join an existing Zenoh router as a client, listening on nothing.

The "router" here is a real Zenoh router (``mode = "router"``, what rmw_zenohd is) opened in
this process on a free loopback port; the daemon's nodes and its service run in this process
too, in two sessions that are both clients of the router, on the fake devices.
"""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from activetouch import paths
from activetouch.cli.commands.serve import client_endpoints, resolve_mode
from activetouch.config import ServiceConfig, load_config
from activetouch.daemon.client import open_client
from activetouch.daemon.process import (
    Daemon,
    DaemonOptions,
    check_service_config,
    listen_endpoints,
    zenoh_settings,
)
from activetouch.errors import ConfigError
from activetouch.transport.messages import RecognizeRequest
from activetouch.transport.zenoh_session import (
    DEFAULT_PORT,
    ZenohSettings,
    free_tcp_port,
    loopback_endpoint,
    make_config,
)

RMW_ZENOHD_PORT = 7447
DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_default_endpoints_do_not_use_rmw_zenohds_port() -> None:
    assert DEFAULT_PORT != RMW_ZENOHD_PORT
    svc = ServiceConfig()
    assert svc.listen == [loopback_endpoint()]  # one default, in config and transport alike
    assert svc.zenoh_mode == "peer"
    for ep in (*svc.listen, *ZenohSettings().listen, *ZenohSettings.server().listen):
        assert not ep.endswith(f":{RMW_ZENOHD_PORT}"), ep
    deployed = load_config(DEPLOY / "activetouch.toml").service
    assert deployed.listen == svc.listen and deployed.zenoh_mode == "peer"

    class Args:
        connect = None

    # The small clients find the daemon where it listens by default.
    assert client_endpoints(Args(), load_config(None)) == svc.listen


def test_client_mode_listens_on_nothing_and_needs_a_router() -> None:
    cfg = load_config(None, ["service.zenoh_mode=client", 'service.connect=["tcp/127.0.0.1:7447"]'])
    svc = cfg.service
    check_service_config(svc)
    assert listen_endpoints(svc) == []
    s = zenoh_settings(svc)
    assert s.mode == "client" and s.listen == () and s.connect == ("tcp/127.0.0.1:7447",)
    conf = make_config(s)
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("listen/endpoints")) == []

    class Args:
        connect = None

    assert client_endpoints(Args(), cfg) == ["tcp/127.0.0.1:7447"]  # through the router

    with pytest.raises(ConfigError, match=r"service.zenoh_mode=client .*service.connect"):
        check_service_config(load_config(None, ["service.zenoh_mode=client"]).service)
    with pytest.raises(ConfigError, match="zenoh_mode: 'router' is not one of peer, client"):
        load_config(None, ["service.zenoh_mode=router"])


@pytest.fixture
def router() -> Iterator[str]:
    """A Zenoh router on a free loopback port (as rmw_zenohd is one), scouting off."""
    ep = loopback_endpoint(free_tcp_port())
    conf = zenoh.Config()
    for key, value in (
        ("mode", "router"),
        ("scouting/multicast/enabled", False),
        ("scouting/gossip/enabled", False),
        ("listen/endpoints", [ep]),
        ("connect/endpoints", []),
    ):
        conf.insert_json5(key, json.dumps(value))
    session = zenoh.open(conf)
    try:
        yield ep
    finally:
        session.close()


def _port_open(ep: str) -> bool:
    host, port = ep.split("/", 1)[1].rsplit(":", 1)
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex((host, int(port))) == 0


def test_a_client_mode_daemon_reaches_its_nodes_through_a_router(
    router: str, trained_home: Path
) -> None:
    unused = loopback_endpoint(free_tcp_port())  # set as listen: client mode must ignore it
    cfg = load_config(
        None,
        [
            "hand.type=fake",
            "arm.type=fake",
            "service.robot=routed",
            "service.zenoh_mode=client",
            f'service.connect=["{router}"]',
            f'service.listen=["{unused}"]',
        ],
    )

    def options(role: str) -> DaemonOptions:
        return DaemonOptions(
            mode=resolve_mode(None, cfg),
            role=role,
            data=trained_home,
            model_dir=paths.default_model(trained_home),
            cfg=cfg,
        )

    # Nodes and service in two sessions, both clients of the router: nothing else links them.
    nodes, daemon = Daemon(options("nodes")), Daemon(options("daemon"))
    try:
        nodes.start()
        daemon.start()  # waits for the hand and arm nodes' tokens: they come via the router
        assert not _port_open(unused)  # neither listens
        for d in (nodes, daemon):
            assert d.zs is not None and d.zs.session.info.routers_zid()
            assert not d.zs.session.info.peers_zid()
        with open_client([router], "routed", timeout=10.0) as client:
            st = client.status()
            assert st.nodes["hand"].alive and st.nodes["arm"].alive
            res = client.recognize(
                RecognizeRequest(policy="greedy", max_moves=3, seed=1, object="cup"),
                timeout=120.0,
            )
        assert res.moves >= 1 and res.labels
    finally:
        daemon.close()
        nodes.close()
