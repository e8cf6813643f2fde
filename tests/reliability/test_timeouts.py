"""Zenoh's own query timeout is reported as a timeout naming the node and key (issue 16, #5).

A queryable that never answers makes Zenoh send the querier an error reply whose payload is
the plain string "Timeout"; it used to surface as ``MessageError: ... not valid JSON``."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from activetouch.daemon.client import DaemonClient
from activetouch.daemon.remote import RemoteHand
from activetouch.errors import NodeUnavailableError
from activetouch.transport.keys import DAEMON_NODE, HAND_NODE, Keys
from activetouch.transport.messages import RecognizeRequest
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint

ROBOT = "silent"


@pytest.fixture
def sessions() -> Iterator[tuple[ZenohSession, ZenohSession]]:
    endpoint = loopback_endpoint()  # loopback, scouting off
    with (
        ZenohSession(ZenohSettings(listen=(endpoint,))) as served,
        ZenohSession(ZenohSettings.client(endpoint)) as client,
    ):
        yield served, client


def _silent(served: ZenohSession, key: str, node: str) -> list:
    """A queryable on `key` that keeps every query and never replies, and `node`'s token."""
    held: list = []  # keeping the queries alive: no final reply goes out before the timeout
    s = served.session
    served.closing(s.declare_queryable(key, held.append))
    served.closing(s.liveliness().declare_token(Keys(ROBOT).alive(node)))
    return held


def test_node_call_timeout_is_a_timeout(sessions) -> None:
    served, client = sessions
    key = Keys(ROBOT).hand_state
    held = _silent(served, key, HAND_NODE)
    rh = client.closing(RemoteHand(client.session, ROBOT, timeout=0.3))
    rh.connect()
    with pytest.raises(NodeUnavailableError, match="timed out") as info:
        rh.state()
    text = str(info.value)
    assert key in text and "hand node" in text and "JSON" not in text
    assert held  # the query did reach the silent queryable


def test_daemon_query_timeout_is_a_timeout(sessions) -> None:
    served, client = sessions
    keys = Keys(ROBOT)
    _silent(served, keys.status, DAEMON_NODE)
    dc = client.closing(DaemonClient(client.session, ROBOT, timeout=0.3))
    dc.connect(2.0)
    with pytest.raises(NodeUnavailableError, match=f"status on {keys.status} timed out"):
        dc.status()


def test_recognize_timeout_is_a_timeout(sessions) -> None:
    served, client = sessions
    keys = Keys(ROBOT)
    _silent(served, keys.recognize, DAEMON_NODE)
    dc = client.closing(DaemonClient(client.session, ROBOT, timeout=0.3))
    dc.connect(2.0)
    req = RecognizeRequest(policy="tree", max_moves=2, object="cup")
    with pytest.raises(NodeUnavailableError, match=f"recognize on {keys.recognize} timed out"):
        dc.recognize(req, timeout=0.3)
