"""Planning on the grasp-likelihood belief (recognition.belief = grasp_likelihood): the tree
search with Bayes' rule in place of the classifier (simulated_belief.KIND_BAYES)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from activetouch.config import PlannerConfig
from activetouch.errors import PlanningError
from activetouch.planning.mcts import TreeSearch
from activetouch.planning.policies import PlanningState, make_policy
from activetouch.planning.simulated_belief import BeliefTable
from tests.planning.test_mcts import (
    NO_POSES,
    OUT_KEY,
    OUT_MIX,
    OUT_ONE,
    OUT_SIX,
    ROOT_CELLS,
    ROOT_COUNTS,
    lookahead_problem,
    path_steps,
)

# log p(outcome's grasp | y) for y = 0, 1: "six" nearly rules class 1 out, "one" a little,
# "mix" and "key" say nothing.
TABLE = np.zeros((4, 2))
TABLE[OUT_ONE] = [0.0, -1.0]
TABLE[OUT_SIX] = [0.0, -6.0]
TABLE[OUT_MIX] = [0.0, 0.0]
TABLE[OUT_KEY] = [0.0, 0.0]
ROOT = np.array([0.0, 0.0])  # the real grasps so far told nothing
# Outcome o is training grasp 3 - o: the table is indexed by grasp, not outcome.
BELIEF = BeliefTable(TABLE[::-1].copy(), np.array([3, 2, 1, 0]))


def bayes_cost(model, start: int, path: list[int], log_b: np.ndarray, horizon: int) -> float:
    """Eq. 1 (lam 0.5) with p = softmax of the summed log-likelihoods along a deterministic path."""
    lb = log_b.copy()
    move = 0.0
    for a, o in path_steps(model, start, path):
        move += model.action_cost[a]
        lb = lb + TABLE[o]
    p = np.exp(lb - lb.max())
    p /= p.sum()
    return 0.5 / horizon * move + 0.5 * (1 - p.max())


def plan_from_root(horizon: int, simulations: int, log_belief: np.ndarray = ROOT):
    """A search on the belief from pose 0 of the lookahead problem (seed 0)."""
    model, kernel = lookahead_problem()
    return TreeSearch(model, kernel, belief=BELIEF).search(
        0,
        NO_POSES,
        ROOT_COUNTS,
        ROOT_CELLS,
        horizon=horizon,
        simulations=simulations,
        rng=np.random.default_rng(0),
        log_belief=log_belief,
    )


def test_the_tree_plans_on_the_belief_and_values_its_paths_by_bayes() -> None:
    model, _ = lookahead_problem()
    costs = {
        p: bayes_cost(model, 0, list(p), ROOT, 2)
        for p in itertools.permutations(range(1, model.n_poses), 2)
    }
    best = min(costs, key=costs.get)
    assert list(best) == [2, 3]  # look first, then the telling grasp
    res = plan_from_root(horizon=2, simulations=20000)
    assert res.poses.tolist() == [2, 3]
    assert res.value == pytest.approx(1.0 - costs[best], abs=1e-12)
    greedy = plan_from_root(horizon=1, simulations=200)
    assert greedy.poses.tolist() == [1]
    assert greedy.value == pytest.approx(1 - bayes_cost(model, 0, [1], ROOT, 1), abs=1e-12)


def test_the_root_belief_is_the_real_one() -> None:
    model, _ = lookahead_problem()
    sure = np.array([0.0, -3.0])  # the real grasps already favour class 0
    res = plan_from_root(horizon=1, simulations=200, log_belief=sure + 100.0)  # differences count
    assert res.value == pytest.approx(1 - bayes_cost(model, 0, [1], sure, 1), abs=1e-12)


def test_a_policy_takes_the_belief_from_the_state() -> None:
    model, kernel = lookahead_problem()
    cfg = PlannerConfig(horizon=2, simulations=5000, lam=0.5, objective="final")
    policy = make_policy("tree", cfg, model, kernel, belief=BELIEF)
    state = PlanningState(0, np.array([0]), ROOT_COUNTS, ROOT_CELLS, log_belief=ROOT)
    plan = policy.plan(state, np.random.default_rng(0))
    assert plan.search is not None
    assert plan.search.poses.tolist() == [2, 3]


def test_bad_belief_arguments_are_planning_errors() -> None:
    model, kernel = lookahead_problem()
    with pytest.raises(PlanningError, match="belief table"):
        TreeSearch(model, kernel, belief=BeliefTable(TABLE, np.arange(3)))
    with pytest.raises(PlanningError, match="outside"):
        TreeSearch(model, kernel, belief=BeliefTable(TABLE, np.array([0, 1, 2, 4])))
    search = TreeSearch(model, kernel, belief=BELIEF)
    kw = dict(horizon=1, simulations=10, rng=np.random.default_rng(0))
    with pytest.raises(PlanningError, match="log_belief"):
        search.search(0, NO_POSES, ROOT_COUNTS, ROOT_CELLS, **kw)
    with pytest.raises(PlanningError, match="log_belief"):
        search.search(
            0, NO_POSES, ROOT_COUNTS, ROOT_CELLS, log_belief=np.array([0.0, np.nan]), **kw
        )
