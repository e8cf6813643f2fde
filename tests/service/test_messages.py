"""Wire messages: round trips, conversions, and malformed payloads rejected with the field named."""

from __future__ import annotations

import json

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from activetouch.errors import ConfigError, MessageError, UnreachableError
from activetouch.interfaces import N_SENSORS, Grasp, HandState, JointState, JointTrajectory, Pose
from activetouch.transport import messages as m
from activetouch.transport.keys import Keys, validate_robot
from activetouch.transport.zenoh_session import ZenohSettings, make_config, validate_endpoint


def _grasp() -> Grasp:
    ids = np.array([3, 12, 30])
    return Grasp(
        sensor_ids=ids,
        xyz=np.array([[0.01, 0.02, 0.03], [0.04, -0.05, 0.06], [0.0, 0.0, 0.082]]),
        pressures=np.array([25.0, 40.5, 120.0]),
        finger_angles=np.array([1.2, 1.3, 0.9]),
        preshape=0.8,
    )


def test_grasp_round_trip() -> None:
    g = _grasp()
    back = m.from_msg(m.decode(m.encode(m.to_msg(g)), m.GraspMsg))
    assert isinstance(back, Grasp)
    np.testing.assert_array_equal(back.sensor_ids, g.sensor_ids)
    np.testing.assert_array_equal(back.xyz, g.xyz)  # JSON floats round-trip exactly
    np.testing.assert_array_equal(back.pressures, g.pressures)
    np.testing.assert_array_equal(back.finger_angles, g.finger_angles)
    assert back.preshape == 0.8


def test_empty_grasp_round_trip() -> None:
    g = Grasp(np.zeros(0, int), np.zeros((0, 3)), np.zeros(0), np.zeros(3))
    back = m.grasp_from_msg(m.decode(m.encode(m.grasp_to_msg(g)), m.GraspMsg))
    assert back.n_contacts == 0 and back.xyz.shape == (0, 3)


def test_pose_hand_state_joint_state_trajectory_round_trips() -> None:
    pose = Pose(np.array([0.1, -0.2, 0.3]), np.array([0.1, 0.2, 0.3, 0.9]))
    back = m.from_msg(m.decode(m.encode(m.to_msg(pose)), m.PoseMsg))
    np.testing.assert_allclose(back.as_array(), pose.as_array())

    contact = np.zeros(N_SENSORS, bool)
    contact[[1, 20]] = True
    hs = HandState(np.linspace(0, 37, N_SENSORS), contact, np.array([0.1, 0.2, 0.3]), 0.4, 12.5)
    hb = m.from_msg(m.decode(m.encode(m.to_msg(hs)), m.HandStateMsg))
    np.testing.assert_array_equal(hb.pressures, hs.pressures)
    np.testing.assert_array_equal(hb.contact, contact)
    assert hb.contact.dtype == bool and hb.stamp == 12.5 and hb.preshape == 0.4

    js = JointState(("s0", "s1"), np.array([0.5, -0.5]), np.array([0.0, 0.1]), 3.0)
    jb = m.from_msg(m.decode(m.encode(m.to_msg(js)), m.JointStateMsg))
    assert jb.names == ("s0", "s1")
    np.testing.assert_array_equal(jb.velocity, js.velocity)

    traj = JointTrajectory(
        names=("a", "b"),
        times=np.array([0.0, 0.5, 1.0]),
        positions=np.arange(6.0).reshape(3, 2),
        velocities=np.zeros((3, 2)),
        accelerations=np.array([[1.5, -1.5], [0.0, 0.0], [-1.5, 1.5]]),
        meta={"ik": "pinocchio", "cost": np.float64(0.25), "seg": np.array([1, 2])},
    )
    tb = m.from_msg(m.decode(m.encode(m.to_msg(traj)), m.JointTrajectoryMsg))
    np.testing.assert_array_equal(tb.positions, traj.positions)
    np.testing.assert_array_equal(tb.velocities, traj.velocities)
    np.testing.assert_array_equal(tb.accelerations, traj.accelerations)
    with pytest.raises(m.MessageError):  # one row short
        m.to_msg(JointTrajectory(("a",), np.zeros(2), np.zeros((2, 1)), accelerations=np.zeros(1)))
    assert tb.meta == {"ik": "pinocchio", "cost": 0.25, "seg": [1, 2]}


