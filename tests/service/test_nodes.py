"""Hand / Arm served over Zenoh on 127.0.0.1 (scouting off), used through RemoteHand / RemoteArm."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from activetouch.clock import ManualClock
from activetouch.daemon.liveliness import AliveNodes
from activetouch.daemon.nodes import ArmNode, HandNode
from activetouch.daemon.remote import Latest, RemoteArm, RemoteHand
from activetouch.errors import (
    DataError,
    MessageError,
    NodeUnavailableError,
    RemoteError,
    UnreachableError,
)
from activetouch.interfaces import (
    N_SENSORS,
    HandState,
    JointTrajectory,
    Pose,
)
from activetouch.transport.keys import Keys
from activetouch.transport.messages import (
    Empty,
    HandInfo,
    HandStateMsg,
    JointStateMsg,
    MotionStats,
    MoveWristRequest,
    PreshapeRequest,
    Reply,
    decode,
    encode,
    hand_state_to_msg,
    pose_to_msg,
)
from activetouch.transport.zenoh_session import (
    ZenohSession,
    ZenohSettings,
)
from tests.doubles import RecordingArm, RecordingHand
from tests.loopback import loopback_endpoint
from tests.waiting import wait_for

ROBOT = "testbot"


@pytest.fixture
def hand() -> RecordingHand:
    return RecordingHand()


@pytest.fixture
def arm() -> RecordingArm:
    return RecordingArm()


@pytest.fixture
def hand_node(hand: RecordingHand, node_session: ZenohSession) -> HandNode:
    return node_session.closing(HandNode(hand, node_session.session, ROBOT, state_hz=50.0))


@pytest.fixture
def arm_node(arm: RecordingArm, node_session: ZenohSession) -> ArmNode:
    return node_session.closing(ArmNode(arm, node_session.session, ROBOT, wrist=arm, state_hz=50.0))


@pytest.fixture
def remote_hand(hand_node: HandNode, client_session: ZenohSession) -> RemoteHand:
    rh = client_session.closing(RemoteHand(client_session.session, ROBOT, timeout=3.0))
    rh.connect()
    return rh


@pytest.fixture
def remote_arm(arm_node: ArmNode, client_session: ZenohSession) -> RemoteArm:
    ra = client_session.closing(RemoteArm(client_session.session, ROBOT, timeout=3.0))
    ra.connect()
    return ra


def test_remote_hand_round_trip(remote_hand: RemoteHand, hand: RecordingHand) -> None:
    remote_hand.preshape(0.8)
    remote_hand.open()
    grasp = remote_hand.guarded_close()
    expected = RecordingHand()
    expected.angle = 0.8
    want = expected.guarded_close()
    np.testing.assert_array_equal(grasp.sensor_ids, want.sensor_ids)
    np.testing.assert_allclose(grasp.xyz, want.xyz)
    np.testing.assert_allclose(grasp.pressures, want.pressures)
    np.testing.assert_allclose(grasp.finger_angles, want.finger_angles)
    assert grasp.preshape == 0.8
    state = remote_hand.state()
    assert state.contact.dtype == bool and state.contact.sum() == 4
    assert state.preshape == 0.8
    assert [c[0] for c in hand.calls] == ["preshape", "open", "guarded_close"]
    assert hand.calls[0] == ("preshape", 0.8)


def test_remote_arm_round_trip(remote_arm: RemoteArm, arm: RecordingArm) -> None:
    pose = Pose(np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.0, 0.0, 2.0]))
    remote_arm.move_wrist(pose)
    ((name, got),) = arm.calls
    assert name == "move_wrist"
    np.testing.assert_allclose(got.as_array(), pose.as_array())
    traj = JointTrajectory(
        names=RecordingArm.NAMES,
        times=np.array([0.0, 0.1, 0.2]),
        positions=np.tile(np.arange(6.0), (3, 1)) * np.array([[0.0], [0.5], [1.0]]),
        meta={"planner": "test", "n": np.int64(3)},
    )
    remote_arm.execute(traj)
    sent = arm.calls[-1][1]
    np.testing.assert_allclose(sent.positions, traj.positions)
    assert sent.meta == {"planner": "test", "n": 3}
    js = remote_arm.joint_state()
    assert js.names == RecordingArm.NAMES
    np.testing.assert_allclose(js.position, np.arange(6.0))


def test_unreachable_crosses_the_wire_as_itself(remote_arm: RemoteArm) -> None:
    with pytest.raises(UnreachableError, match=r"x=2\.00 m is out of reach"):
        remote_arm.move_wrist(Pose(np.array([2.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])))
    # The node goes on serving after the error.
    remote_arm.move_wrist(Pose(np.array([0.5, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])))


def test_device_errors_keep_their_type(remote_hand: RemoteHand, hand: RecordingHand) -> None:
    with pytest.raises(ValueError, match=r"outside 0\.\.1\.6"):
        remote_hand.preshape(2.5)
    hand.fail_with = DataError("tactile board sent a truncated packet")
    with pytest.raises(DataError, match="truncated packet"):
        remote_hand.guarded_close()
    hand.fail_with = RuntimeError("driver bug")
    with pytest.raises(RemoteError, match="RuntimeError: driver bug"):
        remote_hand.guarded_close()
    hand.fail_with = None
    assert remote_hand.guarded_close().n_contacts == 4


def test_state_is_published(hand_node: HandNode, arm_node: ArmNode, client_session) -> None:
    keys = Keys(ROBOT)
    hs = client_session.closing(Latest(client_session.session, keys.hand_state, HandStateMsg))
    js = client_session.closing(
        Latest(client_session.session, keys.arm_joint_states, JointStateMsg)
    )
    first = hs.wait(timeout=5.0)
    second = hs.wait(timeout=5.0)
    assert len(first.pressures) == N_SENSORS and second.stamp > first.stamp
    assert js.wait(timeout=5.0).names == list(RecordingArm.NAMES)
    assert hs.invalid == 0 and js.invalid == 0


def test_malformed_requests_get_error_replies(
    hand_node: HandNode, remote_hand: RemoteHand, client_session
) -> None:
    session = client_session.session
    key = Keys(ROBOT).hand_preshape

    def ask(payload: bytes | None) -> Reply:
        replies = list(session.get(key, payload=payload, timeout=3.0))
        assert len(replies) == 1
        return decode(replies[0].result.payload.to_bytes(), Reply[None])

    cases = {
        b"not json": "not valid JSON",
        b'{"v": 1, "angle": "wide"}': "field `angle`",
        b'{"v": 1}': "field `angle`",
        b'{"v": 1, "angle": 0.5, "speed": 3}': "field `speed`",
        b'{"v": 99, "angle": 0.5}': "schema version 99 is not supported",
        None: "needs a PreshapeRequest payload",
    }
    for payload, text in cases.items():
        reply = ask(payload)
        assert not reply.ok and reply.error_type == "MessageError", payload
        assert text in reply.error, (payload, reply.error)
    assert ask(encode(PreshapeRequest(angle=0.3))).ok  # still serving
    # A plain zenoh client without a payload gets the state (Empty is implied).
    [r] = list(session.get(Keys(ROBOT).hand_state, timeout=3.0))
    assert decode(r.ok.payload.to_bytes(), Reply[HandStateMsg]).result.preshape == 0.3


def test_no_node_fails_fast_with_clear_error(client_session: ZenohSession) -> None:
    rh = client_session.closing(RemoteHand(client_session.session, "nobody", timeout=2.0))
    with pytest.raises(NodeUnavailableError, match="no hand node of robot 'nobody' answers"):
        rh.state()
    with pytest.raises(NodeUnavailableError, match="liveliness token"):
        rh.wait_alive(timeout=0.2)


def test_node_stopped_mid_session(remote_hand: RemoteHand, hand_node: HandNode) -> None:
    assert remote_hand.state().preshape == 0.0
    hand_node.close()
    t0 = time.monotonic()
    with pytest.raises(NodeUnavailableError):
        remote_hand.guarded_close()
    assert time.monotonic() - t0 < remote_hand.motion_timeout
    # Once its liveliness token is known gone (it may drop after the first call failed, on
    # a loaded machine), every call fails at once, naming it gone.
    assert wait_for(lambda: remote_hand.alive is False, timeout=10.0)
    t1 = time.monotonic()
    with pytest.raises(NodeUnavailableError, match="gone"):
        remote_hand.open()
    assert time.monotonic() - t1 < remote_hand.timeout


def test_node_killed_during_a_command() -> None:
    endpoint = loopback_endpoint()
    hand = RecordingHand(close_delay=1.0)
    with ZenohSession(ZenohSettings.client(endpoint)) as client:
        ns = ZenohSession(ZenohSettings(listen=(endpoint,)))
        try:
            node = ns.closing(HandNode(hand, ns.session, ROBOT, state_hz=0))
            rh = client.closing(RemoteHand(client.session, ROBOT, timeout=2.0, motion_timeout=20.0))
            rh.connect()  # the client retries its connect endpoint until the node listens
            errors: list[BaseException] = []

            def grasp() -> None:
                try:
                    rh.guarded_close()
                except BaseException as e:
                    errors.append(e)

            t = threading.Thread(target=grasp)
            t.start()
            while node.busy != "guarded_close":
                time.sleep(0.01)
            t0 = time.monotonic()
            ns.close()  # the node's process goes away: token, queryables, session
            t.join(timeout=25.0)
            assert not t.is_alive()
            elapsed = time.monotonic() - t0
        finally:
            ns.close()
    [err] = errors
    assert isinstance(err, NodeUnavailableError), err
    assert elapsed < 20.0  # well inside the motion timeout: the dropped token woke the call


def test_stop_interrupts_execute(remote_arm: RemoteArm, arm: RecordingArm, client_session) -> None:
    other = client_session.closing(RemoteArm(client_session.session, ROBOT, timeout=3.0))
    long = JointTrajectory(
        names=RecordingArm.NAMES, times=np.array([0.0, 100.0]), positions=np.zeros((2, 6))
    )
    errors: list[BaseException] = []

    def run() -> None:
        try:
            remote_arm.execute(long)
        except BaseException as e:
            errors.append(e)

    t = threading.Thread(target=run)
    t.start()
    assert arm.executing.wait(5.0)
    other.stop()  # served at once, beside the running execute
    t.join(timeout=10.0)
    assert not t.is_alive()
    [err] = errors
    assert isinstance(err, DataError) and "interrupted" in str(err)


def test_expired_requests_are_not_executed(node_session: ZenohSession, client_session) -> None:
    # The node's own clock decides how long a query waited: the guarded close takes 0.6 s of
    # it (and no wall time), so the open queued behind it, whose caller waits 0.2 s, has
    # expired when its turn comes, however loaded the machine.
    clock = ManualClock()
    hand = RecordingHand()
    started, release = threading.Event(), threading.Event()

    def slow_close() -> None:
        started.set()
        release.wait(10.0)  # hold the worker until the open is queued
        clock.advance(0.6)

    hand.before_close = slow_close
    session = client_session.session
    keys = Keys(ROBOT)
    with HandNode(hand, node_session.session, ROBOT, state_hz=0.0, clock=clock) as node:
        # The node's queryables reach the client before its token: once the token is seen,
        # a query is routed (on a loaded machine that can take a moment).
        rh = client_session.closing(RemoteHand(session, ROBOT, timeout=30.0))
        rh.wait_alive(30.0)
        first = session.get(keys.hand_guarded_close, timeout=30.0)
        assert started.wait(30.0)
        late = session.get(f"{keys.hand_open}?timeout=0.2", payload=encode(Empty()), timeout=10.0)
        while node.queued() == 0:  # the open is in the queue, behind the close
            time.sleep(0.005)
        release.set()
        [r1] = list(first)
        assert r1.ok is not None
        [r2] = list(late)
    reply = decode(r2.err.payload.to_bytes(), Reply[None])
    assert "not executed" in reply.error
    assert ("open",) not in hand.calls


def test_message_error_from_bad_reply(node_session: ZenohSession, client_session) -> None:
    # A foreign queryable answering garbage: the client says so instead of crashing.
    keys = Keys("foreign")

    def answer(query) -> None:
        query.reply(keys.hand_state, b'{"v": 1, "ok": true, "result": {"v": 1}}')

    s = node_session.session
    node_session.closing(s.declare_queryable(keys.hand_state, answer))
    node_session.closing(s.liveliness().declare_token(keys.alive("hand")))
    rh = client_session.closing(RemoteHand(client_session.session, "foreign", timeout=2.0))
    rh.connect()  # the token is declared after the queryable: once seen, the queryable is known
    with pytest.raises(MessageError, match=r"result\.pressures"):
        rh.state()


def test_the_twin_served_over_zenoh_matches_in_process(node_session, client_session) -> None:
    """SimHand / SimArm behind nodes (one world, one lock) give the in-process grasp exactly."""
    sim_world = pytest.importorskip("activetouch.sim.world")
    sim_hand = pytest.importorskip("activetouch.sim.hand")
    from scipy.spatial.transform import Rotation

    from activetouch.sim.twin import twin_wrist

    # Hand +z along world +x, towards a 6 cm sphere; contacts on its surface.
    side = Rotation.from_matrix(np.column_stack([[0, 1, 0], [0, 0, 1], [1, 0, 0]])).as_quat()
    pose = Pose(np.array([-(0.06 + 0.0896 + 0.01), 0.0, 0.0]), side)
    under_table = Pose(np.array([0.0, 0.0, -0.5]), side)

    with sim_world.SimWorld() as local_world:
        local_world.place_primitive("sphere", 0.06)
        local_arm, local_hand = sim_world.SimArm(local_world), sim_hand.SimHand(local_world)
        local_hand.open()
        twin_wrist(local_arm).move_to(pose)
        want = local_hand.guarded_close()

    with sim_world.SimWorld() as world:
        world.place_primitive("sphere", 0.06)
        lock = threading.Lock()  # one pybullet client behind both nodes
        s = node_session.session
        hand_node = HandNode(sim_hand.SimHand(world), s, ROBOT, state_hz=20.0, lock=lock)
        sim_arm = sim_world.SimArm(world)
        arm_node = ArmNode(sim_arm, s, ROBOT, wrist=twin_wrist(sim_arm), state_hz=20.0, lock=lock)
        try:
            c = client_session.session
            with RemoteHand(c, ROBOT, timeout=5.0) as hand, RemoteArm(c, ROBOT, 5.0) as arm:
                hand.open()
                arm.move_wrist(pose)
                got = hand.guarded_close()
                with pytest.raises(UnreachableError):
                    arm.move_wrist(under_table)
                # Joints are the hand in the world; the sphere's centre is 6 cm up.
                np.testing.assert_allclose(
                    arm.joint_state().position[:3], pose.xyz + np.array([0, 0, 0.06]), atol=1e-9
                )
                assert hand.state().contact.sum() > 0
        finally:
            arm_node.close()
            hand_node.close()
    assert got.n_contacts >= 3
    np.testing.assert_array_equal(got.sensor_ids, want.sensor_ids)
    np.testing.assert_array_equal(got.xyz, want.xyz)
    np.testing.assert_array_equal(got.pressures, want.pressures)
    np.testing.assert_array_equal(got.finger_angles, want.finger_angles)


EXIT_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from test_nodes import RecordingArm, RecordingHand
from activetouch.daemon.nodes import ArmNode, HandNode
from activetouch.daemon.remote import RemoteHand
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings, free_tcp_port
ep = f"tcp/127.0.0.1:{{free_tcp_port()}}"
node = ZenohSession(ZenohSettings(listen=(ep,)))
client = ZenohSession(ZenohSettings.client(ep))
HandNode(RecordingHand(), node.session, "exitbot", state_hz=100)
arm = RecordingArm()
ArmNode(arm, node.session, "exitbot", wrist=arm, state_hz=100)
hand = RemoteHand(client.session, "exitbot")
hand.connect()
hand.guarded_close()
print("leaving everything open", flush=True)
"""


