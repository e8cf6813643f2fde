"""The daemon's ROS 2 face ([ros2] enabled) on the in-memory fake devices, seen by the test's own
ROS 2 client (tests/ros2/client.py: written from rmw_zenoh's behaviour, sharing no code with the
face) over loopback: the node and its services and topics in the graph, status / estop /
recognize calls answered with attachments, /joint_states and the contacts received."""

from __future__ import annotations

import json
import queue
from typing import Any

import pytest

from tests.conftest import FAKE_ROBOT
from tests.ros2.client import TRIGGER_HASH, RosTestClient, read_attachment
from tests.ros2.hashes import rihs01

TRIGGER = "std_srvs/srv/Trigger"
RECOGNIZE = "activetouch_interfaces/srv/Recognize"
JOINT_STATE = "sensor_msgs/msg/JointState"
CLOUD = "sensor_msgs/msg/PointCloud2"


@pytest.fixture
def face(start_fake_daemon):
    return start_fake_daemon(["ros2.enabled=true"])


def _trigger(store: Any) -> bytes:
    req = store.types[f"{TRIGGER}_Request"](structure_needs_at_least_one_member=0)
    return bytes(store.serialize_cdr(req, f"{TRIGGER}_Request"))


def _one(replies: list, client: RosTestClient, store: Any, response_type: str) -> Any:
    assert len(replies) == 1, replies
    seq, _stamp, gid = read_attachment(replies[0].attachment)
    assert (seq, gid) == (client._seq, client.gid)  # the client's own, echoed
    return store.deserialize_cdr(replies[0].payload, response_type)


def test_graph_status_estop_and_joint_states(face, store) -> None:
    daemon, ep = face
    with RosTestClient(ep) as client:
        tok = client.wait_for_service("/activetouch/status", TRIGGER)
        assert tok.hash == TRIGGER_HASH and tok.node == "activetouch" and tok.namespace == "/"
        graph = client.graph()
        assert any(t.kind == "NN" and t.node == "activetouch" for t in graph)
        services = {t.name: (t.type, t.hash) for t in graph if t.kind == "SS"}
        assert services == {
            "/activetouch/recognize": ("activetouch_interfaces::srv::dds_::Recognize_",
                                       rihs01(RECOGNIZE)),
            "/activetouch/cancel": ("std_srvs::srv::dds_::Trigger_", TRIGGER_HASH),
            "/activetouch/estop": ("std_srvs::srv::dds_::Trigger_", TRIGGER_HASH),
            "/activetouch/status": ("std_srvs::srv::dds_::Trigger_", TRIGGER_HASH),
        }  # fmt: skip
        topics = {t.name: t.type for t in graph if t.kind == "MP" and t.node == "activetouch"}
        assert topics == {
            "/activetouch/progress": "activetouch_interfaces::msg::dds_::Progress_",
            "/activetouch/result": "activetouch_interfaces::msg::dds_::RecognitionResult_",
            "/activetouch/contacts": "sensor_msgs::msg::dds_::PointCloud2_",
            "/activetouch/tactile": "activetouch_interfaces::msg::dds_::Tactile_",
            "/joint_states": "sensor_msgs::msg::dds_::JointState_",
            "/tf": "tf2_msgs::msg::dds_::TFMessage_",
        }

        joints = client.subscribe("/joint_states", JOINT_STATE, rihs01(JOINT_STATE))
        resp = _one(
            client.call("/activetouch/status", TRIGGER, TRIGGER_HASH, _trigger(store)),
            client,
            store,
            f"{TRIGGER}_Response",
        )
        assert resp.success
        status = json.loads(resp.message)
        assert status["robot"] == FAKE_ROBOT and status["model_loaded"] is True
        assert status["nodes"]["daemon"]["alive"] is True

        payload, attachment = joints.get(timeout=30.0)
        js = store.deserialize_cdr(payload, JOINT_STATE)
        assert len(js.name) == len(js.position) > 0
        assert attachment is not None and len(attachment) == 33

        client.wait_for_service("/activetouch/estop", TRIGGER)
        resp = _one(
            client.call("/activetouch/estop", TRIGGER, TRIGGER_HASH, _trigger(store)),
            client,
            store,
            f"{TRIGGER}_Response",
        )
        assert resp.success, resp.message
        assert json.loads(resp.message)["arm_stopped"] is True
    assert daemon.devices.hand.stop_latch.is_set and daemon.devices.arm.stop_latch.is_set


def test_a_legacy_request_gets_a_legacy_reply(face, store) -> None:
    _daemon, ep = face
    with RosTestClient(ep) as client:
        client.wait_for_service("/activetouch/status", TRIGGER)
        replies = client.call(
            "/activetouch/status", TRIGGER, TRIGGER_HASH, _trigger(store), legacy=True
        )
        assert len(replies) == 1
        assert replies[0].attachment.startswith(b"\x0fsequence_number")
        assert store.deserialize_cdr(replies[0].payload, f"{TRIGGER}_Response").success


