"""A driver process killed mid-trajectory: the emulated Baxter holds within its timeout."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from activetouch.emulators.baxter_bridge import BaxterEmulator, EmulatorSettings
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint

DRIVER = textwrap.dedent(
    """
    import sys, numpy as np
    from activetouch.drivers.baxter.arm import BaxterArm, BaxterArmConfig
    from activetouch.interfaces import JointTrajectory
    arm = BaxterArm(BaxterArmConfig(connect=[sys.argv[1]]))
    arm.connect()
    q0 = arm.joint_state().position
    q1 = q0.copy(); q1[0] += 1.4
    print("moving", flush=True)
    arm.execute(JointTrajectory(arm.joint_names, np.array([0.0, 1.5]), np.stack([q0, q1])))
    """
)


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
            time.sleep(0.6)
            proc.kill()  # SIGKILL: no goodbye, no hold command
            proc.wait(5)
            t_kill = time.monotonic()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)
        time.sleep(max(0.0, 0.2 + 0.05 - (time.monotonic() - t_kill)))
        q_held = robot.positions("left")
        time.sleep(0.5)
        np.testing.assert_array_equal(robot.positions("left"), q_held)
        assert 0.2 < q_held[0] - q0 < 1.2  # stopped part-way, not at the goal