def test_interpreter_exits_with_nodes_left_open() -> None:
    """A script that forgets to close its sessions and nodes still exits, cleanly."""
    import subprocess
    import sys
    from pathlib import Path

    script = EXIT_SCRIPT.format(tests=str(Path(__file__).parent))
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "leaving everything open" in proc.stdout


def test_alive_nodes_tracks_tokens(node_session: ZenohSession, client_session, hand, arm) -> None:
    alive = client_session.closing(AliveNodes(client_session.session, ROBOT))
    hand_node = HandNode(hand, node_session.session, ROBOT, state_hz=0)
    arm_node = node_session.closing(ArmNode(arm, node_session.session, ROBOT, state_hz=0))
    alive.wait_for("hand", timeout=5.0)
    alive.wait_for("arm", timeout=5.0)
    assert alive.snapshot() == {"hand": True, "arm": True}
    hand_node.close()
    alive.wait_for("hand", timeout=5.0, alive=False)
    assert alive.snapshot() == {"hand": False, "arm": True}
    assert alive.since("hand") is not None and alive.since("gripper") is None
    assert arm_node.busy is None


def test_arm_estop_enable_disable_reach_the_device(
    remote_arm: RemoteArm, arm: RecordingArm
) -> None:
    remote_arm.enable()
    remote_arm.disable()
    remote_arm.estop()
    assert [c[0] for c in arm.calls] == ["enable", "disable", "estop"]


