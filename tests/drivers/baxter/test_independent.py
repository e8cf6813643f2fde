"""Independent check: the driver served by the arm node, driven and watched by a plain Zenoh
client that builds and parses ROS 1 bytes by hand (no emulator, no driver codec)."""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from activetouch.daemon.nodes import ArmNode
from activetouch.daemon.remote import RemoteArm
from activetouch.drivers.baxter import ros1
from activetouch.drivers.baxter.arm import BaxterArm, BaxterArmConfig
from activetouch.interfaces import JointTrajectory
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.drivers.baxter import handbuilt as hb
from tests.loopback import loopback_endpoint
from tests.waiting import wait_for

ROBOT = "baxter-test"
SIDE_NAMES = [f"right_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")]
JS_KEY = hb.bridge_key(
    "sensor_msgs/JointState", "3066dcd76a6cfaef579bd0f34173e9fd", "/robot/joint_states"
)
STATE_KEY = hb.bridge_key(
    "baxter_core_msgs/AssemblyState", "356d9dd237ce73b2667da9235f541933", "/robot/state"
)
CMD_KEY = hb.bridge_key(
    "baxter_core_msgs/JointCommand",
    "19bfec8434dd568ab3c633d187c36f2e",
    "/robot/limb/right/joint_command",
)
Q0 = [0.1, -0.5, 0.2, 1.0, -0.3, 0.9, 0.05]


class EchoRobot:
    """Publishes hand-built joint states (both arms + head, right arm = its last command) and
    an enabled AssemblyState at 100 Hz; records every JointCommand it receives."""

    def __init__(self, session) -> None:
        self.q = list(Q0)
        self.received: list[tuple[float, int, np.ndarray, list[str]]] = []
        self._stop = threading.Event()
        self._js = session.declare_publisher(JS_KEY)
        self._st = session.declare_publisher(STATE_KEY)
        self._sub = session.declare_subscriber(CMD_KEY, self._on_cmd)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _on_cmd(self, sample) -> None:
        mode, cmd, names = hb.parse_joint_command(bytes(sample.payload.to_bytes()))
        self.received.append((time.monotonic(), mode, cmd, names))
        if names == SIDE_NAMES:
            self.q = list(cmd)

    def _run(self) -> None:
        left = [f"left_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")]
        while not self._stop.wait(0.01):
            names = ["head_pan", *left, *SIDE_NAMES]
            pos = [0.0] + [0.0] * 7 + self.q
            self._js.put(hb.joint_state(names, pos, [0.0] * len(names), stamp_ns=time.time_ns()))
            self._st.put(hb.assembly_state())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for e in (self._sub, self._js, self._st):
            e.undeclare()


class LockstepClock:
    """The driver's stream clock (`BaxterArm(clock=)`): stream time moves only when the stream
    waits for its next command, and only once the robot has the command just sent and the
    driver has heard it echoed back. The stream is judged in its own time, on any machine."""

    def __init__(self, robot: EchoRobot) -> None:
        self.robot = robot
        self.arm: BaxterArm | None = None
        self.now = 0.0
        self.waits = 0  # the stream waits once after each command it sends

    def monotonic(self) -> float:
        return self.now

    def _echoed(self) -> bool:
        got = [r[2] for r in self.robot.received if r[3] == SIDE_NAMES]
        assert self.arm is not None
        return len(got) >= self.waits and np.array_equal(self.arm.joint_state().position, got[-1])

    def wait(self, event: threading.Event, timeout: float) -> bool:
        self.waits += 1
        # a hang bound, not a window: a loaded machine only makes the stream's seconds longer
        assert wait_for(lambda: event.is_set() or self._echoed(), 30.0), "no echo in 30 s"
        if event.is_set():
            return True
        self.now += max(timeout, 0.0)
        return False


@pytest.fixture
def setup() -> Iterator[tuple[EchoRobot, RemoteArm]]:
    bridge_ep = loopback_endpoint()
    node_ep = loopback_endpoint()
    with (
        ZenohSession(ZenohSettings(listen=(bridge_ep,))) as bridge_side,
        ZenohSession(ZenohSettings(listen=(node_ep,))) as node_side,
        ZenohSession(ZenohSettings.client(node_ep)) as client_side,
    ):
        robot = EchoRobot(bridge_side.session)
        clock = LockstepClock(robot)
        arm = BaxterArm(
            # states stay fresh for 5 s: a loaded machine may delay them, nothing here tests that
            BaxterArmConfig(
                side="right", connect=[bridge_ep], command_hz=50.0, state_timeout_s=5.0
            ),
            clock=clock,
        )
        clock.arm = arm
        arm.connect()
        node = ArmNode(arm, node_side.session, ROBOT, state_hz=20.0)
        remote = RemoteArm(client_side.session, ROBOT, timeout=30.0)
        remote.connect()
        try:
            yield robot, remote
        finally:
            remote.close()
            node.close()
            arm.disconnect()
            robot.close()


def test_hand_built_joint_states_reach_arm_joint_state(setup) -> None:
    robot, remote = setup
    js = remote.joint_state()
    assert tuple(js.names) == ros1.joint_names("right")
    np.testing.assert_array_equal(js.position, Q0)
    robot.q = [x + 0.25 for x in Q0]
    wait_for(lambda: np.array_equal(remote.joint_state().position, robot.q), timeout=30.0)
    np.testing.assert_array_equal(remote.joint_state().position, robot.q)


def test_execute_streams_position_commands_at_the_rate(setup) -> None:
    robot, remote = setup
    q1 = list(Q0)
    q1[3] += 0.3  # e1 +0.3 rad, linear over 1 s
    traj = JointTrajectory(ros1.joint_names("right"), np.array([0.0, 1.0]), np.array([Q0, q1]))
    remote.execute(traj)
    # execute returns once the robot's state settled near the goal, which the goal command
    # was sent before: wait for it to arrive
    goal = struct.pack("<d", q1[3])
    wait_for(lambda: struct.pack("<d", robot.received[-1][2][3]) == goal, timeout=30.0)
    got = [r for r in robot.received if r[3] == SIDE_NAMES]
    assert got and all(r[1] == 1 for r in got)  # POSITION_MODE, the seven joints in order
    cmds = np.array([r[2] for r in got])
    others = [0, 1, 2, 4, 5, 6]
    np.testing.assert_array_equal(cmds[:, others], np.tile(np.array(Q0)[others], (len(cmds), 1)))
    # e1 follows the trajectory at the configured 50 Hz, in the stream's own time (the lockstep
    # clock): command k is the trajectory sampled at k / 50 s, all the way along the ramp
    implied = (cmds[:, 3] - Q0[3]) / 0.3
    on_ramp = implied < 0.999
    assert np.all(np.diff(implied) >= -1e-12)
    assert on_ramp.sum() == 50 and np.all(on_ramp[:50])  # 0 .. 0.98 s
    np.testing.assert_allclose(implied[on_ramp], np.arange(50) / 50.0, rtol=0, atol=1e-9)
    assert len(cmds) <= 52  # then the goal, until the echoed state settles there
    assert cmds[-1, 3] == pytest.approx(q1[3])
    assert struct.pack("<d", cmds[-1, 3]) == goal  # goal sent exactly
