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


def test_cli_object_needs_a_name_in_one_line(tmp_path, capsys):
    assert main(["calibrate", "object", "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--object NAME" in err and len(err.strip().splitlines()) == 1


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
    assert main(["calibrate", "show", "object", "--data", str(tmp_path)]) == 0
    assert "object workcell" in capsys.readouterr().out
