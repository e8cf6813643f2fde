"""The recognition service on the in-memory fake devices, in this process: the e-stop reaches
a grasp that is running, and the devices stay stopped until the next recognition."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading

import pytest

from activetouch.daemon.client import RecognitionAbortedError, open_client
from activetouch.transport.messages import RecognizeRequest
from tests.waiting import wait_for

ROBOT = "fakebot"
HANG_S = 60.0  # bounds waits that only a defect runs out (never a measure of speed)


@pytest.fixture
def fake_daemon(start_fake_daemon):
    # A grasp that only a stop ends (an hour long); never confident early.
    return start_fake_daemon(["hand.close_s=3600", "session.stable_grasps=1000"])


def test_estop_reaches_the_hand_during_a_grasp(fake_daemon) -> None:
    daemon, ep = fake_daemon
    hand = daemon.devices.hand
    with open_client([ep], ROBOT, timeout=10.0) as client:
        out: dict = {}

        def run() -> None:
            req = RecognizeRequest(policy="tree", max_moves=3, seed=1, object="cup")
            try:
                out["result"] = client.recognize(req, timeout=4 * HANG_S)
            except Exception as e:
                out["error"] = e

        t = threading.Thread(target=run)
        t.start()
        assert hand.closing.wait(2 * HANG_S), "the first grasp never started"
        res = client.estop("test")
        # Only the stop can end the hour-long grasp: the recognition ends because of it.
        t.join(HANG_S)
        assert not t.is_alive(), "the e-stop did not end the running grasp"
    assert res.arm_stopped and res.hand_opened
    assert isinstance(out.get("error"), RecognitionAbortedError), out
    assert hand.closes == 0  # the grasp never completed
    assert hand.stop_latch.is_set and daemon.devices.arm.stop_latch.is_set  # in force


def test_the_next_recognition_clears_the_stop(fake_daemon) -> None:
    daemon, ep = fake_daemon
    daemon.devices.hand.cfg.close_s = 0.0
    with open_client([ep], ROBOT, timeout=10.0) as client:
        client.estop("before")
        assert daemon.devices.hand.stop_latch.is_set
        res = client.recognize(
            RecognizeRequest(policy="random", max_moves=2, seed=0, object="cup"), timeout=60.0
        )
    assert res.moves == 2
    assert not daemon.devices.hand.stop_latch.is_set


CLIENT = """
import sys
from activetouch.daemon.client import open_client
from activetouch.transport.messages import RecognizeRequest
from tests.waiting import wait_for
with open_client([{ep!r}], {robot!r}, timeout=10.0) as c:
    c.recognize(
        RecognizeRequest(policy="random", max_moves=50, seed=0, object="cup"),
        on_progress=lambda ev: print("progress", flush=True),
        timeout=120.0,
        detached={detached},
    )
print("done", flush=True)
"""


def _client(ep: str, detached: bool) -> subprocess.Popen:
    script = CLIENT.format(ep=ep, robot=ROBOT, detached=detached)
    return subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
    )


class _Ended:
    """Told by the service how its recognition ended (an observer, on the runner thread)."""

    def __init__(self) -> None:
        self.done = threading.Event()
        self.result = self.error = None

    def on_result(self, _session_id, result, error) -> None:
        self.result, self.error = result, error
        self.done.set()


@pytest.mark.parametrize("detached", [False, True])
def test_a_killed_client_cancels_its_recognition(fake_daemon, caplog, detached: bool) -> None:
    caplog.set_level(logging.INFO, logger="activetouch.daemon")
    daemon, ep = fake_daemon
    hand = daemon.devices.hand
    hand.cfg.close_s = 0.3  # 50 grasps: 15 s at least
    ended = _Ended()
    daemon.service.observers.append(ended)
    proc = _client(ep, detached)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "progress"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(HANG_S)
        if detached:
            # It asked to run on: it grasps on after its client is gone, until cancelled.
            closes = hand.closes
            assert wait_for(lambda: hand.closes >= closes + 2 or ended.done.is_set(), HANG_S)
            assert not ended.done.is_set(), (ended.result, ended.error)
            assert "recognition runs detached" in caplog.text  # nothing watches its requester
            with open_client([ep], ROBOT, timeout=10.0) as client:
                assert client.status().session is not None
                assert client.cancel().cancelled
            assert ended.done.wait(HANG_S)
            assert ended.error is None and ended.result.stop_reason == "cancelled", ended.error
        else:
            assert ended.done.wait(HANG_S), "the recognition ran on without its requester"
            assert isinstance(ended.error, RecognitionAbortedError), (ended.result, ended.error)
            assert "its requester is gone" in str(ended.error)
            with open_client([ep], ROBOT, timeout=10.0) as client:
                assert client.status().session is None
        assert hand.closes < 50
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(HANG_S)


def test_arm_cli_enables_through_the_arm_node(start_fake_daemon, capsys) -> None:
    from activetouch.cli.main import main as cli_main

    _daemon, ep = start_fake_daemon()
    assert cli_main(["arm", "enable", "--connect", ep, "--robot", ROBOT]) == 0
    assert "enabled" in capsys.readouterr().out


def test_robot_seconds_cross_the_wire(start_fake_daemon) -> None:
    """Through Zenoh the daemon's session reads the arm node's counters (arm/motion_stats via
    RemoteArm): the result's motion_s is what the node's wrist counted, progress grows to it."""
    daemon, ep = start_fake_daemon(["session.stable_grasps=1000"])
    wrist = daemon.devices.wrist
    before = wrist.robot_seconds
    events: list = []
    with open_client([ep], ROBOT, timeout=10.0) as client:
        res = client.recognize(
            RecognizeRequest(policy="random", max_moves=3, seed=2, object="cup"),
            on_progress=events.append,
            timeout=60.0,
        )
    moved = wrist.robot_seconds - before
    assert res.moves == 3 and moved > 0
    assert abs(res.motion_s - moved) < 1e-9
    assert res.motion_planning_s == 0.0 and res.grasp_s > 0
    steps = [e.motion_s for e in events]
    assert len(steps) == 3 and steps == sorted(steps) and steps[0] > 0
    assert abs(steps[-1] - res.motion_s) < 1e-9
