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
    kw.setdefault("connect_timeout_s", 30.0)
    # states fresh for 5 s (default 0.5): a loaded machine may delay them; the tests of that
    # timeout pass it themselves
    kw.setdefault("state_timeout_s", 5.0)
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


def line(q0: np.ndarray, joint: int, delta: float, duration: float) -> JointTrajectory:
    """Constant speed from q0 by `delta` on one joint: slow, long ones give a test seconds to
    act on a motion's progress while no machine could finish it first."""
    q1 = q0.copy()
    q1[joint] += delta
    return JointTrajectory(LEFT, np.array([0.0, duration]), np.stack([q0, q1]))


def when(cond, action) -> threading.Thread:
    """Run `action` in another thread once `cond()` holds (progress, never a time; 30 s bound)."""

    def run() -> None:
        if wait_for(cond, timeout=30.0):
            action()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def ticks_later(robot: BaxterEmulator, n: int) -> None:
    """Return once the emulator ran `n` more control ticks (its own time, not the wall's)."""
    seq = robot._seq
    assert wait_for(lambda: robot._seq >= seq + n, timeout=30.0)


class EstopPast:
    """A body on the emulated joints that presses the red button in the control tick taking
    left_s0 past `at`: mid-trajectory at the same angle on any machine."""

    def __init__(self, robot: BaxterEmulator, at: float) -> None:
        self.robot, self.at = robot, at
        self.pressed_at: np.ndarray | None = None

    def follow(self, side: str, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
        if side == "left" and self.pressed_at is None and q_to[0] >= self.at:
            self.pressed_at = q_to.copy()
            self.robot._estop(button=1, source=1)  # press_estop(); the tick holds its lock
        return q_to


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
    # Nothing was sent: a stop's hold, on the same publisher, is the first command to arrive
    # (anything sent before it would arrive first, however slow the machine).
    arm.stop()
    assert wait_for(lambda: len(robot.commands("left")) > n, timeout=30.0)
    cmds = robot.commands("left")[n:]
    assert len(cmds) == 1
    np.testing.assert_allclose(cmds[0][3], q0, atol=0.01)  # the hold where the arm stands
    arm.clear_stop()


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
    robot.body = button = EstopPast(robot, q0[0] + 0.1)
    with pytest.raises(StoppedError, match="e-stopped"):
        arm.execute(ramp(q0, {0: 1.0}, 1.5))
    q_stop = robot.positions("left")
    assert button.pressed_at is not None
    np.testing.assert_array_equal(q_stop, button.pressed_at)  # stopped in the tick pressed
    ticks_later(robot, 30)
    np.testing.assert_array_equal(robot.positions("left"), q_stop)  # it does not move on
    assert 0.1 <= q_stop[0] - q0[0] < 0.9
    # enable refuses while the button is pressed; after release, enable resets first
    with pytest.raises(StoppedError, match="button"):
        arm.enable()
    robot.release_estop()
    wait_for(lambda: arm.robot_state().estop_button != 1, timeout=30.0)  # the driver saw it
    arm.enable()
    assert arm.robot_state().enabled


def test_stop_from_another_thread_holds_and_latches(robot: BaxterEmulator, arm: BaxterArm) -> None:
    q0 = arm.joint_state().position
    n = len(robot.commands("left"))
    # stopped once the arm is on its way (+0.03 rad of 1.5 over 30 s: no machine ends it first)
    stopper = when(lambda: robot.positions("left")[0] > q0[0] + 0.03, arm.stop)
    with pytest.raises(StoppedError):
        arm.execute(line(q0, 0, 1.5, 30.0))
    stopper.join(30.0)
    assert not stopper.is_alive()

    def hold_arrived() -> bool:
        # the hold is the measured position, behind every stream command (the arm lags them)
        s0 = [c[3][0] for c in robot.commands("left")[n:]]
        return len(s0) >= 2 and s0[-1] < max(s0[:-1])

    # let the hold arrive (through Zenoh: later on a loaded machine): the robot holds
    assert wait_for(hold_arrived, timeout=30.0)
    assert wait_for(lambda: robot.holding("left"), timeout=30.0)
    count, last = len(robot.commands("left")), robot.commands("left")[-1][3]
    ticks_later(robot, 20)
    # nothing is sent after the hold
    assert len(robot.commands("left")) == count and robot.commands("left")[-1][3] == last
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


def test_lost_joint_states_are_an_error_not_a_hang(robot: BaxterEmulator, endpoint: str) -> None:
    arm = make_arm(endpoint, state_timeout_s=0.5)  # the timeout under test
    arm.connect()
    try:
        q0 = arm.joint_state().position
        n = len(robot.commands("left"))
        at_drop: list[float] = []

        def drop() -> None:
            at_drop.append(max(c[3][0] for c in robot.commands("left")[n:]))
            robot.faults.drop_states = True

        # the states stop once the stream is under way (10 commands in)
        dropper = when(lambda: len(robot.commands("left")) >= n + 10, drop)
        with pytest.raises(NodeUnavailableError, match="lost"):
            arm.execute(line(q0, 0, 0.6, 60.0))  # 0.01 rad/s for a minute
        dropper.join(30.0)
        assert at_drop
        # Not a hang: the driver gave up within its state timeout (0.5 s, 0.005 rad of this
        # ramp) of the states stopping; the bound is a hang bound (30 s of the ramp, 0.3 rad),
        # playing the ramp out would command 0.6 rad
        reached = max(c[3][0] for c in robot.commands("left")[n:])
        assert reached - at_drop[0] < 0.3
        with pytest.raises(NodeUnavailableError):
            arm.joint_state()
    finally:
        arm.disconnect()


def test_delayed_joint_states_abort_as_lost(robot: BaxterEmulator, endpoint: str) -> None:
    arm = make_arm(endpoint, state_timeout_s=0.5)  # the timeout under test
    arm.connect()

    def fresh() -> bool:
        try:
            arm.joint_state()
        except NodeUnavailableError:
            return False
        return True

    try:
        assert fresh()
        robot.faults.state_delay_s = 0.8  # states keep coming, but 0.8 s old (header stamps)
        # 100 control ticks take at least 1 s: the states published now are the delayed ones
        ticks_later(robot, 100)
        assert wait_for(lambda: not fresh(), timeout=30.0)
        n = robot._seq
        with pytest.raises(NodeUnavailableError, match="lost"):
            arm.joint_state()
        robot.faults.state_delay_s = 0.0
        assert wait_for(fresh, timeout=30.0)  # back once timely again
        assert robot._seq > n and arm.joint_state().names == LEFT
    finally:
        arm.disconnect()


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
    start = robot.positions("left")
    goal = start.copy()
    goal[0] += 1.5
    last = goal.copy()
    last[0] -= 1e-6  # the stream's last command, told apart by its value
    with ZenohSession(ZenohSettings.client(endpoint)) as zs:
        pub = zs.session.declare_publisher(key)
        raw = hb.joint_command(1, list(goal), list(LEFT))
        # stream (at about 100 Hz) until the arm is on its way: +0.1 rad of 1.5
        for _ in range(3000):  # a 30 s hang bound
            if robot.positions("left")[0] > start[0] + 0.1:
                break
            pub.put(raw)
            time.sleep(0.01)  # pacing only: nothing below depends on it
        pub.put(hb.joint_command(1, list(last), list(LEFT)))
        pub.undeclare()
    assert robot.positions("left")[0] > start[0] + 0.1
    # the last command arrived (and all before it: one publisher, in order); then the robot
    # holds after its command timeout
    assert wait_for(lambda: robot.commands("left")[-1][3][0] == last[0], timeout=30.0)
    assert wait_for(lambda: robot.holding("left"), timeout=30.0)
    ticks_later(robot, 2)  # a control tick that began before the timeout has ended
    q_held = robot.positions("left")
    ticks_later(robot, 40)
    np.testing.assert_array_equal(robot.positions("left"), q_held)
    assert q_held[0] < goal[0] - 0.5  # it holds part-way: it was still on its way
