from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from activetouch import paths
from activetouch.cli.main import main
from activetouch.errors import ConfigError
from activetouch.pipelines.evaluation import (
    bootstrap_ci,
    first_correct,
    first_stable_correct,
    parse_seeds,
    sign_test_p,
    summarise,
)


def test_parse_seeds():
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("5,1, 2") == [1, 2, 5]
    assert parse_seeds("0-1,7") == [0, 1, 7]
    for bad in ("", "a-b", "3-1", "x"):
        with pytest.raises(ConfigError):
            parse_seeds(bad)


def test_moves_until_correct():
    labels = ["mug", "cup", "cup", "mug", "cup", "cup", "cup"]
    assert first_correct(labels, "cup") == 2
    assert first_stable_correct(labels, "cup") == 7
    assert first_correct(labels, "bowl") is None
    assert first_stable_correct(["cup", "cup"], "cup") is None


def _run(obj, policy, seed, first, final):
    return {
        "object": obj,
        "policy": policy,
        "seed": seed,
        "moves_to_first_correct": first,
        "moves_to_stable_correct": None,
        "final_correct": final,
        "moves": 5,
        "planning_s": 0.1,
    }


def test_summary_pairs_runs_by_seed():
    runs = [
        _run("cup", "tree", 0, 2, True),
        _run("cup", "random", 0, 4, True),
        _run("cup", "tree", 1, None, False),
        _run("cup", "random", 1, 3, False),
    ]
    s = summarise(runs, max_moves=10)
    assert s["table"]["cup"]["tree"]["ever_correct"] == 1
    assert s["table"]["cup"]["random"]["median_first_correct"] == 3.5
    # never counts as budget + 1 = 11: (4 - 2) + (3 - 11) = -6 over 2 pairs.
    assert s["paired_by_seed"]["tree_vs_random"]["mean_moves_saved"] == -3.0
    assert s["paired_by_seed"]["tree_vs_random"]["tree_fewer"] == 1
    lo, hi = s["paired_by_seed"]["tree_vs_random"]["ci95"]
    assert lo == -8.0 and hi == 2.0  # resampling two pairs: both -8, both +2, or one each
    assert s["paired_by_seed"]["tree_vs_random"]["sign_p"] == 1.0
    assert s["per_policy"]["tree"]["objects_final_correct_majority"] == 0


def test_sign_test_and_bootstrap():
    assert sign_test_p(10, 0) == pytest.approx(2 / 2**10)
    assert sign_test_p(5, 5) == 1.0 and sign_test_p(0, 0) == 1.0
    assert 0.0 < sign_test_p(600, 500) < 0.01  # large evaluations do not overflow
    lo, hi = bootstrap_ci(np.full(30, 0.5), np.random.default_rng(0))
    assert lo == hi == 0.5
    d = np.random.default_rng(1).normal(1.0, 1.0, 400)
    lo, hi = bootstrap_ci(d, np.random.default_rng(0))
    assert lo < d.mean() < hi and hi - lo == pytest.approx(2 * 1.96 / 20, rel=0.2)


def _resampled_ci(d: np.ndarray, rng: np.random.Generator, n_boot: int = 10_000) -> tuple:
    # The plain percentile bootstrap, by hand: what bootstrap_ci computed before scipy did it.
    means = np.concatenate(
        [d[rng.integers(0, d.size, size=(500, d.size))].mean(1) for _ in range(n_boot // 500)]
    )
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


@pytest.mark.parametrize("n", [2, 7, 400])
def test_bootstrap_is_the_plain_percentile_bootstrap(n):
    d = np.random.default_rng(n).integers(-5, 6, n).astype(float)
    got = bootstrap_ci(d, np.random.default_rng(3))
    assert got == pytest.approx(_resampled_ci(d, np.random.default_rng(3)), abs=1e-12)
    assert got == bootstrap_ci(d, np.random.default_rng(3))  # seeded: reproducible


@pytest.mark.parametrize(
    "d, want",
    [(np.array([3]), 3.0), (np.full(30, 0.1), 0.1), (np.array([-2, -2, -2]), -2.0)],
)
def test_bootstrap_degenerate_inputs(d, want):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # scipy's DegenerateDataWarning, numpy's RuntimeWarning
        assert bootstrap_ci(d, np.random.default_rng(0)) == (want, want)
        lo, hi = bootstrap_ci(np.array([]), np.random.default_rng(0))
    assert np.isnan(lo) and np.isnan(hi)


def test_eval_command_writes_results_and_report(trained_home, tmp_path, capsys):
    out = tmp_path / "report"
    rc = main(
        [
            "eval",
            "--data",
            str(trained_home),
            "--seeds",
            "0-1",
            "--max-moves",
            "4",
            "--policies",
            "tree,random",
            "--out",
            str(out),
            "--workers",
            "1",
            "--set",
            "grid.step_deg=40",
        ]
    )
    assert rc == 0
    doc = json.loads((out / "results.json").read_text())
    assert len(doc["runs"]) == 3 * 2 * 2
    r = doc["runs"][0]
    for key in (
        "object",
        "policy",
        "seed",
        "labels",
        "moves_to_first_correct",
        "moves_to_stable_correct",
        "final_correct",
        "planning_s",
    ):
        assert key in r
    assert all(1 <= len(r["labels"]) <= 4 for r in doc["runs"])
    md = (out / "report.md").read_text()
    assert "Median moves until first correct" in md and "python -m activetouch eval" in md
    for fig in ("distance_vs_moves.png", "histograms.png", "contacts.png"):
        assert (out / fig).stat().st_size > 10_000
    assert paths.models_dir(trained_home).is_dir()


def test_eval_user_mistakes(trained_home, tmp_path, capsys):
    base = ["eval", "--data", str(trained_home), "--out", str(tmp_path / "r")]
    assert main([*base, "--policies", "oracle"]) == 2
    assert main([*base, "--seeds", "9-1"]) == 2
    assert main([*base, "--max-moves", "0"]) == 2
    assert main(["eval", "--data", str(tmp_path / "empty"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "no model" in err


def test_robot_seconds_to_first_correct_are_summarised_and_paired():
    from activetouch.pipelines.evaluation import robot_s_at

    assert robot_s_at([4.0, 9.0, 13.0], 2) == 9.0
    assert robot_s_at([4.0, 9.0], None) is None and robot_s_at([], 1) is None

    def timed(policy, seed, first, robot_s):
        r = _run("cup", policy, seed, first, first is not None)
        r["robot_s_to_first_correct"] = robot_s_at(robot_s, first)
        r["total_s"] = robot_s[-1]
        return r

    runs = [
        timed("tree", 0, 2, [5.0, 11.0, 15.0]),
        timed("greedy", 0, 1, [5.0, 12.0]),
        timed("tree", 1, 1, [4.0]),
        timed("greedy", 1, None, [4.0, 9.0, 20.0]),  # never: its whole 20 s counts
    ]
    s = summarise(runs, max_moves=3)
    assert s["per_policy"]["tree"]["mean_robot_s_to_first_correct"] == pytest.approx(7.5)
    assert s["per_policy"]["greedy"]["mean_robot_s_to_first_correct"] == pytest.approx(12.5)
    assert s["per_policy"]["greedy"]["never_correct"] == 1
    saved = s["paired_by_seed"]["tree_vs_greedy"]["robot_s_saved"]
    assert saved["mean"] == pytest.approx(((5.0 - 11.0) + (20.0 - 4.0)) / 2)
    assert (saved["tree_faster"], saved["tree_slower"]) == (1, 1)