@settings(max_examples=50, deadline=None)
@given(
    n=st.integers(0, N_SENSORS),
    seed=st.integers(0, 2**32 - 1),
    preshape=st.floats(0, 1.6),
)
def test_grasp_round_trip_property(n: int, seed: int, preshape: float) -> None:
    rng = np.random.default_rng(seed)
    ids = rng.choice(N_SENSORS, size=n, replace=False)
    g = Grasp(ids, rng.normal(size=(n, 3)), rng.uniform(0, 500, n), rng.uniform(0, 3, 3), preshape)
    back = m.grasp_from_msg(m.decode(m.encode(m.grasp_to_msg(g)), m.GraspMsg))
    np.testing.assert_array_equal(back.sensor_ids, g.sensor_ids)
    np.testing.assert_array_equal(back.xyz, g.xyz)
    np.testing.assert_array_equal(back.pressures, g.pressures)
    assert back.preshape == preshape


def test_daemon_messages_round_trip() -> None:
    req = m.RecognizeRequest(policy="greedy", max_moves=10, seed=3, object="mug", horizon=1)
    assert m.decode(m.encode(req), m.RecognizeRequest) == req
    prog = m.Progress(
        session_id="s1",
        move=2,
        pose=m.PoseMsg(xyz=(0.0, 0.1, 0.2), quat=(0.0, 0.0, 0.0, 1.0)),
        n_contacts=5,
        top3=[("mug", 0.6), ("cup", 0.3), ("bowl", 0.1)],
        skipped=1,
    )
    assert m.decode(m.encode(prog), m.Progress) == prog
    res = m.RecognizeResult(
        session_id="s1", label="mug", probability=0.9, labels=["cup", "mug"], moves=1
    )
    assert m.decode(m.encode(m.Reply.success(res)), m.Reply[m.RecognizeResult]).result == res
    status = m.Status(
        robot="sim",
        nodes={"hand": m.NodeHealth(alive=True), "arm": m.NodeHealth(alive=False, detail="gone")},
        model_loaded=True,
        session=m.SessionSummary(session_id="s1", policy="tree", max_moves=16, move=3),
    )
    assert m.decode(m.encode(status), m.Status) == status
    for msg in (
        m.CancelRequest(),
        m.CancelResult(cancelled=True, session_id="s1"),
        m.EStopRequest(reason="test"),
        m.EStopResult(arm_stopped=True, hand_opened=True),
    ):
        assert m.decode(m.encode(msg), type(msg)) == msg


def test_wire_format_is_plain_json_with_version_first() -> None:
    data = m.encode(m.PreshapeRequest(angle=0.8))
    assert data.startswith(b'{"v":1,')
    assert json.loads(data) == {"v": m.SCHEMA_VERSION, "angle": 0.8}
    # What a client written in any language sends:
    req = m.decode(b'{"v": 1, "policy": "tree", "max_moves": 8}', m.RecognizeRequest)
    assert req.seed is None and req.object is None


def test_reply_failure_carries_the_error_type() -> None:
    r = m.Reply.failure(UnreachableError("pose 12 out of reach"))
    back = m.decode(m.encode(r), m.Reply[None])
    assert not back.ok and back.error == "pose 12 out of reach"
    assert back.error_type == "UnreachableError" and "ActiveTouchError" in back.error_bases
    assert m.error_types()["UnreachableError"] is UnreachableError