def test_motion_stats_are_served_at_once_and_move_wrist_still_replies_null(
    remote_arm: RemoteArm, arm: RecordingArm, client_session
) -> None:
    """``arm/motion_stats`` answers the node's wrist counters (RemoteArm.robot_seconds /
    planning_seconds), also while a motion runs; ``arm/move_wrist`` replies null as before."""
    keys = Keys(ROBOT)
    session = client_session.session
    [r] = list(
        session.get(
            keys.arm_move_wrist,
            payload=encode(
                MoveWristRequest(
                    pose=pose_to_msg(
                        Pose(np.array([0.1, 0.0, 0.3]), np.array([0.0, 0.0, 0.0, 1.0]))
                    )
                )
            ),
            timeout=5.0,
        )
    )
    assert decode(r.ok.payload.to_bytes(), Reply[None]).result is None
    assert (remote_arm.robot_seconds, remote_arm.planning_seconds) == (0.0, 0.0)
    arm.robot_seconds, arm.planning_seconds, arm.moves = 12.5, 0.25, 3
    assert (remote_arm.robot_seconds, remote_arm.planning_seconds) == (12.5, 0.25)
    [r] = list(session.get(keys.arm_motion_stats, timeout=5.0))
    stats = decode(r.ok.payload.to_bytes(), Reply[MotionStats]).result
    assert stats == MotionStats(robot_s=12.5, planning_s=0.25, moves=3)

    long = JointTrajectory(
        names=RecordingArm.NAMES, times=np.array([0.0, 100.0]), positions=np.zeros((2, 6))
    )
    errors: list[BaseException] = []

    def run() -> None:
        try:
            remote_arm.execute(long)
        except BaseException as e:  # the stop below ends it
            errors.append(e)

    t = threading.Thread(target=run)
    t.start()
    try:
        assert arm.executing.wait(5.0)
        other = client_session.closing(RemoteArm(session, ROBOT, timeout=1.0))
        assert other.robot_seconds == 12.5  # beside the running execute, not behind it:
        assert arm.executing.is_set()  # the execute is still running when the answer came
    finally:
        arm.stop()
        t.join(timeout=10.0)
    assert not t.is_alive() and isinstance(errors[0], DataError)


