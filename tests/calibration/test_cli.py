"""`activetouch calibrate`: the independent check of issue 14 (a separate packet source with
known offsets + noise, the real driver, the CLI, the stored file) and `calibrate show`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from activetouch.cli.main import main

from .board import NoisyBoard


def test_cli_tactile_independent_check(tmp_path, capsys):
    rng = np.random.default_rng(21)
    offsets = rng.uniform(100.0, 4000.0, 38)
    with NoisyBoard(offsets, noise=2.0, seed=4) as board:
        rc = main(
            [
                "calibrate",
                "tactile",
                "--no-open",
                "--device",
                "reflex-A1",
                "--duration",
                "2",
                "--data",
                str(tmp_path),
                "--set",
                "hand.type=reflex-takktile",
                "--set",
                f"hand.state_listen=127.0.0.1:{board.state_port}",
                "--set",
                f"hand.command_to=127.0.0.1:{board.command_port}",
                "--set",
                "hand.multicast_group=",
            ]
        )
    assert rc == 0
    path = tmp_path / "calibration" / "reflex-A1" / "tactile.json"
    rec = json.loads(path.read_text())
    assert rec["schema"] == "activetouch.calibration" and rec["version"] == 1
    zero = np.asarray(rec["values"]["zero"])
    assert len(zero) == 38 and len(rec["values"]["threshold"]) == 38
    assert np.max(np.abs(zero - offsets)) < 1.0
    capsys.readouterr()
    assert main(["calibrate", "show", "tactile", "--json", "--data", str(tmp_path)]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown[0]["values"]["zero"] == rec["values"]["zero"]
    assert main(["calibrate", "show", "--data", str(tmp_path)]) == 0
    assert "tactile reflex-A1" in capsys.readouterr().out
    _check_tactile_recording(tmp_path, rec, capsys)


def _check_tactile_recording(root, stored, capsys):
    """The procedure left an MCAP recording: read with the `mcap` library (not ours), every
    new hand state is there, and its result is the record that was stored."""
    from mcap.reader import make_reader

    (path,) = sorted((root / "recordings").glob("*.mcap"))
    assert "calibrate-tactile-reflex-A1" in path.name
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: c for c in summary.channels.values()}
        counts = summary.statistics.channel_message_counts
        by_topic = {summary.channels[i].topic: n for i, n in counts.items()}
        messages = {
            ch.topic: json.loads(m.data)
            for _, ch, m in reader.iter_messages(
                topics=["/activetouch/result", "/activetouch/request"]
            )
        }
    assert topics["/joint_states"].message_encoding == "cdr"
    assert summary.schemas[topics["/joint_states"].schema_id].name == "sensor_msgs/msg/JointState"
    assert summary.schemas[topics["/activetouch/hand_state"].schema_id].encoding == "jsonschema"
    n = stored["quality"]["n_samples"]
    assert by_topic["/activetouch/hand_state"] >= n  # the samples, and the checks around them
    assert by_topic["/joint_states"] == by_topic["/activetouch/hand_state"]
    req = messages["/activetouch/request"]
    assert req["kind"] == "calibration" and req["procedure"] == "tactile"
    assert req["device"] == "reflex-A1" and req["settings"]["duration"] == 2
    res = messages["/activetouch/result"]
    assert res["stored"] is True and res["record"]["values"] == stored["values"]
    capsys.readouterr()
    assert main(["recordings", "list", "--json", "--data", str(root)]) == 0
    (row,) = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert row["kind"] == "calibration" and row["object"] == "calibrate tactile"
    assert main(["recordings", "show", path.stem, "--data", str(root)]) == 0
    out = capsys.readouterr().out
    assert "calibrate tactile" in out and "stored" in out and "hand states:" in out
    assert main(["replay", str(path), "--data", str(root)]) == 2
    err = capsys.readouterr().err
    assert "replay re-runs recognitions" in err and len(err.strip().splitlines()) == 1


def test_cli_object_needs_a_name_in_one_line(tmp_path, capsys):
    assert main(["calibrate", "object", "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--object NAME" in err and len(err.strip().splitlines()) == 1
    # The refused procedure's recording says why it ended.
    from activetouch.recordings.reader import read_recording

    (path,) = (tmp_path / "recordings").glob("*.mcap")
    assert "--object NAME" in read_recording(path).result["error"]
    assert main(["calibrate", "object", "--no-record", "--data", str(tmp_path)]) == 2
    assert len(list((tmp_path / "recordings").glob("*.mcap"))) == 1


@pytest.mark.slow
def test_cli_object_on_the_twin_finds_the_injected_displacement(tmp_path, capsys):
    """`calibrate object --inject-object 21,-17`: the twin stands the mug 21 mm, -17 mm off the
    workcell's place; the stored record says where it is (within 2 mm; spec 5 mm)."""
    args = ["calibrate", "object", "--object", "mug", "--inject-object", "21,-17"]
    assert main([*args, "--data", str(tmp_path), "--json"]) == 0
    out = capsys.readouterr().out
    rec, _ = json.JSONDecoder().raw_decode(out[out.index("{") :])
    assert rec["kind"] == "object" and rec["values"]["object"] == "mug"
    x, y = rec["values"]["xyz"][:2]
    assert np.hypot(x - 0.021, y + 0.017) < 0.002, (x, y)
    from activetouch.recordings.reader import read_recording

    (path,) = (tmp_path / "recordings").glob("*.mcap")
    got = read_recording(path)
    assert got.complete and got.kind == "calibration" and got.request["procedure"] == "object"
    goals = got.decoded("/activetouch/wrist_goal")
    reached = got.decoded("/tf")
    assert len(goals) == len(reached) > 2 * rec["quality"]["n_touches"]  # down and back, each
    assert goals[0].header.frame_id == "world"
    g, r = goals[-1].pose.position, reached[-1].transforms[0].transform.translation
    assert np.allclose([g.x, g.y, g.z], [r.x, r.y, r.z], atol=2e-3)  # each goal was reached
    assert got.result["record"]["values"] == rec["values"]
    assert main(["calibrate", "show", "object", "--data", str(tmp_path)]) == 0
    assert "object workcell" in capsys.readouterr().out
