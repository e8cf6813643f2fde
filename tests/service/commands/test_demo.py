from __future__ import annotations

import json

from activetouch.cli.main import main


def test_demo_recognises_through_the_daemon_and_writes_the_report(trained_home, tmp_path, capsys):
    out = tmp_path / "report"
    rc = main(
        [
            "demo",
            "--data",
            str(trained_home),
            "--object",
            "cup",
            "--seeds",
            "0",
            "--out",
            str(out),
            "--set",
            "grid.step_deg=40",
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "through the daemon" in text and "recognised:" in text
    doc = json.loads((out / "results.json").read_text())
    assert {r["policy"] for r in doc["runs"]} == {"tree", "greedy", "random"}
    assert (out / "report.md").is_file() and (out / "distance_vs_moves.png").is_file()


def test_demo_unknown_object_is_a_one_line_error(trained_home, capsys):
    assert main(["demo", "--data", str(trained_home), "--object", "unicorn"]) == 2
    err = capsys.readouterr().err
    assert "unicorn" in err and "Traceback" not in err
