"""Evaluation with the real robot's errors, and the optional Ray executor with a stand-in
for Ray (the real one: test_ray_executor.py)."""

from __future__ import annotations

import json
import sys
import types

import pytest

from activetouch.cli.main import main
from activetouch.config import load_config
from activetouch.errors import ConfigError
from activetouch.pipelines import evaluation
from activetouch.pipelines.evaluation import error_overrides, robot_errors, run_all
from activetouch.pipelines.executors import RAY_LOCAL_ONLY_ENV


def test_error_flags_become_settings():
    over = error_overrides("0.02,15", "noise=5,dead=2,stuck=1,spurious=0.02")
    cfg = load_config(None, over)
    assert robot_errors(cfg.sim) == {
        "placement_error_m": 0.02,
        "placement_error_deg": 15.0,
        "fault_noise_std": 5.0,
        "fault_dead": 2,
        "fault_stuck": 1,
        "fault_spurious": 0.02,
    }
    assert robot_errors(load_config(None, error_overrides("0.01", None)).sim) == {
        "placement_error_m": 0.01
    }
    assert error_overrides(None, None) == [] and robot_errors(load_config().sim) == {}
    over = error_overrides(None, None, "0.01", "fingers=0.05,sensors=1")
    assert robot_errors(load_config(None, over).sim) == {
        "nudge_max_m": 0.01,
        "fault_finger_offset_rad": 0.05,
        "fault_sensor_drift": 1.0,
    }


@pytest.mark.parametrize(
    ("nudge", "drift"), [("1cm", None), ("0.2", None), (None, "fingers"), (None, "zero=1")]
)
def test_bad_nudge_and_drift_flags_say_what_is_expected(nudge, drift):
    with pytest.raises(ConfigError, match="expected"):
        error_overrides(None, None, nudge, drift)


@pytest.mark.parametrize(
    ("placement", "faults"),
    [("2cm", None), ("0.02,15,3", None), ("-0.01", None), (None, "noise"), (None, "hot=1")],
)
def test_bad_error_flags_say_what_is_expected(placement, faults):
    with pytest.raises(ConfigError, match="expected"):
        error_overrides(placement, faults)


def test_ray_executor_without_ray_says_how_to_get_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    monkeypatch.delenv(RAY_LOCAL_ONLY_ENV, raising=False)
    with pytest.raises(ConfigError, match="pip install"):
        run_all([], executor="ray")
    with pytest.raises(ConfigError, match="executor"):
        run_all([], executor="dask")
    with pytest.raises(ConfigError, match="only with --executor ray"):
        run_all([], executor="local", address="auto")


def test_ray_executor_keeps_job_order(monkeypatch):
    """A stand-in for Ray that finishes tasks in reverse order: records still come back in
    job order (results.json must not depend on the executor)."""
    calls = []

    class Ref:
        def __init__(self, value):
            self.value = value

    fake = types.SimpleNamespace(
        is_initialized=lambda: False,
        init=lambda **kw: calls.append(kw),
        remote=lambda fn: types.SimpleNamespace(remote=lambda job: Ref(fn(job))),
        wait=lambda refs, num_returns: (refs[-1:], refs[:-1]),
        get=lambda ref: ref.value,
    )
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.setattr(evaluation, "run_job", lambda job: {"job": job})
    done = []
    out = run_all(
        [3, 1, 2], executor="ray", address="auto", progress=lambda i, n: done.append((i, n))
    )  # type: ignore[list-item]
    assert out == [{"job": 3}, {"job": 1}, {"job": 2}]
    assert calls[0]["address"] == "auto" and done[-1] == (3, 3)


@pytest.mark.slow  # about 6 s (recognitions, figures)
def test_eval_with_errors_records_what_each_run_had(trained_home, tmp_path):
    out = tmp_path / "r"
    args = ["eval", "--data", str(trained_home), "--out", str(out), "--workers", "1"]
    args += ["--seeds", "0-1", "--max-moves", "2", "--policies", "greedy", "--objects", "cup"]
    args += ["--set", "grid.step_deg=40", "--placement-error", "0.02,15"]
    args += ["--sensor-faults", "dead=3,stuck=1"]
    assert main(args) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["summary"]["robot_errors"]["placement_error_deg"] == 15.0
    r0, r1 = doc["runs"]
    assert len(r0["errors"]["dead_sensors"]) == 3 and len(r0["errors"]["stuck_sensors"]) == 1
    assert abs(r0["errors"]["placement_dx_m"]) <= 0.02
    assert r0["errors"]["placement_dx_m"] != r1["errors"]["placement_dx_m"]  # per seed
    assert "real robot's errors" in (out / "report.md").read_text()
