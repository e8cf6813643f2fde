"""`activetouch serve --sim` (the PyBullet twin, a subprocess) with the ROS 2 face on, seen by the
test's own ROS 2 client: status, and a recognition over ROS 2 that gives the same grasps and
answers as the same request over the Zenoh API (a seeded recognition is deterministic), with
/joint_states and the contacts received while it runs. Loopback, scouting off; the daemon is
stopped by its pid."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from activetouch.daemon.client import open_client
from activetouch.transport.messages import RecognizeRequest
from activetouch.transport.zenoh_session import free_tcp_port
from tests.ros2.client import TRIGGER_HASH, RosTestClient
from tests.ros2.hashes import rihs01
from tests.ros2.test_face import RECOGNIZE, TRIGGER, _one, _recognize, _trigger
from tests.service.test_daemon import ROBOT, DaemonProcess, serve_args, wait_ready

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def twin_daemon(
    trained_home: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[DaemonProcess, str]]:
    port = free_tcp_port()
    d = DaemonProcess(
        serve_args(trained_home, port, "--set", "ros2.enabled=true"),
        tmp_path_factory.mktemp("ros2-twin") / "daemon.log",
    )
    try:
        wait_ready(d, f"tcp/127.0.0.1:{port}")
        yield d, f"tcp/127.0.0.1:{port}"
        assert d.stop() == 0, d.text()
    finally:
        d.kill()


def test_status_and_recognize_on_the_twin(twin_daemon, store) -> None:
    d, ep = twin_daemon
    with RosTestClient(ep) as client:
        client.wait_for_service("/activetouch/status", TRIGGER)
        resp = _one(
            client.call("/activetouch/status", TRIGGER, TRIGGER_HASH, _trigger(store)),
            client,
            store,
            f"{TRIGGER}_Response",
        )
        assert resp.success, resp.message
        status = json.loads(resp.message)
        assert status["robot"] == ROBOT and status["mode"] == "sim" and status["model_loaded"]

        joints = client.subscribe(
            "/joint_states", "sensor_msgs/msg/JointState", rihs01("sensor_msgs/msg/JointState")
        )
        cloud_type = "sensor_msgs/msg/PointCloud2"
        contacts = client.subscribe("/activetouch/contacts", cloud_type, rihs01(cloud_type))
        client.wait_for_service("/activetouch/recognize", RECOGNIZE)
        req = _recognize(store, policy="tree", max_moves=4, seed=7, object="cup")
        rec = _one(
            client.call("/activetouch/recognize", RECOGNIZE, rihs01(RECOGNIZE), req),
            client,
            store,
            f"{RECOGNIZE}_Response",
        )
        assert rec.success, rec.message
        r = rec.result
        js = store.deserialize_cdr(joints.get(timeout=30.0)[0], "sensor_msgs/msg/JointState")
        assert len(js.name) == len(js.position) > 0
        for _ in range(r.moves):
            cloud = store.deserialize_cdr(contacts.get(timeout=30.0)[0], cloud_type)
            assert cloud.header.frame_id == "hand" and len(cloud.data) == 16 * cloud.width
    with open_client([ep], ROBOT, timeout=10.0) as zc:
        same = zc.recognize(
            RecognizeRequest(policy="tree", max_moves=4, seed=7, object="cup"), timeout=120.0
        )
    assert list(r.labels) == same.labels and list(r.pose_ids) == same.pose_ids
    assert r.label == same.label and r.probability == pytest.approx(same.probability)
    assert r.stop_reason == same.stop_reason and r.moves == same.moves
    assert d.running(), d.text()
