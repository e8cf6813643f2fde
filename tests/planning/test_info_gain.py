"""The information-gain objective (`planner.objective = "info_gain"`): the mean over the path
of the normalised entropy of p(y | h_t), i.e. the expected entropy reduction per step."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from activetouch.config import load_config
from activetouch.errors import PlanningError
from activetouch.planning.mcts import TreeSearch
from activetouch.planning.policies import make_policy
from tests.planning.test_mcts import NO_POSES, ROOT_CELLS, ROOT_COUNTS, path_steps
from tests.planning.test_mcts import lookahead_problem as problem


def entropy_cost(model, kernel, path: list[int], horizon: int, lam: float) -> float:
    """The info-gain cost of a path of the deterministic hand model, computed directly."""
    h = ROOT_COUNTS.astype(float).copy()
    move = unsure = 0.0
    for a, o in path_steps(model, 0, path):
        move += model.action_cost[a]
        np.add.at(h, model.out_bin[model.out_ptr[o] : model.out_ptr[o + 1]], 1.0)
        p = kernel.proba(h)
        p = p[p > 0]
        unsure += float(-(p * np.log(p)).sum() / np.log(kernel.n_classes))
    return (lam * move + (1 - lam) * unsure) / horizon


def test_value_is_the_entropy_cost_and_the_tree_finds_its_optimum():
    model, kernel = problem(cost=0.3)
    ts = TreeSearch(model, kernel, objective="info_gain")
    for seed, horizon, lam in [(1, 1, 0.5), (2, 2, 0.2), (3, 3, 0.5)]:
        res = ts.search(
            0, NO_POSES, ROOT_COUNTS, ROOT_CELLS, horizon=horizon, simulations=3000, lam=lam,
            rng=np.random.default_rng(seed),
        )  # fmt: skip
        c = entropy_cost(model, kernel, res.poses.tolist(), horizon, lam)
        assert res.value == pytest.approx(1.0 - c, abs=1e-12)
    res = ts.search(
        0, NO_POSES, ROOT_COUNTS, ROOT_CELLS, horizon=2, simulations=20000, lam=0.5,
        rng=np.random.default_rng(0),
    )  # fmt: skip
    costs = {
        p: entropy_cost(model, kernel, list(p), 2, 0.5)
        for p in itertools.permutations(range(1, model.n_poses), 2)
    }
    assert tuple(res.poses.tolist()) == min(costs, key=costs.get)


def test_the_objective_is_a_config_choice_and_other_words_are_refused():
    model, kernel = problem()
    cfg = load_config(None, ["planner.objective=info_gain"])
    for name in ("tree", "greedy"):
        pol = make_policy(name, cfg.planner, model, kernel)
        assert pol.search.objective == "info_gain"
    assert TreeSearch(model, kernel, anytime=True).objective == "anytime"  # older keyword
    assert TreeSearch(model, kernel).objective == "final"
    with pytest.raises(PlanningError, match="objective"):
        TreeSearch(model, kernel, objective="entropy")