def test_motion_stats_of_a_node_without_a_wrist_are_zero(
    arm: RecordingArm, node_session: ZenohSession, client_session
) -> None:
    node_session.closing(ArmNode(arm, node_session.session, ROBOT, state_hz=0.0))
    ra = client_session.closing(RemoteArm(client_session.session, ROBOT, timeout=3.0))
    ra.connect()
    arm.robot_seconds = 9.0  # the arm's own attribute; this node has no motion layer
    assert (ra.robot_seconds, ra.planning_seconds) == (0.0, 0.0)


class StreamingHand(RecordingHand):
    """A hand that reports readings as they arrive (as the ReFlex drivers do)."""

    def __init__(self) -> None:
        super().__init__(close_delay=1.0)
        self.listeners: list = []

    def add_state_listener(self, fn) -> None:
        self.listeners.append(fn)

    def emit(self, stale: bool = False) -> None:
        s = self.state()
        s = HandState(s.pressures, s.contact, s.finger_angles, s.preshape, s.stamp, stale, 123.0)
        for fn in self.listeners:
            fn(s)


def test_a_streaming_hand_is_published_beside_a_running_grasp(
    node_session: ZenohSession, client_session: ZenohSession
) -> None:
    from activetouch.daemon.remote import Latest
    from activetouch.transport.messages import HandStateMsg

    hand = StreamingHand()
    node_session.closing(HandNode(hand, node_session.session, ROBOT, state_hz=50.0))
    latest = client_session.closing(
        Latest(client_session.session, Keys(ROBOT).hand_state, HandStateMsg)
    )
    rh = client_session.closing(RemoteHand(client_session.session, ROBOT, timeout=3.0))
    rh.connect()
    # Readings until one arrives: the subscription is matched (a reading published before
    # that is not kept, and on a loaded machine matching can outlast the grasp below).
    for _ in range(200):
        hand.emit()
        try:
            latest.wait(0.05)
            break
        except NodeUnavailableError:
            continue
    seen = latest.count
    t = threading.Thread(target=rh.guarded_close)  # holds the node's worker for 1 s
    t.start()
    time.sleep(0.2)
    hand.emit(stale=True)  # a reading during the grasp: published at once
    for _ in range(50):  # past any reading from the loop above still on its way
        msg = latest.wait(10.0, newer_than=seen)  # a loaded machine delays the delivery
        if msg.stale:
            break
        seen = latest.count
    assert msg.stale is True and msg.wall_stamp == 123.0
    t.join(5.0)


