"""The recognition service on the in-memory fake devices, in this process: the e-stop reaches
a grasp that is running, and the devices stay stopped until the next recognition."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from activetouch.daemon.client import RecognitionAbortedError, open_client
from activetouch.transport.messages import RecognizeRequest

ROBOT = "fakebot"


@pytest.fixture
def fake_daemon(start_fake_daemon):
    # A slow grasp (the e-stop must not wait for its end); never confident early.
    return start_fake_daemon(["hand.close_s=5", "session.stable_grasps=1000"])


def test_estop_reaches_the_hand_during_a_grasp(fake_daemon) -> None:
    daemon, ep = fake_daemon
    hand = daemon.devices.hand
    with open_client([ep], ROBOT, timeout=10.0) as client:
        out: dict = {}

        def run() -> None:
            req = RecognizeRequest(policy="tree", max_moves=3, seed=1, object="cup")
            try:
                out["result"] = client.recognize(req, timeout=60.0)
            except Exception as e:
                out["error"] = e
            out["t"] = time.monotonic()

        t = threading.Thread(target=run)
        t.start()
        deadline = time.monotonic() + 10.0
        while not hand.stop_latch.is_set and time.monotonic() < deadline:
            st = client.status()
            if st.session is not None and hand.closes == 0 and st.session.move == 0:
                time.sleep(0.3)  # inside the first (5 s) grasp
                break
            time.sleep(0.02)
        t_stop = time.monotonic()
        res = client.estop("test")
        t.join(10.0)
        assert not t.is_alive()
    assert res.arm_stopped and res.hand_opened
    assert isinstance(out.get("error"), RecognitionAbortedError), out
    assert out["t"] - t_stop < 1.0  # not the 4.7 s left of the grasp
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


@pytest.mark.parametrize("detached", [False, True])
def test_a_killed_client_cancels_its_recognition(fake_daemon, detached: bool) -> None:
    daemon, ep = fake_daemon
    hand = daemon.devices.hand
    hand.cfg.close_s = 0.3  # 50 grasps: 15 s, far longer than the test waits
    proc = _client(ep, detached)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "progress"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        t_kill = time.monotonic()
        with open_client([ep], ROBOT, timeout=10.0) as client:
            while client.status().session is not None and time.monotonic() - t_kill < 5.0:
                time.sleep(0.05)
            gone_after = time.monotonic() - t_kill
            running = client.status().session is not None
            if detached:
                assert running  # it asked to run on
                client.cancel()
            else:
                assert not running and gone_after < 2.0, gone_after
    finally:
        if proc.poll() is None:
            proc.kill()


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
