"""The daemon's ROS 2 face seen by zenoh-ros2-sdk (PyPI; ROBOTIS-GIT/zenoh_ros2_sdk), a second,
third-party implementation of rmw_zenoh's protocol (a dev dependency; skipped where it is
missing). Every definition and hash is passed explicitly, so it fetches nothing; its session
connects to the fake daemon's loopback endpoint with scouting off and listens nowhere."""

from __future__ import annotations

import json
import queue
from typing import Any

import pytest

from tests.conftest import FAKE_ROBOT
from tests.ros2.client import TRIGGER_HASH
from tests.ros2.hashes import PACKAGE_DIR, rihs01

sdk = pytest.importorskip("zenoh_ros2_sdk")

TIME = "int32 sec\nuint32 nanosec\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
JOINT_STATE = (
    "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
    "float64[] effort\n"
)


@pytest.fixture
def sdk_session(start_fake_daemon, monkeypatch: pytest.MonkeyPatch) -> Any:
    daemon, ep = start_fake_daemon(["ros2.enabled=true"])
    monkeypatch.setenv(
        "ZENOH_CONFIG_OVERRIDE",
        "scouting/multicast/enabled=false;scouting/gossip/enabled=false;listen/endpoints=[]",
    )
    monkeypatch.delenv("ZENOH_SESSION_CONFIG_URI", raising=False)
    port = int(ep.rsplit(":", 1)[1])
    mgr = sdk.ZenohSession.get_instance("127.0.0.1", port)
    for definition, name in (
        (TIME, "builtin_interfaces/msg/Time"),
        (HEADER, "std_msgs/msg/Header"),
    ):
        mgr.register_message_type(definition, name)
    yield daemon, port
    mgr.close()


def test_zenoh_ros2_sdk_calls_status_and_recognize(sdk_session) -> None:
    _daemon, port = sdk_session
    status = sdk.ROS2ServiceClient(
        "/activetouch/status",
        "std_srvs/srv/Trigger",
        request_definition="",
        response_definition="bool success\nstring message\n",
        router_port=port,
        type_hash=TRIGGER_HASH,
        timeout=30.0,
    )
    try:
        resp = status.call()
    finally:
        status.close()
    assert resp is not None and resp.success
    assert json.loads(resp.message)["robot"] == FAKE_ROBOT

    srv = (PACKAGE_DIR / "srv" / "Recognize.srv").read_text()
    request_def, response_def = srv.split("\n---\n")
    result_def = (PACKAGE_DIR / "msg" / "RecognitionResult.msg").read_text()
    mgr = sdk.ZenohSession.get_instance("127.0.0.1", port)
    mgr.register_message_type(result_def, "activetouch_interfaces/msg/RecognitionResult")
    recognize = sdk.ROS2ServiceClient(
        "/activetouch/recognize",
        "activetouch_interfaces/srv/Recognize",
        request_definition=request_def,
        response_definition=response_def.replace(
            "RecognitionResult result", "activetouch_interfaces/RecognitionResult result"
        ),
        router_port=port,
        type_hash=rihs01("activetouch_interfaces/srv/Recognize"),
        timeout=60.0,
    )
    try:
        resp = recognize.call(
            policy="random", max_moves=2, seed=3, object="cup", horizon=0, simulations=0,
            session_id="sdk-1",
        )  # fmt: skip
    finally:
        recognize.close()
    assert resp is not None and resp.success, resp
    assert resp.result.session_id == "sdk-1" and resp.result.moves == 2


def test_zenoh_ros2_sdk_receives_joint_states(sdk_session) -> None:
    _daemon, port = sdk_session
    got: queue.SimpleQueue = queue.SimpleQueue()
    sub = sdk.ROS2Subscriber(
        "/joint_states",
        "sensor_msgs/msg/JointState",
        got.put,
        msg_definition=JOINT_STATE,
        router_port=port,
        type_hash=rihs01("sensor_msgs/msg/JointState"),
    )
    try:
        msg = got.get(timeout=30.0)
    finally:
        sub.close()
    assert len(msg.name) == len(msg.position) > 0