def _recognize(store: Any, **kw: Any) -> bytes:
    fields = {"policy": "", "max_moves": 0, "seed": -1, "object": "", "horizon": 0,
              "simulations": 0, "session_id": ""} | kw  # fmt: skip
    req = store.types[f"{RECOGNIZE}_Request"](**fields)
    return bytes(store.serialize_cdr(req, f"{RECOGNIZE}_Request"))


def test_recognize_over_ros2_sends_contacts_and_result(face, store) -> None:
    _daemon, ep = face
    with RosTestClient(ep) as client:
        client.wait_for_service("/activetouch/recognize", RECOGNIZE)
        h = rihs01(RECOGNIZE)
        contacts = client.subscribe("/activetouch/contacts", CLOUD, rihs01(CLOUD))
        results = client.subscribe(
            "/activetouch/result",
            "activetouch_interfaces/msg/RecognitionResult",
            rihs01("activetouch_interfaces/msg/RecognitionResult"),
        )
        progress = client.subscribe(
            "/activetouch/progress",
            "activetouch_interfaces/msg/Progress",
            rihs01("activetouch_interfaces/msg/Progress"),
        )
        tf = client.subscribe("/tf", "tf2_msgs/msg/TFMessage", rihs01("tf2_msgs/msg/TFMessage"))
        tactile = client.subscribe(
            "/activetouch/tactile",
            "activetouch_interfaces/msg/Tactile",
            rihs01("activetouch_interfaces/msg/Tactile"),
        )
        req = _recognize(store, policy="random", max_moves=2, seed=0, object="cup",
                         session_id="ros-1")  # fmt: skip
        resp = _one(client.call("/activetouch/recognize", RECOGNIZE, h, req), client, store,
                    f"{RECOGNIZE}_Response")  # fmt: skip
        assert resp.success, resp.message
        r = resp.result
        assert r.success and r.session_id == "ros-1" and r.moves == 2 and len(r.labels) == 2
        assert r.seed == 0 and r.object == "cup" and r.policy == "random"
        for _ in range(2):  # one cloud per grasp, in the hand frame
            payload, _att = contacts.get(timeout=30.0)
            cloud = store.deserialize_cdr(payload, CLOUD)
            assert cloud.header.frame_id == "hand" and cloud.point_step == 16
            assert [f.name for f in cloud.fields] == ["x", "y", "z", "pressure"]
            assert len(cloud.data) == 16 * cloud.width
        payload, _att = results.get(timeout=30.0)
        published = store.deserialize_cdr(payload, "activetouch_interfaces/msg/RecognitionResult")
        assert published.session_id == "ros-1" and list(published.labels) == list(r.labels)
        with pytest.raises(queue.Empty):
            contacts.get_nowait()  # two grasps, two clouds
        for move in (1, 2):
            p = store.deserialize_cdr(progress.get(timeout=30.0)[0],
                                      "activetouch_interfaces/msg/Progress")  # fmt: skip
            assert p.session_id == "ros-1" and p.move == move and p.has_pose
            assert p.header.frame_id == "object"
            assert len(p.top_labels) == len(p.top_probabilities) <= 3
            frames = store.deserialize_cdr(tf.get(timeout=30.0)[0], "tf2_msgs/msg/TFMessage")
            pairs = [(t.header.frame_id, t.child_frame_id) for t in frames.transforms]
            assert pairs == [("base", "object"), ("object", "hand")]
            wrist = frames.transforms[1].transform.translation
            assert (wrist.x, wrist.y, wrist.z) == (p.pose.position.x, p.pose.position.y,
                                                   p.pose.position.z)  # fmt: skip
        hand = store.deserialize_cdr(tactile.get(timeout=30.0)[0],
                                     "activetouch_interfaces/msg/Tactile")  # fmt: skip
        assert len(hand.pressures) == 38 and len(hand.contact) == 38
        assert hand.header.frame_id == "hand"


def test_recognize_is_admitted_as_the_zenoh_api_admits_it(face, store) -> None:
    """The same request refused the same way over both faces (the service's own checks)."""
    _daemon, ep = face
    with RosTestClient(ep) as client:
        client.wait_for_service("/activetouch/recognize", RECOGNIZE)
        req = _recognize(store, policy="tree", max_moves=5000, seed=1, object="cup")
        resp = _one(
            client.call("/activetouch/recognize", RECOGNIZE, rihs01(RECOGNIZE), req),
            client,
            store,
            f"{RECOGNIZE}_Response",
        )
        assert not resp.success and not resp.result.success
        body = json.dumps({"v": 1, "policy": "tree", "max_moves": 5000, "seed": 1,
                           "object": "cup"})  # fmt: skip
        replies = list(
            client.session.get(f"activetouch/{FAKE_ROBOT}/recognize", payload=body, timeout=30.0)
        )
        assert len(replies) == 1 and replies[0].err is not None
        envelope = json.loads(replies[0].err.payload.to_bytes())
        assert "max_moves" in envelope["error"]
        assert resp.message == f"{envelope['error_type']}: {envelope['error']}"
        assert resp.result.error == envelope["error"]