@pytest.mark.parametrize(
    ("payload", "typ", "field", "text"),
    [
        (b'{"v":1,"policy":"tree","max_moves":-3}', m.RecognizeRequest, "max_moves", ">= 1"),
        (b'{"v":1,"policy":"tree","max_moves":0}', m.RecognizeRequest, "max_moves", ">= 1"),
        (b'{"v":1,"policy":"best","max_moves":3}', m.RecognizeRequest, "policy", "'best'"),
        (b'{"v":1,"policy":"tree","max_moves":"3"}', m.RecognizeRequest, "max_moves", "`str`"),
        (b'{"v":1,"policy":"tree"}', m.RecognizeRequest, "max_moves", "missing"),
        (
            b'{"v":1,"policy":"tree","max_moves":3,"maxmoves":2}',
            m.RecognizeRequest,
            "maxmoves",
            "unknown field",
        ),
        (b'{"v":1,"policy":"tree","max_moves":3,"seed":-1}', m.RecognizeRequest, "seed", ">= 0"),
        (
            b'{"v":1,"policy":"tree","max_moves":3,"object":""}',
            m.RecognizeRequest,
            "object",
            "length",
        ),
        (
            b'{"v":2,"policy":"tree","max_moves":3}',
            m.RecognizeRequest,
            "v",
            "schema version 2 is not supported",
        ),
        (b'{"policy":"tree","max_moves":3}', m.RecognizeRequest, "v", "missing"),
        (b'{"v":"one"}', m.RecognizeRequest, "v", "`str`"),
        (
            b'{"v":1,"pose":{"xyz":[0,0],"quat":[0,0,0,1]}}',
            m.MoveWristRequest,
            "pose.xyz",
            "length 3",
        ),
        (
            b'{"v":1,"pose":{"xyz":[0,0,0],"quat":[0,0,0,0]}}',
            m.MoveWristRequest,
            "pose",
            "`quat` has zero norm",
        ),
        (
            b'{"v":1,"pose":{"v":7,"xyz":[0,0,0],"quat":[0,0,0,1]}}',
            m.MoveWristRequest,
            "pose",
            "schema version 7",
        ),
        (
            b'{"v":1,"sensor_ids":[1,96],"xyz":[[0,0,0],[0,0,0]],"pressures":[1,2],'
            b'"finger_angles":[0,0,0]}',
            m.GraspMsg,
            "sensor_ids[1]",
            "<= 95",
        ),
        (
            b'{"v":1,"sensor_ids":[1,2],"xyz":[[0,0,0]],"pressures":[1,2],"finger_angles":[0,0,0]}',
            m.GraspMsg,
            None,
            "differ in length",
        ),
        (
            b'{"v":1,"sensor_ids":[],"xyz":[],"pressures":[],"finger_angles":[0,0]}',
            m.GraspMsg,
            "finger_angles",
            "length >= 3",
        ),
        (
            b'{"v":1,"pressures":[],"contact":[],"finger_angles":[0,0,0],"preshape":0,"stamp":0}',
            m.HandStateMsg,
            "pressures",
            "length >= 1",
        ),
        (
            b'{"v":1,"pressures":[0],"contact":[true,false],"finger_angles":[0,0,0],'
            b'"preshape":0,"stamp":0}',
            m.HandStateMsg,
            None,
            "differ in length",
        ),
        (
            b'{"v":1,"pressures":[' + b",".join([b"0"] * 97) + b'],"contact":[true],'
            b'"finger_angles":[0,0,0],"preshape":0,"stamp":0}',
            m.HandStateMsg,
            "pressures",
            "length <= 96",
        ),
        (b'{"v":1,"thresholds":[]}', m.ThresholdsRequest, "thresholds", "length >= 1"),
        (b'{"v":1,"sensor_ids":[3,96]}', m.MaskRequest, "sensor_ids[1]", "<= 95"),
        (b'{"v":1,"n_sensors":97}', m.HandInfo, "n_sensors", "<= 96"),
        (b'{"v":1,"n_sensors":0}', m.HandInfo, "n_sensors", ">= 1"),
        (
            b'{"v":1,"trajectory":{"names":["a"],"times":[0,1],"positions":[[0],[1,2]]}}',
            m.ExecuteRequest,
            "trajectory",
            "`positions[1]` has 2 values",
        ),
        (
            b'{"v":1,"trajectory":{"names":["a"],"times":[1,0],"positions":[[0],[1]]}}',
            m.ExecuteRequest,
            "trajectory",
            "must not decrease",
        ),
        (
            b'{"v":1,"pose":{"xyz":[0,0,1e999],"quat":[0,0,0,1]}}',
            m.MoveWristRequest,
            "pose.xyz[2]",
            "out of range",
        ),
        (b'{"v":1,"ok":false}', m.Reply[None], None, "`error` must say"),
        (
            b'{"v":1,"ok":true,"result":{"v":1,"xyz":[0,0,0]}}',
            m.Reply[m.PoseMsg],
            "result.quat",
            "missing",
        ),
    ],
)
def test_malformed_payloads_name_the_field(payload, typ, field, text) -> None:
    with pytest.raises(MessageError) as info:
        m.decode(payload, typ)
    msg = str(info.value)
    assert text in msg, msg
    assert info.value.field == field, msg
    if field:
        assert f"field `{field}`" in msg


@pytest.mark.parametrize("payload", [b"", b"not json", b"{", b"[1, 2]", b"null", b'"x"'])
def test_not_a_json_object(payload: bytes) -> None:
    with pytest.raises(MessageError, match="invalid PreshapeRequest"):
        m.decode(payload, m.PreshapeRequest)