def test_noise_thresholds_and_sensor_flags_cross_the_wire(
    remote_hand: RemoteHand, hand: RecordingHand
) -> None:
    # A hand without them answers False / {} (the session then filters itself).
    assert remote_hand.set_contact_thresholds([25.0] * 38) is False
    assert remote_hand.sensor_flags() == {}
    got: list[list[float]] = []
    hand.set_contact_thresholds = lambda t: got.append(list(t)) or True  # type: ignore[method-assign]
    hand.sensor_flags = lambda: {4: "dead", 30: "noisy"}  # type: ignore[method-assign]
    thr = [20.0 + i for i in range(38)]
    assert remote_hand.set_contact_thresholds(thr) is True
    assert got == [thr]
    assert remote_hand.sensor_flags() == {4: "dead", 30: "noisy"}
    with pytest.raises(Exception, match="thresholds"):  # 38 values or an error reply
        remote_hand.set_contact_thresholds([1.0] * 5)


def test_sensor_sites_and_own_thresholds_cross_the_wire(
    remote_hand: RemoteHand, hand: RecordingHand
) -> None:
    # A hand that does not tell them gives None on the client (the session then reads its
    # grasps as they are); one that does gives them as its node read them.
    assert remote_hand.sensor_sites() is None
    assert remote_hand.own_contact_thresholds() is None
    sites = np.arange(38 * 3, dtype=np.float64).reshape(38, 3) / 1000.0
    hand.sensor_sites = lambda: sites  # type: ignore[method-assign]
    hand.own_contact_thresholds = lambda: np.full(38, 20.0)  # type: ignore[method-assign]
    np.testing.assert_array_equal(remote_hand.sensor_sites(), sites)
    np.testing.assert_array_equal(remote_hand.own_contact_thresholds(), np.full(38, 20.0))
    hand.sensor_sites = lambda: sites[:5]  # type: ignore[method-assign]
    assert remote_hand.sensor_sites() is None  # not one per sensor: not the hand's layout


