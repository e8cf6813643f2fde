"""`activetouch calibrate`: the independent check of issue 14 (a separate packet source with
known offsets + noise, the real driver, the CLI, the stored file) and `calibrate show`."""

from __future__ import annotations

import json

import numpy as np

from activetouch.service.cli import main

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


def test_cli_object_not_implemented_is_one_line(tmp_path, capsys):
    assert main(["calibrate", "object", "--data", str(tmp_path)]) == 2
    assert "not implemented" in capsys.readouterr().err
