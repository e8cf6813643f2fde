"""`python -m activetouch bench motion --json FILE`: the figures issue 11 names, on a small run."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("pinocchio")

KEYS = (
    "ik_success_rate",
    "ik_ms_median",
    "ik_ms_p95",
    "collision_us_median",
    "ruckig_us_median",
    "plan_ms_median",
    "plan_ms_p95",
    "colliding_executions",
)


@pytest.mark.slow
def test_bench_motion_writes_the_issue_figures(tmp_path, capsys) -> None:
    from activetouch.cli.main import main

    out = tmp_path / "motion.json"
    argv = ["bench", "motion", "--targets", "20", "--moves", "6", "--objects", "cup"]
    assert main([*argv, "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert all(k in doc for k in KEYS), sorted(set(KEYS) - set(doc))
    assert doc["ik_success_rate"] >= 0.9 and doc["colliding_executions"] == 0
    assert doc["moves"] >= 1 and doc["grid_reachable"]["cup"] > 0
    # The planner's travel-time estimate is exact for straight moves, a lower bound otherwise.
    assert doc["travel_estimate_ratio_median"] >= 0.999
    assert json.loads(capsys.readouterr().out) == doc  # printed as written
    assert main(["bench", "motion", "--objects", "nothing"]) == 2
    assert "not builtin objects" in capsys.readouterr().err