def test_the_face_is_off_by_default(start_fake_daemon) -> None:
    daemon, ep = start_fake_daemon()
    assert daemon.ros2 is None
    with RosTestClient(ep) as client:
        assert not [t for t in client.graph(timeout=2.0) if t.node == "activetouch"]


def test_domain_and_namespace(start_fake_daemon, store) -> None:
    _daemon, ep = start_fake_daemon(["ros2.enabled=true", "ros2.domain_id=7",
                                     "ros2.namespace=/lab/cell1"])  # fmt: skip
    with RosTestClient(ep, domain=7) as client:
        tok = client.wait_for_service("/lab/cell1/activetouch/status", TRIGGER)
        assert tok.namespace == "/lab/cell1" and tok.node == "activetouch"
        names = {t.name for t in client.graph() if t.node == "activetouch" and t.kind == "MP"}
        assert {"/lab/cell1/joint_states", "/tf", "/lab/cell1/activetouch/result"} <= names
        resp = _one(
            client.call("/lab/cell1/activetouch/status", TRIGGER, TRIGGER_HASH, _trigger(store)),
            client,
            store,
            f"{TRIGGER}_Response",
        )
        assert resp.success
    with RosTestClient(ep) as other:  # domain 0 sees nothing of it
        assert not [t for t in other.graph(timeout=2.0) if t.node == "activetouch"]


def test_cancel_over_ros2_ends_the_running_recognition(start_fake_daemon, store) -> None:
    import threading

    _daemon, ep = start_fake_daemon(
        ["ros2.enabled=true", "hand.close_s=0.3", "session.stable_grasps=1000"]
    )
    h = rihs01(RECOGNIZE)
    out: dict = {}
    with RosTestClient(ep) as runner, RosTestClient(ep, node="operator") as op:
        runner.wait_for_service("/activetouch/recognize", RECOGNIZE)
        op.wait_for_service("/activetouch/cancel", TRIGGER)
        progress = op.subscribe(
            "/activetouch/progress",
            "activetouch_interfaces/msg/Progress",
            rihs01("activetouch_interfaces/msg/Progress"),
        )
        req = _recognize(store, policy="random", max_moves=50, seed=0, object="cup")

        def run() -> None:
            out["replies"] = runner.call("/activetouch/recognize", RECOGNIZE, h, req)

        t = threading.Thread(target=run)
        t.start()
        try:
            progress.get(timeout=30.0)  # it runs
            resp = _one(
                op.call("/activetouch/cancel", TRIGGER, TRIGGER_HASH, _trigger(store)),
                op,
                store,
                f"{TRIGGER}_Response",
            )
        finally:
            t.join(60.0)
        assert resp.success and json.loads(resp.message)["cancelled"] is True
        rec = _one(out["replies"], runner, store, f"{RECOGNIZE}_Response")
        assert rec.success and rec.result.stop_reason == "cancelled"
        assert rec.result.moves < 50


def test_legacy_setting_labels_the_publications(start_fake_daemon) -> None:
    _daemon, ep = start_fake_daemon(["ros2.enabled=true", "ros2.attachment=legacy"])
    with RosTestClient(ep) as client:
        client.wait_for_service("/activetouch/status", TRIGGER)
        joints = client.subscribe("/joint_states", JOINT_STATE, rihs01(JOINT_STATE))
        _payload, attachment = joints.get(timeout=30.0)
    assert attachment is not None and attachment.startswith(b"\x0fsequence_number")
    assert b"\x10source_timestamp" in attachment and b"\x0asource_gid\x10" in attachment


def test_a_hand_with_another_sensor_count_is_not_published_as_tactile(caplog, monkeypatch) -> None:
    """Tactile has the ReFlex's 38 fixed sensors: a BarrettHand's 96-cell state is skipped
    with one warning (not a failure per sample), a 38-sensor state still goes out."""
    from types import SimpleNamespace

    import numpy as np

    from activetouch.daemon import ros2_face
    from activetouch.interfaces import HandState
    from activetouch.transport.messages import encode, hand_state_to_msg

    monkeypatch.setattr(ros2_face, "_header", lambda *_a: None)
    sent: list = []
    face = SimpleNamespace(  # what _on_sample uses of a face
        types=SimpleNamespace(new=lambda _type, **fields: fields),
        rcfg=SimpleNamespace(hand_frame="hand"),
        _tactile_skipped=False,
        _publish=lambda topic, msg: sent.append((topic, msg)),
    )

    def sample(n: int) -> None:
        state = HandState(np.zeros(n), np.zeros(n, dtype=bool), np.zeros(3), 0.0, 1.0)
        ros2_face.Ros2Face._on_sample(face, "tactile", encode(hand_state_to_msg(state)))  # type: ignore[arg-type]

    for _ in range(3):
        sample(96)
    assert sent == []
    assert sum("has 96 sensors" in r.getMessage() for r in caplog.records) == 1
    sample(38)
    [(topic, msg)] = sent
    assert topic == "tactile" and len(msg["pressures"]) == 38
