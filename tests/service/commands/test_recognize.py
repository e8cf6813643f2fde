from __future__ import annotations

import json

from activetouch.service.cli import main


def test_recognize_json_prints_one_object(trained_home, capsys):
    rc = main(
        [
            "recognize",
            "--object",
            "bottle",
            "--data",
            str(trained_home),
            "--json",
            "--max-moves",
            "4",
            "--seed",
            "1",
            "--set",
            "grid.step_deg=40",
        ]
    )
    assert rc == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)  # stdout is only the JSON object; progress went to stderr
    assert doc["object"] == "bottle" and doc["policy"] == "tree" and doc["seed"] == 1
    assert 1 <= doc["moves"] == len(doc["labels"]) <= 4
    assert doc["label"] == doc["labels"][-1]
    assert doc["correct"] == (doc["label"] == "bottle")
    assert "move  1" in out.err


def test_recognize_progress_and_answer_in_plain_text(trained_home, capsys):
    rc = main(
        [
            "recognize",
            "--object",
            "sphere",
            "--policy",
            "random",
            "--data",
            str(trained_home),
            "--max-moves",
            "3",
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "move  1" in out and "recognised:" in out


def test_recognize_user_mistakes_are_one_line(trained_home, tmp_path, capsys):
    assert main(["recognize", "--object", "unicorn", "--data", str(trained_home)]) == 2
    assert (
        main(["recognize", "--object", "cup", "--data", str(trained_home), "--policy", "psychic"])
        == 2
    )
    assert (
        main(["recognize", "--object", "cup", "--data", str(trained_home), "--max-moves", "-1"])
        == 2
    )
    assert main(["recognize", "--object", "cup", "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "unicorn" in err and "psychic" in err and "no model" in err
