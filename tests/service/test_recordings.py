"""Every recognition recorded as MCAP (issue 25): a twin recognition leaves a file that the
`mcap` reader opens with the expected channels and schemas, each ROS 2 message deserialises
with rosbags back to the recorded values, `replay` gives the recorded labels, a file cut short
is still read, the limits delete the oldest, and `--no-record` writes nothing."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from activetouch import paths
from activetouch.cli.main import main
from activetouch.config import RecordingConfig, load_config
from activetouch.daemon.client import open_client
from activetouch.errors import ConfigError, DataError
from activetouch.model import load_model
from activetouch.recordings import format as fmt
from activetouch.recordings.reader import read_recording
from activetouch.recordings.store import list_recordings, prune, recording_name
from activetouch.session.replay import replay
from activetouch.transport.messages import RecognizeRequest
from tests.loopback import loopback_endpoint

ROS_SCHEMAS = {
    "/joint_states": "sensor_msgs/msg/JointState",
    "/activetouch/contacts": "sensor_msgs/msg/PointCloud2",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/activetouch/wrist_goal": "geometry_msgs/msg/PoseStamped",
}
JSON_CHANNELS = {
    "/activetouch/request",
    "/activetouch/grasp",
    "/activetouch/belief",
    "/activetouch/plan",
    "/activetouch/robot_time",
    "/activetouch/error",
    "/activetouch/result",
}


@pytest.fixture
def home(trained_home: Path, tmp_path: Path) -> Path:
    """A data directory of its own (its recordings/ is this test's) with the small model."""
    root = tmp_path / "home"
    root.mkdir()
    for name in ("objects", "models", "datasets"):
        (root / name).symlink_to(trained_home / name)
    return root


def _recognize(home: Path, *extra: str) -> None:
    args = ["recognize", "--object", "cup", "--data", str(home), "--json", "--seed", "3"]
    assert main([*args, "--max-moves", "5", "--set", "grid.step_deg=40", *extra]) == 0


def _only_recording(home: Path) -> Path:
    recs = list_recordings(home)
    assert len(recs) == 1, recs
    return recs[0].path


def test_a_twin_recognition_is_recorded_with_ros2_and_json_channels(home: Path, capsys) -> None:
    _recognize(home)
    doc = json.loads(capsys.readouterr().out)
    path = _only_recording(home)
    assert path.parent == paths.recordings_dir(home)

    # The mcap library's own (seeking) reader: summary, schemas, channels, counts.
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None and header.profile == "ros2"
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == set(ROS_SCHEMAS) | JSON_CHANNELS
        for topic, typename in ROS_SCHEMAS.items():
            schema = summary.schemas[topics[topic].schema_id]
            assert (schema.name, schema.encoding, topics[topic].message_encoding) == (
                typename,
                "ros2msg",
                "cdr",
            )
            assert schema.data == fmt.ros_schema(typename)
        for topic in JSON_CHANNELS:
            schema = summary.schemas[topics[topic].schema_id]
            assert schema.encoding == "jsonschema" and topics[topic].message_encoding == "json"
            assert json.loads(schema.data)["type"] == "object"
        counts = {
            c.topic: summary.statistics.channel_message_counts.get(cid, 0)
            for cid, c in summary.channels.items()
        }
        n = doc["moves"]
        assert counts["/activetouch/grasp"] == counts["/activetouch/belief"] == n
        assert counts["/activetouch/contacts"] == counts["/joint_states"] == n
        assert counts["/tf"] == n  # object -> hand per grasp
        assert counts["/tf_static"] == 1  # world -> object
        assert counts["/activetouch/request"] == counts["/activetouch/result"] == 1
        assert counts["/activetouch/wrist_goal"] == n + doc["skipped"]
        assert counts["/activetouch/plan"] >= n - 1
        json_msgs = {
            (c.topic, json.loads(m.data)["v"])
            for _, c, m in reader.iter_messages(topics=["/activetouch/result"])
        }
        assert json_msgs == {("/activetouch/result", 1)}

    rec = read_recording(path)
    assert rec.complete and rec.labels == doc["labels"] and rec.result["label"] == doc["label"]
    assert [g["pose_id"] for g in rec.grasps] == doc["pose_ids"]
    assert rec.request["object"] == "cup" and rec.request["seed"] == 3

    # Every ROS 2 message back through rosbags, equal to the JSON grasp it came with.
    clouds = rec.decoded(fmt.CONTACTS)
    joints = rec.decoded(fmt.JOINT_STATES)
    tfs = rec.decoded(fmt.TF_STATIC) + rec.decoded(fmt.TF)
    goals = rec.decoded(fmt.WRIST_GOAL)
    assert tfs[0].transforms[0].header.frame_id == "world"
    assert tfs[0].transforms[0].child_frame_id == "object"
    place = tfs[0].transforms[0].transform.translation
    assert np.isfinite([place.x, place.y, place.z]).all()
    for g, cloud, js, tf in zip(rec.grasps, clouds, joints, tfs[1:], strict=True):
        assert cloud.header.frame_id == "hand" and cloud.width == len(g["sensor_ids"])
        assert [f.name for f in cloud.fields] == ["x", "y", "z", "pressure", "sensor_id"]
        pts = np.frombuffer(cloud.data.tobytes(), dtype=fmt.POINT_DTYPE)
        xyz = np.asarray(g["xyz"]).reshape(-1, 3)
        assert np.allclose(np.stack([pts["x"], pts["y"], pts["z"]], axis=1), xyz, atol=1e-6)
        assert np.allclose(pts["pressure"], g["pressures"], rtol=1e-6)
        assert pts["sensor_id"].tolist() == g["sensor_ids"]
        assert list(js.name) == list(fmt.HAND_JOINTS)
        assert np.allclose(js.position, [g["preshape"], *g["finger_angles"]])
        (t,) = tf.transforms
        assert (t.header.frame_id, t.child_frame_id) == ("object", "hand")
        tr, q = t.transform.translation, t.transform.rotation
        assert np.allclose([tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w], g["pose"])
        assert js.header.stamp.sec > 0
    grasped = {tuple(np.round(g["pose"], 12)) for g in rec.grasps}
    goal_poses = {
        tuple(
            np.round(
                [
                    p.pose.position.x,
                    p.pose.position.y,
                    p.pose.position.z,
                    p.pose.orientation.x,
                    p.pose.orientation.y,
                    p.pose.orientation.z,
                    p.pose.orientation.w,
                ],
                12,
            )
        )
        for p in goals
    }
    assert all(p.header.frame_id == "object" for p in goals)
    assert grasped <= goal_poses
    # Each grasp's wrist pose in the object frame is a unit quaternion pose.
    assert all(np.isclose(np.linalg.norm(g["pose"][3:]), 1.0) for g in rec.grasps)
    Rotation.from_quat([g["pose"][3:] for g in rec.grasps])

    # Replay: the same labels and probabilities, in code and on the command line.
    out = replay(rec, load_model(paths.default_model(home)))
    assert out.same_labels and out.labels == doc["labels"]
    assert out.max_abs_diff == 0.0
    assert main(["replay", str(path), "--data", str(home), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["same_labels"] and rep["labels"] == doc["labels"]

    # list and show
    assert main(["recordings", "list", "--data", str(home)]) == 0
    text = capsys.readouterr().out
    assert path.stem[:16] in text and "cup" in text and "KiB" in text
    assert main(["recordings", "list", "--data", str(home), "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    assert (row["object"], row["label"], row["grasps"]) == ("cup", doc["label"], doc["moves"])
    assert row["size"] == path.stat().st_size
    assert main(["recordings", "show", path.stem, "--data", str(home)]) == 0
    text = capsys.readouterr().out
    assert "grasp  1" in text and "result:" in text and "sensor_msgs/msg/PointCloud2" in text


def test_replay_equals_on_the_grasp_likelihood_belief(home: Path, capsys) -> None:
    _recognize(home, "--set", "recognition.belief=grasp_likelihood", "--policy", "greedy")
    doc = json.loads(capsys.readouterr().out)
    rec = read_recording(_only_recording(home))
    assert rec.request["recognition"]["belief"] == "grasp_likelihood"
    out = replay(rec, load_model(paths.default_model(home)))
    assert out.labels == rec.labels == doc["labels"] and out.max_abs_diff == 0.0


def test_a_recording_cut_short_keeps_every_finished_grasp(home: Path, capsys) -> None:
    _recognize(home)
    path = _only_recording(home)
    full = read_recording(path)
    data = path.read_bytes()
    # Where the writer was after its second grasp: the end of that grasp's chunk.
    cut = tmp = path.with_name("cut.mcap")
    for size in range(len(data) - 1, 0, -97):
        tmp.write_bytes(data[:size])
        try:
            part = read_recording(tmp)
        except DataError:
            break
        if len(part.grasps) < len(full.grasps):
            break
    part = read_recording(cut)
    assert not part.complete and part.result is None
    assert 0 < len(part.grasps) < len(full.grasps)
    assert part.labels == full.labels[: len(part.labels)]
    out = replay(part, load_model(paths.default_model(home)))
    assert out.same_labels
    tmp.write_bytes(b"not an mcap file")
    with pytest.raises(DataError, match="not a readable MCAP recording"):
        read_recording(tmp)
    assert main(["replay", str(tmp), "--data", str(home)]) == 2
    assert "not a readable MCAP" in capsys.readouterr().err


def test_no_record_and_recording_enabled_off_write_nothing(home: Path, capsys) -> None:
    _recognize(home, "--no-record")
    _recognize(home, "--set", "recording.enabled=false")
    assert list_recordings(home) == []
    assert not paths.recordings_dir(home).exists() or not any(paths.recordings_dir(home).iterdir())


def test_the_daemon_records_and_honours_record_false(home: Path) -> None:
    from activetouch.cli.commands.serve import resolve_mode
    from activetouch.daemon.process import Daemon, DaemonOptions

    ep = loopback_endpoint()
    cfg = load_config(
        None,
        ["hand.type=fake", "arm.type=fake", "service.robot=recbot", f'service.listen=["{ep}"]'],
    )
    daemon = Daemon(
        DaemonOptions(
            mode=resolve_mode(None, cfg),
            role="all",
            data=home,
            model_dir=paths.default_model(home),
            cfg=cfg,
        )
    )
    try:
        daemon.start()
        with open_client([ep], "recbot", timeout=10.0) as client:
            res = client.recognize(
                RecognizeRequest(
                    policy="tree", max_moves=4, seed=2, object="bottle", session_id="rec-1"
                ),
                timeout=120.0,
            )
            client.recognize(
                RecognizeRequest(policy="tree", max_moves=2, seed=2, object="cup", record=False),
                timeout=120.0,
            )
        cli = ["recognize", "--connect", ep, "--robot", "recbot", "--object", "sphere"]
        assert main([*cli, "--max-moves", "2", "--no-record", "--data", str(home)]) == 0
    finally:
        daemon.close()
    path = _only_recording(home)
    assert path.name.endswith("-rec-1.mcap")
    rec = read_recording(path)
    assert rec.complete and rec.labels == res.labels
    assert rec.result["session_id"] == "rec-1" and rec.result["pose_ids"] == res.pose_ids
    assert rec.request["source"].startswith("daemon recbot")
    assert replay(rec, load_model(paths.default_model(home))).labels == res.labels


def test_the_limits_delete_the_oldest(tmp_path: Path) -> None:
    d = paths.recordings_dir(tmp_path)
    d.mkdir(parents=True)
    day = 86400.0
    now = 1_800_000_000.0
    made = []
    for i in range(5):  # 1 MB each, one day apart, oldest first
        started = now - (5 - i) * day
        p = d / recording_name(f"s{i}", started)
        p.write_bytes(b"\0" * 1_000_000)
        os.utime(p, (started, started))
        made.append(p)
    assert [r.path for r in list_recordings(tmp_path)] == made
    # Age: older than 3.5 days goes (the first two).
    gone = prune(tmp_path, RecordingConfig(max_total_mb=0, max_age_days=3.5), now=now)
    assert gone == made[:2]
    # Size: at most 2 MB, the oldest go first, the one being written is kept.
    gone = prune(tmp_path, RecordingConfig(max_total_mb=2.0, max_age_days=0), now=now)
    assert gone == made[2:3]
    assert [r.path for r in list_recordings(tmp_path)] == made[3:]
    gone = prune(tmp_path, RecordingConfig(max_total_mb=0.5, max_age_days=0), keep=made[3])
    assert gone == made[4:] and made[3].exists()
    with pytest.raises(ConfigError, match=r"recording\.max_total_mb must be >= 0"):
        prune(tmp_path, RecordingConfig(max_total_mb=-1))


def test_a_recognition_applies_the_limits(home: Path, capsys) -> None:
    d = paths.recordings_dir(home)
    d.mkdir()
    old = d / recording_name("old", 1_000_000_000.0)
    old.write_bytes(b"\0" * 100)
    os.utime(old, (1_000_000_000.0, 1_000_000_000.0))  # 2001: beyond any age limit
    _recognize(home, "--set", "recording.max_age_days=30")
    (kept,) = list_recordings(home)
    assert not old.exists() and kept.path.stat().st_size > 0
    shutil.rmtree(d)
    assert main(["recordings", "show", "nothing-here", "--data", str(home)]) == 2
    assert "no recording 'nothing-here'" in capsys.readouterr().err


def test_bad_limits_are_refused_when_the_config_loads() -> None:
    with pytest.raises(ConfigError, match=r"recording\.max_age_days must be >= 0"):
        load_config(None, ["recording.max_age_days=-2"])
    assert load_config(None).recording == RecordingConfig(True, 1000.0, 30.0)


def test_a_daemon_killed_mid_recognition_leaves_its_finished_grasps(
    home: Path, tmp_path: Path
) -> None:
    """SIGKILL (no goodbye) after the second grasp's progress: the recording, without footer,
    still holds at least those two grasps, and they replay to their recorded labels."""
    import threading

    from activetouch.transport.zenoh_session import free_tcp_port
    from tests.service.test_daemon import ROBOT, DaemonProcess, serve_args, wait_ready

    port = free_tcp_port()
    d = DaemonProcess(
        [
            *serve_args(home, port),
            "--set",
            "service.sim_motion_delay_s=0.2",
            "--set",
            "session.stable_grasps=100",
        ],
        tmp_path / "daemon.log",
    )
    endpoint = f"tcp/127.0.0.1:{port}"
    second = threading.Event()
    try:
        wait_ready(d, endpoint)
        with open_client([endpoint], ROBOT, timeout=10.0) as c:
            req = RecognizeRequest(
                policy="tree", max_moves=40, seed=4, object="sphere", session_id="killed"
            )

            def on_progress(p) -> None:
                if p.move >= 2:
                    second.set()

            out: dict = {}

            def run() -> None:
                try:
                    c.recognize(req, on_progress, timeout=120.0)
                except Exception as e:
                    out["error"] = e

            t = threading.Thread(target=run, daemon=True)
            t.start()
            assert second.wait(60.0), d.text()
            d.kill()  # SIGKILL by its pid
            t.join(30.0)
            assert "error" in out
    finally:
        d.kill()
    path = _only_recording(home)
    assert path.name.endswith("-killed.mcap")
    rec = read_recording(path)
    assert not rec.complete and rec.result is None
    assert len(rec.grasps) >= 2
    out2 = replay(rec, load_model(paths.default_model(home)))
    assert out2.same_labels and out2.max_abs_diff == 0.0
