"""Finding 1 of the reliability issue: a client that declares and drops a node's liveliness
token must not make the daemon's side believe the node is gone; a real node's death must."""

from __future__ import annotations

import time

from activetouch.daemon.liveliness import AliveNodes
from activetouch.daemon.nodes import HandNode
from activetouch.daemon.remote import RemoteHand
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.doubles import RecordingHand
from tests.loopback import loopback_endpoint

ROBOT = "spoofbot"


def test_a_spoofed_token_drop_changes_nothing_and_a_real_one_is_seen() -> None:
    ep = loopback_endpoint()
    # As `serve` runs by default: the nodes and the daemon share one session (that is where a
    # dropped remote token on the same key is reported as a DELETE); the attacker is a client.
    with (
        ZenohSession(ZenohSettings(listen=(ep,))) as node_zs,
        ZenohSession(ZenohSettings.client(ep)) as attacker,
    ):
        daemon_zs = node_zs
        node = HandNode(RecordingHand(), node_zs.session, ROBOT, state_hz=0)
        hand = daemon_zs.closing(RemoteHand(daemon_zs.session, ROBOT, timeout=3.0))
        alive = daemon_zs.closing(AliveNodes(daemon_zs.session, ROBOT))
        hand.connect()
        alive.wait_for("hand", timeout=5.0)
        key = f"activetouch/{ROBOT}/alive/hand"
        for _ in range(5):  # declare / drop from a plain client
            token = attacker.session.liveliness().declare_token(key)
            time.sleep(0.2)
            token.undeclare()
        time.sleep(1.5)  # longer than a liveliness check
        assert hand.alive is True
        assert alive.snapshot()["hand"] is True
        hand.guarded_close()  # the node still answers, and is still used
        node.close()  # now it really goes
        deadline = time.monotonic() + 5.0
        while hand.alive is not False and time.monotonic() < deadline:
            time.sleep(0.05)
        assert hand.alive is False
        alive.wait_for("hand", timeout=5.0, alive=False)
