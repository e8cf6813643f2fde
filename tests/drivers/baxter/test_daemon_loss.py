"""A driver process killed mid-trajectory: the emulated Baxter holds within its timeout."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from activetouch.emulators.baxter_bridge import BaxterEmulator, EmulatorSettings
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint
from tests.waiting import wait_for

# s0 +1.4 rad, linear over 15 s: killed once past +0.3 rad (about 3 s in), so only a test
# thread starved for some 10 s could let the driver come near the goal before the kill.
DRIVER = textwrap.dedent(
    """
    import sys, numpy as np
    from activetouch.drivers.baxter.arm import BaxterArm, BaxterArmConfig
    from activetouch.interfaces import JointTrajectory
    # states fresh for 5 s, tracking grace 5 s: a loaded machine must not end the motion first
    arm = BaxterArm(BaxterArmConfig(connect=[sys.argv[1]], state_timeout_s=5.0,
                                    tracking_grace_s=5.0, connect_timeout_s=30.0))
    arm.connect()
    q0 = arm.joint_state().position
    q1 = q0.copy(); q1[0] += 1.4
    print("moving", flush=True)
    arm.execute(JointTrajectory(arm.joint_names, np.array([0.0, 15.0]), np.stack([q0, q1])))
    """
)


def ticks_later(robot: BaxterEmulator, n: int) -> None:
    """Return once the emulator ran `n` more control ticks (its own time, not the wall's)."""
    seq = robot._seq
    assert wait_for(lambda: robot._seq >= seq + n, timeout=30.0)


@pytest.mark.slow
def test_killed_driver_leaves_the_arm_holding() -> None:
    ep = loopback_endpoint()
    with (
        ZenohSession(ZenohSettings(listen=(ep,))) as zs,
        BaxterEmulator(zs.session, EmulatorSettings(enabled=True)) as robot,
    ):
        q0 = robot.positions("left")[0]
        proc = subprocess.Popen(
            [sys.executable, "-c", DRIVER, ep], stdout=subprocess.PIPE, text=True
        )
        try:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == "moving"
            # mid-trajectory: once the arm is well on its way (or the driver died)
            wait_for(lambda: robot.positions("left")[0] - q0 > 0.3 or proc.poll() is not None, 30.0)
            assert proc.poll() is None, f"the driver ended by itself (exit {proc.returncode})"
            assert robot.positions("left")[0] - q0 > 0.3
            proc.kill()  # SIGKILL: no goodbye, no hold command
            proc.wait(30)
            assert proc.returncode == -signal.SIGKILL
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(30)
        # Every command the driver got out has arrived once its connection is gone (the bytes
        # before the close are read first); then the robot holds after its command timeout.
        assert wait_for(lambda: not list(zs.session.info.peers_zid()), timeout=30.0)
        assert wait_for(lambda: robot.holding("left"), timeout=30.0)
        ticks_later(robot, 2)  # a control tick that began before the timeout has ended
        q_held = robot.positions("left")
        ticks_later(robot, 30)
        np.testing.assert_array_equal(robot.positions("left"), q_held)
        assert 0.3 < q_held[0] - q0 < 1.2  # stopped part-way, not at the goal