def test_conversions_reject_non_finite_values() -> None:
    with pytest.raises(MessageError, match="`pressures` contains NaN"):
        m.grasp_to_msg(Grasp(np.array([1]), np.zeros((1, 3)), np.array([np.nan]), np.zeros(3)))
    with pytest.raises(MessageError, match="`pressures` has 37 values, expected 38"):
        m.hand_state_to_msg(HandState(np.zeros(37), np.zeros(37, bool), np.zeros(3), 0.0, 0.0), 38)
    with pytest.raises(MessageError, match="`contact` has 37 values, expected 38"):
        m.hand_state_to_msg(HandState(np.zeros(38), np.zeros(37, bool), np.zeros(3), 0.0, 0.0))
    with pytest.raises(MessageError, match=r"97 tactile sensors: the hand messages carry 1\.\.96"):
        m.hand_state_to_msg(HandState(np.zeros(97), np.zeros(97, bool), np.zeros(3), 0.0, 0.0))
    with pytest.raises(MessageError, match="cannot encode"):
        m.encode(
            m.JointTrajectoryMsg(names=["a"], times=[0.0], positions=[[0.0]], meta={"x": object()})
        )
    with pytest.raises(TypeError):
        m.to_msg("not an interfaces value")  # type: ignore[arg-type]


def test_every_message_is_versioned_and_strict() -> None:
    for name in m.__all__:
        obj = getattr(m, name)
        if isinstance(obj, type) and issubclass(obj, msgspec.Struct):
            assert issubclass(obj, m.Message), name
            assert obj.__struct_config__.forbid_unknown_fields, name
            assert "v" in obj.__struct_fields__, name


def test_hands_with_up_to_96_sensors_cross_the_wire() -> None:
    """A BarrettHand's 96 cells: states, grasps, thresholds and masks of any count 1..96; a
    receiver that knows its hand's count refuses another with the field and both counts."""
    n = m.MAX_SENSORS
    contact = np.zeros(n, bool)
    contact[[24, 50, 95]] = True
    hs = HandState(np.linspace(0, 1, n), contact, np.array([0.1, 0.2, 0.3]), 0.4, 12.5)
    msg = m.decode(m.encode(m.hand_state_to_msg(hs, n)), m.HandStateMsg)
    back = m.hand_state_from_msg(msg, n)
    np.testing.assert_array_equal(back.contact, contact)
    with pytest.raises(MessageError, match=r"`pressures` has 96 values, expected 38 \(the hand "):
        m.hand_state_from_msg(msg, 38)
    with pytest.raises(MessageError, match="`pressures` has 96 values, expected 38"):
        m.hand_state_to_msg(hs, 38)
    # A ReFlex state of an older producer still decodes, for a 38-sensor hand.
    old = m.decode(
        m.encode(
            m.hand_state_to_msg(HandState(np.zeros(38), np.zeros(38, bool), np.zeros(3), 0.0, 1.0))
        ),
        m.HandStateMsg,
    )
    assert m.hand_state_from_msg(old, N_SENSORS).pressures.shape == (38,)

    ids = np.array([3, 30, 47, 95])
    g = Grasp(ids, np.zeros((4, 3)), np.ones(4), np.zeros(3), 0.5)
    gm = m.decode(m.encode(m.grasp_to_msg(g, n)), m.GraspMsg)
    assert m.grasp_from_msg(gm, n).sensor_ids.tolist() == ids.tolist()
    with pytest.raises(MessageError, match=r"`sensor_ids` has \[47, 95\]: not a sensor id"):
        m.grasp_from_msg(gm, 38)
    with pytest.raises(MessageError, match=r"\[47, 95\]: not a sensor id of a hand with 38"):
        m.grasp_to_msg(g, 38)

    thr = m.decode(m.encode(m.ThresholdsRequest(thresholds=[1.0] * n)), m.ThresholdsRequest)
    assert len(thr.thresholds) == n
    assert m.decode(b'{"v":1,"sensor_ids":[0,95]}', m.MaskRequest).sensor_ids == [0, 95]
    # HandInfo: a node that says nothing more serves a ReFlex's 38.
    assert m.decode(b'{"v":1}', m.HandInfo) == m.HandInfo(n_sensors=38, device="")
    info = m.HandInfo(n_sensors=96, device="barrett-bh8")
    assert m.decode(m.encode(info), m.HandInfo) == info
    assert Keys("b").hand_info == "activetouch/b/hand/info"


def test_keys() -> None:
    k = Keys("baxter-1")
    assert k.hand_state == "activetouch/baxter-1/hand/state"
    assert k.hand_guarded_close == "activetouch/baxter-1/hand/guarded_close"
    assert k.arm_joint_states == "activetouch/baxter-1/arm/joint_states"
    assert k.arm_move_wrist == "activetouch/baxter-1/arm/move_wrist"
    assert k.recognize == "activetouch/baxter-1/recognize"
    assert k.alive("hand") == "activetouch/baxter-1/alive/hand"
    assert k.alive_all == "activetouch/baxter-1/alive/*"
    assert Keys.node_of_alive_key(k.alive("arm")) == "arm"
    for bad in ("", "a/b", "*", "**", "a*", "$*", "a b", "x?y", "a#b", "-lead", "ü"):
        with pytest.raises(ConfigError, match="robot name"):
            validate_robot(bad)
    with pytest.raises(ConfigError, match="node name"):
        k.alive("hand/*")