class WideHand(RecordingHand):
    """A hand with a BarrettHand's 96 sensors: records the masks and thresholds it is given;
    its grasp touches 5, 30 and 90."""

    IDS = (5, 30, 90)

    def __init__(self) -> None:
        super().__init__()
        self.masks: list[list[int]] = []
        self.thresholds: list[list[float]] = []

    @property
    def n_sensors(self) -> int:
        return 96

    def state(self) -> HandState:
        contact = np.zeros(96, dtype=bool)
        contact[list(self.IDS)] = self.closed
        return HandState(
            np.arange(96.0) * contact, contact, np.zeros(3), self.angle, time.monotonic()
        )

    def guarded_close(self):
        g = super().guarded_close()
        ids = np.array(self.IDS)
        return type(g)(ids, np.zeros((3, 3)), ids * 1.0, g.finger_angles, g.preshape)

    def mask_sensors(self, sensor_ids) -> bool:
        self.masks.append([int(i) for i in sensor_ids])
        return True

    def set_contact_thresholds(self, thresholds) -> bool:
        self.thresholds.append([float(t) for t in thresholds])
        return True


def test_a_96_sensor_hand_is_served_with_its_sensor_count(
    node_session: ZenohSession, client_session: ZenohSession
) -> None:
    """``hand/info`` gives the hand's count; states, grasps, thresholds and masks of 96
    sensors cross; another count is refused with an error reply and the node serves on."""
    hand = WideHand()
    node_session.closing(
        HandNode(hand, node_session.session, ROBOT, state_hz=50.0, device="wide-hand")
    )
    published = client_session.closing(
        Latest(client_session.session, Keys(ROBOT).hand_state, HandStateMsg)
    )
    rh = client_session.closing(RemoteHand(client_session.session, ROBOT, timeout=5.0))
    rh.connect()
    assert rh.info() == HandInfo(n_sensors=96, device="wide-hand") and rh.n_sensors == 96
    assert rh.state().pressures.shape == (96,)
    assert rh.guarded_close().sensor_ids.tolist() == [5, 30, 90]
    st = rh.state()
    assert st.contact.shape == (96,) and np.flatnonzero(st.contact).tolist() == [5, 30, 90]
    thr = [10.0 + i for i in range(96)]
    assert rh.set_contact_thresholds(thr) is True and hand.thresholds == [thr]
    assert rh.mask_sensors([40, 95]) is True and hand.masks == [[40, 95]]
    with pytest.raises(
        MessageError,
        match=r"`thresholds`: 38 values, expected 96, one per sensor of this hand "
        r"\(wide-hand, 96 sensors\)",
    ):
        rh.set_contact_thresholds([1.0] * 38)
    with pytest.raises(MessageError, match=r"sensor_ids\[0\]`: Expected `int` <= 95"):
        rh.mask_sensors([96])
    assert hand.thresholds == [thr] and hand.masks == [[40, 95]]  # refused before the hand
    assert rh.state().pressures.shape == (96,)  # still serving
    assert len(published.wait(timeout=10.0).pressures) == 96 and published.invalid == 0


