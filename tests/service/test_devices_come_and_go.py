"""Devices that come and go (issue 23): the daemon starts without its robot, connects when it
appears, reconnects after a loss, and says in `status` which device is connected, waiting or
lost, with why and since when.

The robot here is a tagged-release bridge (legacy keys) with Baxter behind it, started after
the daemon, with the arm's default settings, as on a robot PC that boots before Baxter."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest

from activetouch.config import load_config
from activetouch.daemon.process import Daemon, DaemonOptions
from activetouch.emulators.baxter_bridge import BaxterEmulator, EmulatorSettings
from activetouch.errors import NodeUnavailableError
from activetouch.transport.messages import Status
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint

WAIT_S = 60.0  # generous: a loaded machine may be slow; nothing here is a timing window


def wait_status(daemon: Daemon, ok: Callable[[Status], bool], what: str) -> Status:
    assert daemon.service is not None
    deadline = time.monotonic() + WAIT_S
    st = daemon.service.status()
    while not ok(st):
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not reached within {WAIT_S:g} s: {st}")
        time.sleep(0.05)
        st = daemon.service.status()
    return st


@pytest.mark.slow
def test_the_daemon_waits_for_a_late_bridge_and_follows_it_going_and_coming(
    tmp_path: Path,
) -> None:
    ep, bridge = loopback_endpoint(), loopback_endpoint()
    cfg = load_config(
        None,
        [
            "hand.type=fake",
            "arm.type=baxter",
            f'arm.connect=["{bridge}"]',  # the bridge's Zenoh endpoint, not up yet
            f'service.listen=["{ep}"]',
            "service.robot=late",
            "service.node_wait_s=0.2",
            "service.device_retry_s=0.2",
            "service.device_check_s=0.1",
        ],
    )
    assert cfg.arm.bridge_format == "auto" and cfg.arm.connect_timeout_s == 5.0  # defaults
    opts = DaemonOptions("hardware", "all", tmp_path, tmp_path / "no-model", cfg)
    daemon = Daemon(opts)
    started = time.monotonic()
    daemon.start()  # before: ConfigError / NodeUnavailableError "no joint state ... within 5 s"
    try:
        st = wait_status(
            daemon,
            lambda s: s.nodes["arm"].state == "waiting" and s.nodes["arm"].detail != "",
            "the arm waiting for its bridge",
        )
        assert not st.nodes["arm"].alive and st.nodes["arm"].device == "baxter"
        assert st.nodes["hand"].state == "connected" and st.nodes["hand"].alive
        waiting_since = st.nodes["arm"].since
        assert waiting_since is not None and waiting_since <= time.time()

        # The probe: the bridge comes up 8 s after the daemon started.
        time.sleep(max(0.0, 8.0 - (time.monotonic() - started)))
        with ZenohSession(ZenohSettings(listen=(bridge,))) as zs:
            robot = BaxterEmulator(zs.session, EmulatorSettings(enabled=True, legacy=True))
            try:
                st = wait_status(daemon, lambda s: s.nodes["arm"].alive, "the arm connected")
                assert st.nodes["arm"].state == "connected"
                assert daemon.devices.arm.bridge_format == "legacy"
            finally:
                robot.close()  # Baxter (or its bridge) goes away
            # The node's token may drop a moment before its health (with the reason) arrives:
            # the status says "lost" at once and names the reason once it is in.
            st = wait_status(
                daemon,
                lambda s: s.nodes["arm"].state == "lost" and "joint state" in s.nodes["arm"].detail,
                "the arm lost, with the reason",
            )
            assert not st.nodes["arm"].alive
            # A recognition asked now is refused at once with the reason (here the missing
            # model speaks first; the arm is checked in test_daemon's killed-node test).
            robot = BaxterEmulator(zs.session, EmulatorSettings(enabled=True, legacy=True))
            try:
                st = wait_status(daemon, lambda s: s.nodes["arm"].alive, "the arm reconnected")
                assert st.nodes["arm"].state == "connected"
                assert daemon.devices.arm.joint_state().position.shape == (7,)
            finally:
                robot.close()
    finally:
        daemon.close()


def test_a_device_node_answers_commands_only_while_connected(tmp_path: Path) -> None:
    """The hand node of a hand that cannot connect: no liveliness token, and a command gets
    the link's reason at once rather than a driver's traceback."""
    import threading

    from activetouch.daemon.nodes import HandNode
    from activetouch.daemon.remote import RemoteHand
    from activetouch.daemon.supervision import DeviceLink, LinkSettings, hand_probe
    from tests.doubles import RecordingHand

    class Unplugged(RecordingHand):
        plugged = False

        def connect(self) -> None:
            if not self.plugged:
                raise OSError(2, "No such file or directory: '/dev/ttyUSB0'")

    hand = Unplugged()
    lock = threading.Lock()
    link = DeviceLink(
        "hand", "reflex-sf", hand, hand_probe, lock, LinkSettings(retry_s=0.05, check_s=0.05)
    )
    ep = loopback_endpoint()
    with ZenohSession(ZenohSettings(listen=(ep,))) as zs:
        node = HandNode(hand, zs.session, "plug", lock=lock, link=link, state_hz=0.0)
        link.start()
        remote = RemoteHand(zs.session, "plug", timeout=10.0, motion_timeout=10.0)
        try:
            deadline = time.monotonic() + WAIT_S
            while link.health().attempts < 2 and time.monotonic() < deadline:
                time.sleep(0.02)
            h = link.health()
            assert h.state == "waiting" and "ttyUSB0" in h.detail and h.attempts >= 2
            with pytest.raises(NodeUnavailableError, match=r"not connected yet.*ttyUSB0"):
                remote.open()
            assert ("open",) not in hand.calls
            hand.plugged = True
            remote.wait_alive(WAIT_S)  # the token appears once the device is connected
            remote.open()
            assert link.health().state == "connected"
        finally:
            remote.close()
            link.close()
            node.close()