def test_zenoh_settings_are_explicit_and_local() -> None:
    s = ZenohSettings()
    assert s.listen == ("tcp/127.0.0.1:7457",) and s.connect == ()
    conf = make_config(ZenohSettings.client("tcp/127.0.0.1:9000"))
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is False
    assert json.loads(conf.get_json("listen/endpoints")) == []
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9000"]
    for good in ("tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tls/robot.lan:7447", "tcp/localhost:1"):
        assert validate_endpoint(good) == good
    for bad in ("127.0.0.1:7447", "tcp/127.0.0.1", "tcp/127.0.0.1:99999", "tcp/ x:1", ""):
        with pytest.raises(ConfigError, match="endpoint"):
            validate_endpoint(bad)
    with pytest.raises(ConfigError, match="mode"):
        ZenohSettings(mode="router-ish")


def test_robot_time_fields_are_optional_and_old_results_still_decode() -> None:
    """A result of a daemon from before robot time (no motion_s, ...) decodes with zeros; the
    new fields round-trip and are validated; MotionStats is a strict, versioned message."""
    old = (
        b'{"v":1,"session_id":"demo-7","label":"cup","probability":0.99,"labels":["cup"],'
        b'"moves":1,"skipped":0,"planning_s":0.002,"elapsed_s":0.08,"policy":"tree","seed":7,'
        b'"object":"cup","stop_reason":"confident","pose_ids":[4]}'
    )
    res = m.decode(old, m.RecognizeResult)
    assert (res.motion_s, res.motion_planning_s, res.grasp_s) == (0.0, 0.0, 0.0)
    assert res.planning_s == 0.002 and res.pose_ids == [4]  # the other fields as they were
    new = m.RecognizeResult(
        session_id="s",
        label="cup",
        probability=0.9,
        labels=["cup"],
        moves=1,
        motion_s=12.5,
        motion_planning_s=0.25,
        grasp_s=3.0,
    )
    back = m.decode(m.encode(new), m.RecognizeResult)
    assert (back.motion_s, back.motion_planning_s, back.grasp_s) == (12.5, 0.25, 3.0)
    bad = json.loads(m.encode(new))
    bad["grasp_s"] = -1.0
    with pytest.raises(MessageError, match="field `grasp_s`"):
        m.decode(json.dumps(bad).encode(), m.RecognizeResult)

    progress = m.decode(
        b'{"v":1,"session_id":"s","move":1,"pose":null,"n_contacts":0,"top3":[]}', m.Progress
    )
    assert progress.motion_s == 0.0
    assert (
        m.decode(
            m.encode(m.Progress(**{**msgspec.structs.asdict(progress), "motion_s": 4.5})),
            m.Progress,
        ).motion_s
        == 4.5
    )

    stats = m.MotionStats(robot_s=3.5, planning_s=0.1, moves=2)
    assert m.decode(m.encode(stats), m.MotionStats) == stats
    assert m.decode(b'{"v":1}', m.MotionStats) == m.MotionStats()
    with pytest.raises(MessageError, match="field `moves`"):
        m.decode(b'{"v":1,"moves":-1}', m.MotionStats)
    with pytest.raises(MessageError, match="robot_seconds"):
        m.decode(b'{"v":1,"robot_seconds":1.0}', m.MotionStats)  # unknown field: a typo
    assert Keys("b").arm_motion_stats == "activetouch/b/arm/motion_stats"


def test_the_record_field_is_sent_only_when_set() -> None:
    """`RecognizeRequest.record` came later: a request without it encodes as before (a daemon
    from before it, which refuses unknown fields, still reads it), and both forms decode."""
    plain = m.RecognizeRequest(policy="tree", max_moves=2, object="cup")
    assert b"record" not in m.encode(plain)
    assert m.decode(m.encode(plain), m.RecognizeRequest) == plain
    off = m.RecognizeRequest(policy="tree", max_moves=2, object="cup", record=False)
    assert b'"record":false' in m.encode(off)
    assert m.decode(m.encode(off), m.RecognizeRequest).record is False
    assert m.decode(b'{"v":1,"policy":"tree","max_moves":2}', m.RecognizeRequest).record is None
