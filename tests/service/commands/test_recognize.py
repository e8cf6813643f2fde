from __future__ import annotations

import json

from activetouch.cli.main import main


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


def test_more_user_mistakes_fail_before_any_work(trained_home, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("")
    assert main(["recognize", "--object", "cup", "--data", str(trained_home), "--seed", "-1"]) == 2
    assert main(["eval", "--data", str(trained_home), "--seeds", "0", "--out", str(afile)]) == 2
    assert (
        main(
            [
                "eval",
                "--data",
                str(trained_home),
                "--objects",
                "nosuch",
                "--out",
                str(tmp_path / "r"),
            ]
        )
        == 2
    )
    assert (
        main(
            [
                "objects",
                "render",
                "cup",
                "--data",
                str(trained_home),
                "--dataset",
                "nosuch",
                "--out",
                str(tmp_path / "png"),
            ]
        )
        == 2
    )
    assert main(["train", "--data", str(afile)]) == 2  # an OSError, as one line
    assert (
        main(
            [
                "recognize",
                "--object",
                "cup",
                "--data",
                str(trained_home),
                "--set",
                "recognition.classifier=bogus",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "Traceback" not in err
    for text in (
        "seed must be >= 0",
        "not a directory",
        "nosuch",
        "no dataset 'nosuch'",
        "recognition.classifier",
    ):
        assert text in err, text
    assert not (tmp_path / "r").exists()  # nothing was run or written


def test_an_object_outside_the_model_is_announced(trained_home, capsys):
    assert (
        main(["recognize", "--object", "teapot", "--data", str(trained_home), "--max-moves", "1"])
        == 0
    )
    assert "is not one of the model's classes" in capsys.readouterr().out


def test_recognize_reports_robot_time(trained_home, capsys):
    """--json carries the robot time (moving, grasping, motion planning, total); the plain
    summary prints it. The floating twin rules nothing out (it has no reachable())."""
    args = ["recognize", "--object", "cup", "--data", str(trained_home), "--max-moves", "3"]
    args += ["--set", "grid.step_deg=40"]
    assert main([*args, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["motion_s"] > 0 and doc["grasp_s"] > 0 and doc["motion_planning_s"] == 0.0
    assert doc["unreachable"] == 0 and doc["reachability_s"] == 0.0
    parts = doc["motion_s"] + doc["grasp_s"] + doc["planning_s"] + doc["motion_planning_s"]
    assert abs(doc["total_s"] - parts) < 1e-9
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "robot time:" in out and f"moving {doc['motion_s']:.1f} s" in out
    assert "robot " in out.split("recognised:")[0]  # progress lines: robot seconds so far