def test_a_38_sensor_hand_refuses_ids_and_thresholds_beyond_its_sensors(
    remote_hand: RemoteHand, hand: RecordingHand
) -> None:
    assert remote_hand.n_sensors == N_SENSORS and remote_hand.info().device == ""
    with pytest.raises(MessageError, match=r"\[40, 95\] are not sensor ids of this hand "):
        remote_hand.mask_sensors([3, 40, 95])
    with pytest.raises(MessageError, match="96 values, expected 38"):
        remote_hand.set_contact_thresholds([1.0] * 96)
    assert remote_hand.mask_sensors([3, 37]) is False  # RecordingHand cannot mask: False


def test_a_node_without_hand_info_serves_38_sensors(
    node_session: ZenohSession, client_session: ZenohSession
) -> None:
    """A hand node from before ``hand/info``: the client takes 38 sensors (asking costs one
    query, answered by nobody at once), and a state of 96 is refused as not that hand's."""
    keys = Keys("older")
    state = HandState(np.zeros(96), np.zeros(96, dtype=bool), np.zeros(3), 0.0, 1.0)

    def answer(query) -> None:
        query.reply(keys.hand_state, encode(Reply.success(hand_state_to_msg(state))))

    s = node_session.session
    node_session.closing(s.declare_queryable(keys.hand_state, answer))
    node_session.closing(s.liveliness().declare_token(keys.alive("hand")))
    rh = client_session.closing(RemoteHand(client_session.session, "older", timeout=5.0))
    rh.connect()
    assert rh.n_sensors == 38 and rh.info() == HandInfo()
    with pytest.raises(
        MessageError, match=r"`pressures` has 96 values, expected 38 \(the hand node reported 38"
    ):
        rh.state()


def test_a_hand_the_messages_cannot_carry_is_refused_at_once(node_session) -> None:
    class Huge(RecordingHand):
        n_sensors = 120

    with pytest.raises(MessageError, match=r"120 tactile sensors: the hand messages carry 1\.\.96"):
        HandNode(Huge(), node_session.session, ROBOT, state_hz=0.0)
