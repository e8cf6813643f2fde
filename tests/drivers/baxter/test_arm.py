"""The Baxter driver against the byte-level emulator over loopback Zenoh."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from activetouch.device_types import device_config
from activetouch.drivers.baxter import ros1
from activetouch.drivers.baxter.arm import BaxterArm, BaxterArmConfig, TrackingError
from activetouch.emulators.baxter_bridge import BaxterEmulator, EmulatorSettings
from activetouch.errors import (
    ConfigError,
    NodeUnavailableError,
    StoppedError,
    UnreachableError,
)
from activetouch.interfaces import JointTrajectory
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.drivers.baxter import handbuilt as hb
from tests.loopback import loopback_endpoint
from tests.waiting import wait_for

LEFT = ros1.joint_names("left")


@pytest.fixture
def endpoint() -> str:
    return loopback_endpoint()


@pytest.fixture
def robot(endpoint: str) -> Iterator[BaxterEmulator]:
    with (
        ZenohSession(ZenohSettings(listen=(endpoint,))) as zs,
        BaxterEmulator(zs.session, EmulatorSettings(enabled=True)) as emu,
    ):
        yield emu


def make_arm(endpoint: str, **kw) -> BaxterArm:
    kw.setdefault("connect_timeout_s", 3.0)
    return BaxterArm(BaxterArmConfig(connect=[endpoint], **kw))


@pytest.fixture
def arm(robot: BaxterEmulator, endpoint: str) -> Iterator[BaxterArm]:
    a = make_arm(endpoint)
    a.connect()
    yield a
    a.disconnect()


def ramp(q0: np.ndarray, delta: dict[int, float], duration: float, n: int = 21) -> JointTrajectory:
    """Smooth (cosine) rest-to-rest move from q0 by `delta` per joint index."""
    q1 = q0.copy()
    for j, d in delta.items():
        q1[j] += d
    t = np.linspace(0.0, duration, n)
    s = (1 - np.cos(np.pi * t / duration)) / 2
    return JointTrajectory(LEFT, t, q0 + (q1 - q0) * s[:, None])


def test_config_through_the_registry() -> None:
    cfg = device_config(
        "arm",
        {"type": "baxter", "side": "right", "bridge_namespace": "lab", "bridge_format": "legacy"},
    )
    assert isinstance(cfg, BaxterArmConfig) and cfg.command_hz == 100.0
    assert (cfg.side, cfg.bridge_namespace, cfg.bridge_format) == ("right", "lab", "legacy")
    for bad in ({"side": "up"}, {"bridge_format": "v3"}, {"bridge_namespace": "a/b"},
                {"command_hz": 2.0}, {"speed_ratio": 0.0}, {"connect": []}):  # fmt: skip
        with pytest.raises(ConfigError):
            device_config("arm", {"type": "baxter", **bad})


def test_executes_a_trajectory_and_settles(robot: BaxterEmulator, arm: BaxterArm) -> None:
    js = arm.joint_state()
    assert js.names == LEFT
    np.testing.assert_allclose(js.position, robot.positions("left"), atol=0.02)
    traj = ramp(js.position, {0: 0.4, 3: -0.3, 6: 0.8}, 1.0)
    n = len(robot.commands("left"))
    arm.execute(traj)
    # Streamed in real time (the robot's own receive stamps span the trajectory's second),
    # not sent ahead of time; a loaded machine only makes the span longer.
    stamps = [c[0] for c in robot.commands("left")[n:]]
    assert stamps[-1] - stamps[0] >= 0.9
    np.testing.assert_allclose(arm.joint_state().position, traj.positions[-1], atol=0.0088)
    # the driver set the robot's command timeout and speed ratio
    assert robot.command_timeout("left") == pytest.approx(0.2)
    assert robot.speed_ratio("left") == pytest.approx(1.0)


def test_refuses_before_anything_moves(robot: BaxterEmulator, arm: BaxterArm) -> None:
    q0 = arm.joint_state().position
    n = len(robot.commands("left"))
    for traj in (
        ramp(q0, {1: 3.0}, 1.0),  # s1 beyond its upper limit
        ramp(q0, {0: 1.0}, 0.2),  # far too fast for s0 (1.5 rad/s)
        JointTrajectory(LEFT[::-1], np.array([0.0, 1.0]), np.stack([q0, q0])),  # wrong order
        JointTrajectory(LEFT[:6], np.array([0.0]), q0[None, :6]),  # missing joint
        JointTrajectory(LEFT, np.array([0.0, 0.0]), np.stack([q0, q0])),  # time not increasing
        JointTrajectory(LEFT, np.array([0.0, 1.0]), np.stack([q0 + 0.3, q0 + 0.3])),  # far start
    ):
        with pytest.raises(UnreachableError):
            arm.execute(traj)
    time.sleep(0.05)
    assert len(robot.commands("left")) == n


def test_names_are_reordered(robot: BaxterEmulator, arm: BaxterArm) -> None:
    q0 = arm.joint_state().position
    traj = ramp(q0, {4: 0.5}, 0.5)
    perm = [6, 5, 4, 3, 2, 1, 0]
    arm.execute(JointTrajectory(tuple(LEFT[i] for i in perm), traj.times, traj.positions[:, perm]))
    assert robot.positions("left")[4] == pytest.approx(q0[4] + 0.5, abs=0.01)


def test_disabled_and_enable(robot: BaxterEmulator, arm: BaxterArm) -> None:
    robot.disable()
    # the state reached the driver
    wait_for(lambda: (st := arm.robot_state()) is not None and not st.enabled, timeout=30.0)
    q0 = arm.joint_state().position
    with pytest.raises(StoppedError, match="disabled"):
        arm.execute(ramp(q0, {0: 0.1}, 0.5))
    arm.enable()
    assert arm.robot_state().enabled
    arm.execute(ramp(q0, {0: 0.1}, 0.5))
    arm.disable()
    assert not arm.robot_state().enabled


def test_lagging_joint_aborts_with_its_name(robot: BaxterEmulator, arm: BaxterArm) -> None:
    robot.faults.lag_joint = "left_e1"
    q0 = arm.joint_state().position
    with pytest.raises(TrackingError, match="left_e1"):
        arm.execute(ramp(q0, {3: 1.0}, 1.5))
    # the driver commanded a hold at the measured position on the way out
    # the hold arrived (through Zenoh: later on a loaded machine) and the robot holds there
    wait_for(lambda: robot.holding("left"), timeout=30.0)
    _, mode, names, cmd = robot.commands("left")[-1]
    assert mode == 1 and names == LEFT
    np.testing.assert_allclose(cmd, robot.positions("left"), atol=0.05)
    assert cmd[3] < q0[3] + 0.9  # aborted part-way, not at the end of the ramp


def test_estop_mid_trajectory_stops(robot: BaxterEmulator, arm: BaxterArm) -> None:
    q0 = arm.joint_state().position
    threading.Timer(0.3, robot.press_estop).start()
    with pytest.raises(StoppedError, match="e-stopped"):
        arm.execute(ramp(q0, {0: 1.0}, 1.5))
    q_stop = robot.positions("left")
    time.sleep(0.3)
    np.testing.assert_array_equal(robot.positions("left"), q_stop)  # it does not move on
    assert 0.05 < q_stop[0] - q0[0] < 0.9
    # enable refuses while the button is pressed; after release, enable resets first
    with pytest.raises(StoppedError, match="button"):
        arm.enable()
    robot.release_estop()
    wait_for(lambda: arm.robot_state().estop_button != 1, timeout=30.0)  # the driver saw it
    arm.enable()
    assert arm.robot_state().enabled


def test_stop_from_another_thread_holds_and_latches(robot: BaxterEmulator, arm: BaxterArm) -> None:
    q0 = arm.joint_state().position
    threading.Timer(0.3, arm.stop).start()
    with pytest.raises(StoppedError):
        arm.execute(ramp(q0, {0: 1.0}, 1.5))
    # let the hold arrive (through Zenoh: later on a loaded machine): the robot holds
    wait_for(lambda: robot.holding("left"), timeout=30.0)
    last = robot.commands("left")[-1][3]
    time.sleep(0.1)
    assert robot.commands("left")[-1][3] == last  # nothing is sent after the hold
    # the last command is the hold, near where the arm is (not further along the ramp)
    assert abs(last[0] - robot.positions("left")[0]) < 0.05
    with pytest.raises(StoppedError):
        arm.execute(ramp(arm.joint_state().position, {0: 0.1}, 0.5))
    arm.clear_stop()
    arm.execute(ramp(arm.joint_state().position, {0: -0.1}, 0.5))


def test_super_stop_on_stop_asserts_the_robots_estop(robot: BaxterEmulator, endpoint: str) -> None:
    a = make_arm(endpoint, super_stop_on_stop=True)
    a.connect()
    try:
        a.stop()
        wait_for(lambda: a.robot_state() and a.robot_state().stopped, timeout=30.0)
        assert a.robot_state().stopped and a.robot_state().estop_button == 2
        a.clear_stop()
        a.enable()  # reset then enable
        assert a.robot_state().enabled
        a.estop()
        assert a.robot_state().stopped
    finally:
        a.disconnect()


def test_lost_joint_states_are_an_error_not_a_hang(robot: BaxterEmulator, arm: BaxterArm) -> None:
    q0 = arm.joint_state().position
    dropped: list[float] = []

    def drop() -> None:
        dropped.append(time.monotonic())
        robot.faults.drop_states = True

    threading.Timer(0.2, drop).start()
    with pytest.raises(NodeUnavailableError, match="lost"):
        arm.execute(ramp(q0, {0: 0.5}, 2.0))
    # Not a hang: after the states stopped the driver sent at most the commands of its state
    # timeout (0.5 s, ~50 at 100 Hz); playing the ramp out would be ~180 more.
    after = [c for c in robot.commands("left") if c[0] > dropped[0]]
    assert len(after) <= 100
    with pytest.raises(NodeUnavailableError):
        arm.joint_state()


def test_delayed_joint_states_abort_as_lost(robot: BaxterEmulator, arm: BaxterArm) -> None:
    robot.faults.state_delay_s = 0.8  # states keep coming, but 0.8 s old (header stamps)
    time.sleep(1.2)
    n = robot._seq
    with pytest.raises(NodeUnavailableError, match="lost"):
        arm.joint_state()
    robot.faults.state_delay_s = 0.0
    time.sleep(0.1)
    assert robot._seq > n and arm.joint_state().names == LEFT  # back once timely again


def test_connect_without_a_robot_times_out(endpoint: str) -> None:
    with ZenohSession(ZenohSettings(listen=(endpoint,))):
        a = make_arm(endpoint, connect_timeout_s=0.5)
        with pytest.raises(NodeUnavailableError, match="no joint state"):
            a.connect()  # returns with the error (a hang would meet pytest's timeout)


@pytest.mark.parametrize(
    ("ns", "legacy", "fmt"), [("lab", False, "namespaced"), ("*", True, "legacy")]
)
def test_namespace_and_legacy_keys(endpoint: str, ns: str, legacy: bool, fmt: str) -> None:
    with (
        ZenohSession(ZenohSettings(listen=(endpoint,))) as zs,
        BaxterEmulator(zs.session, EmulatorSettings(enabled=True, namespace=ns, legacy=legacy)),
    ):
        a = make_arm(endpoint, bridge_namespace=ns, bridge_format=fmt)
        a.connect()
        try:
            q0 = a.joint_state().position
            a.execute(ramp(q0, {5: 0.2}, 0.4))
        finally:
            a.disconnect()


@pytest.mark.parametrize(
    ("ns", "legacy", "fmt"),
    [("lab", False, "namespaced"), ("*", False, "namespaced"), ("*", True, "legacy")],
)
def test_default_settings_take_the_key_format_from_the_bridge(
    endpoint: str, ns: str, legacy: bool, fmt: str
) -> None:
    # Issue 23 finding 4: with the old default ("namespaced") a tagged-release bridge (legacy
    # keys) gave no joint state at all. `auto` hears both forms and answers in the one it heard.
    with (
        ZenohSession(ZenohSettings(listen=(endpoint,))) as zs,
        BaxterEmulator(
            zs.session, EmulatorSettings(enabled=True, namespace=ns, legacy=legacy)
        ) as robot,
    ):
        a = make_arm(endpoint)  # no bridge_format: the default
        assert a.cfg.bridge_format == "auto"
        a.connect()
        try:
            assert (a.bridge_format, a.bridge_namespace) == (fmt, "" if legacy else ns)
            q0 = a.joint_state().position
            a.execute(ramp(q0, {5: 0.2}, 0.4))
            assert robot.positions("left")[5] == pytest.approx(q0[5] + 0.2, abs=0.02)
        finally:
            a.disconnect()


def test_commands_the_bridge_does_not_forward_are_named_as_such(endpoint: str) -> None:
    # Issue 23 finding 5 (zenoh-plugin-ros1 #92): joint states flow, joint_command vanishes.
    # Before, this was only "a tracking error"; now the error says what is likely happening.
    with (
        ZenohSession(ZenohSettings(listen=(endpoint,))) as zs,
        BaxterEmulator(zs.session, EmulatorSettings(enabled=True, drop_commands=True)),
    ):
        a = make_arm(endpoint)
        a.connect()
        try:
            q0 = a.joint_state().position
            with pytest.raises(TrackingError, match=r"issue #92"):
                a.execute(ramp(q0, {1: 0.5}, 1.0))
        finally:
            a.disconnect()


def test_default_namespace_reaches_a_named_bridge(endpoint: str) -> None:
    # the bridge's default "*" is literal in its keys; a driver on "*" still meets a bridge
    # publishing under a named namespace, and vice versa (Zenoh key intersection)
    with (
        ZenohSession(ZenohSettings(listen=(endpoint,))) as zs,
        BaxterEmulator(zs.session, EmulatorSettings(enabled=True, namespace="lab")) as robot,
    ):
        a = make_arm(endpoint)
        a.connect()
        try:
            a.execute(ramp(a.joint_state().position, {0: 0.1}, 0.3))
            assert robot.commands("left")
        finally:
            a.disconnect()


def test_command_stream_loss_leaves_the_emulated_arm_holding(
    robot: BaxterEmulator, endpoint: str
) -> None:
    """A plain client streams hand-built JointCommands toward a far goal, then goes silent:
    the emulated arm holds within its command timeout."""
    key = hb.bridge_key(
        "baxter_core_msgs/JointCommand",
        "19bfec8434dd568ab3c633d187c36f2e",
        "/robot/limb/left/joint_command",
    )
    goal = robot.positions("left")
    goal[0] += 1.5
    with ZenohSession(ZenohSettings.client(endpoint)) as zs:
        pub = zs.session.declare_publisher(key)
        time.sleep(0.2)
        raw = hb.joint_command(1, list(goal), list(LEFT))
        for _ in range(30):  # 0.3 s at 100 Hz
            pub.put(raw)
            time.sleep(0.01)
        t_last = time.monotonic()
        pub.undeclare()
    q_moving = robot.positions("left")[0]
    time.sleep(0.2 + 0.05 - (time.monotonic() - t_last))  # timeout 0.2 s + one tick
    q_held = robot.positions("left")
    time.sleep(0.4)
    assert q_moving < goal[0] - 0.5  # it was still on its way when the stream stopped
    np.testing.assert_array_equal(robot.positions("left"), q_held)
