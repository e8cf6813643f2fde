"""Policies behind one interface: tree, greedy (T = 1) and random, and the replanning loop."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chisquare

from activetouch.config import ObservationConfig, PlannerConfig
from activetouch.errors import ConfigError
from activetouch.planning.observation_builder import build_observation_model
from activetouch.planning.policies import (
    GreedyPolicy,
    PlanningState,
    RandomPolicy,
    TreePolicy,
    make_policy,
    run_policy,
)
from activetouch.planning.synthetic import synthetic_problem
from activetouch.recognition.histogram import HistogramSpec
from activetouch.recognition.kernels import KIND_LINEAR_OVR, ClassifierKernel
from tests.planning.test_mcts import (
    C_ROOT,
    ROOT_COUNTS,
    _rule,
    lookahead_problem,
)


def lookahead_observe(model):
    """Real observations of the hand-built problem (deterministic, conditioned on the last cell)."""
    last = {"cell": C_ROOT}

    def observe(pose: int) -> tuple[np.ndarray, np.ndarray]:
        o = _rule(pose, last["cell"])  # action id = target pose id
        counts = np.bincount(
            model.out_bin[model.out_ptr[o] : model.out_ptr[o + 1]], minlength=model.n_bins
        ).astype(float)
        last["cell"] = int(model.out_cell[o])
        return counts, np.array([last["cell"]])

    return observe


def start_state() -> PlanningState:
    return PlanningState.start(0, ROOT_COUNTS, np.array([C_ROOT]))


def test_tree_looks_ahead_where_greedy_does_not() -> None:
    model, kernel = lookahead_problem()
    # The paper's objective and scheme (the problem is built for Eq. 1 on h_T).
    cfg = PlannerConfig(
        policy="tree",
        horizon=2,
        simulations=20000,
        lam=0.5,
        objective="final",
        replan_every_grasp=False,
    )
    tree = make_policy("tree", cfg, model, kernel)
    greedy = make_policy("greedy", cfg, model, kernel)
    assert isinstance(tree, TreePolicy) and isinstance(greedy, GreedyPolicy)
    assert greedy.horizon == 1
    t = tree.plan(start_state(), np.random.default_rng(0))
    g = greedy.plan(start_state(), np.random.default_rng(0))
    assert t.poses.tolist() == [2, 3]  # the key pose, then the pose it unlocks
    assert g.poses.tolist() == [1]  # the immediate gain
    # Executed, the tree's plan ends more confident than two greedy steps.
    ep_t = run_policy(
        tree, start_state(), lookahead_observe(model), max_moves=2, rng=np.random.default_rng(1)
    )
    ep_g = run_policy(
        greedy, start_state(), lookahead_observe(model), max_moves=2, rng=np.random.default_rng(1)
    )
    assert ep_t.poses.tolist() == [2, 3] and len(ep_t.plans) == 1
    assert len(ep_g.plans) == 2 and ep_g.poses[0] == 1
    assert kernel.proba(ep_t.state.counts).max() > kernel.proba(ep_g.state.counts).max() + 0.1


def test_replanning_mode_executes_one_pose_per_tree() -> None:
    model, kernel = lookahead_problem()
    cfg = PlannerConfig(
        horizon=2, simulations=20000, lam=0.5, objective="final", replan_every_grasp=True
    )
    tree = make_policy("tree", cfg, model, kernel)
    plan = tree.plan(start_state(), np.random.default_rng(0))
    assert plan.poses.tolist() == [2]
    assert plan.search is not None and plan.search.poses.tolist() == [2, 3]
    ep = run_policy(
        tree, start_state(), lookahead_observe(model), max_moves=3, rng=np.random.default_rng(0)
    )
    assert len(ep.plans) == 3 and ep.poses[:2].tolist() == [2, 3]
    assert ep.state.visited.tolist() == [0, *ep.poses.tolist()]


def test_random_policy_is_uniform_over_unvisited_poses() -> None:
    pr = synthetic_problem(12, 3, rng=np.random.default_rng(0))
    policy = make_policy("random", PlannerConfig(), pr.model, pr.kernel)
    assert isinstance(policy, RandomPolicy)
    counts, cells = pr.observe(4)
    state = PlanningState(4, np.array([0, 3, 4, 7]), counts, cells)
    rng = np.random.default_rng(42)
    draws = np.array([policy.plan(state, rng).poses[0] for _ in range(4000)])
    allowed = [p for p in range(12) if p not in (0, 3, 4, 7)]
    assert set(draws.tolist()) == set(allowed)
    freq = np.array([(draws == p).sum() for p in allowed])
    assert chisquare(freq).pvalue > 1e-3
    plan = policy.plan(state, np.random.default_rng(1))
    e = pr.model.edge_ptr[4] + int(
        np.flatnonzero(
            pr.model.edge_target[pr.model.edge_ptr[4] : pr.model.edge_ptr[5]] == plan.poses[0]
        )[0]
    )
    assert plan.actions[0] == pr.model.edge_action[e]


@pytest.mark.parametrize("name", ["tree", "greedy", "random"])
def test_policies_are_deterministic_given_a_seed(name: str) -> None:
    pr = synthetic_problem(60, 4, rng=np.random.default_rng(3))
    cfg = PlannerConfig(horizon=4, simulations=300)
    policy = make_policy(name, cfg, pr.model, pr.kernel)
    counts, cells = pr.observe(0)
    state = PlanningState.start(0, counts, cells)
    runs = [
        run_policy(policy, state, pr.observe, max_moves=12, rng=np.random.default_rng(9))
        for _ in range(2)
    ]
    assert runs[0].poses.tolist() == runs[1].poses.tolist()
    assert len(runs[0].poses) == 12
    # No pose is executed twice, and the start pose is never revisited.
    assert len(set(runs[0].state.visited.tolist())) == 13


@pytest.mark.parametrize("name", ["tree", "greedy", "random"])
def test_policies_say_when_poses_are_exhausted(name: str) -> None:
    pr = synthetic_problem(6, 2, rng=np.random.default_rng(1))
    policy = make_policy(name, PlannerConfig(horizon=3, simulations=50), pr.model, pr.kernel)
    counts, cells = pr.observe(0)
    state = PlanningState(0, np.arange(6), counts, cells)
    plan = policy.plan(state, np.random.default_rng(0))
    assert plan.exhausted and len(plan) == 0
    # Executing until nothing is left: 5 more poses, then an exhausted plan ends the loop.
    ep = run_policy(
        policy,
        PlanningState.start(0, counts, cells),
        pr.observe,
        max_moves=50,
        rng=np.random.default_rng(0),
    )
    assert ep.exhausted and sorted(ep.poses.tolist()) == [1, 2, 3, 4, 5]
    assert ep.plans[-1].exhausted


def test_stop_condition_and_bad_names() -> None:
    pr = synthetic_problem(30, 3, rng=np.random.default_rng(1))
    policy = make_policy("tree", PlannerConfig(horizon=3, simulations=100), pr.model, pr.kernel)
    counts, cells = pr.observe(0)
    ep = run_policy(
        policy,
        PlanningState.start(0, counts, cells),
        pr.observe,
        max_moves=20,
        rng=np.random.default_rng(0),
        stop=lambda s: len(s.visited) >= 4,
    )
    assert len(ep.poses) == 3 and not ep.exhausted
    with pytest.raises(ConfigError, match="unknown planner policy"):
        make_policy("mcts", PlannerConfig(), pr.model, pr.kernel)
    with pytest.raises(ConfigError, match="horizon"):
        make_policy("tree", PlannerConfig(horizon=0), pr.model, pr.kernel)
    with pytest.raises(ConfigError, match="eq4_sampling"):
        make_policy("tree", PlannerConfig(eq4_sampling="guess"), pr.model, pr.kernel)
    per_class = make_policy("tree", PlannerConfig(eq4_sampling="per_class"), pr.model, pr.kernel)
    plan = per_class.plan(PlanningState.start(0, counts, cells), np.random.default_rng(0))
    assert plan.poses.size


# --- absolute actions: a discriminating pose the relative model pools away -------------------


def ring_problem(action_frame: str):
    """Two classes grasped at the same six poses on a ring (pose k at 60k degrees, rotated about
    z by the same angle). Every pose but the opposite one (k = 3) gives both classes the same
    triangle; there class a and class b differ. Relative actions pool "move k steps" over the
    ring (rotational symmetry), so every move looks alike and the cheapest wins; absolute
    actions know that only pose 3 tells the classes apart."""
    spec = HistogramSpec(lo=np.array([0.0, 0.0, 1.0]), hi=np.array([0.2, 0.2, 3.2]), bins=2)
    shared, only_a, only_b = [0.10, 0.09, 2.0], [0.05, 0.04, 1.5], [0.13, 0.05, 2.6]
    th = np.deg2rad(60.0 * np.arange(6))
    poses = np.concatenate(
        [
            np.stack([0.2 * np.cos(th), 0.2 * np.sin(th), np.zeros(6)], 1),
            Rotation.from_rotvec(np.stack([np.zeros(6), np.zeros(6), th], 1)).as_quat(),
        ],
        axis=1,
    )

    def grasps(special: list[float]) -> list[np.ndarray]:
        return [np.array([special if k == 3 else shared]) for k in range(6)]

    objs = [("a", poses, grasps(only_a)), ("b", poses, grasps(only_b))]
    model = build_observation_model(objs, spec, ObservationConfig(action_frame=action_frame))
    ba, bb = (int(spec.bin_index(np.array([t]))[0]) for t in (only_a, only_b))
    W = np.zeros((2, spec.n_bins))
    W[0, ba], W[0, bb], W[1, ba], W[1, bb] = 1.0, -1.0, -1.0, 1.0
    kernel = ClassifierKernel(
        kind=KIND_LINEAR_OVR,
        W=W,
        b=np.zeros(2),
        row_class=np.array([0, 1], dtype=np.int64),
        platt_a=np.array([-20.0, -20.0]),
        platt_b=np.zeros(2),
        temperature=1.0,
        n_classes=2,
    )
    counts = np.bincount(spec.bin_index(np.array([shared])), minlength=spec.n_bins).astype(float)
    start = PlanningState.start(0, counts, model.cells_of(np.array([shared])))
    return model, kernel, start


def test_absolute_actions_find_the_discriminating_pose() -> None:
    rel, kernel, start = ring_problem("relative")
    ab, _, _ = ring_problem("absolute")
    assert rel.n_poses == ab.n_poses == 6 and rel.n_actions == 5 and ab.n_actions == 6
    cfg = PlannerConfig(horizon=2, simulations=3000, lam=0.2)
    g_ab = make_policy("greedy", cfg, ab, kernel).plan(start, np.random.default_rng(0))
    g_rel = make_policy("greedy", cfg, rel, kernel).plan(start, np.random.default_rng(0))
    assert g_ab.poses.tolist() == [3]
    assert g_rel.poses.tolist() in ([1], [5])  # every move looks alike: the cheapest
    t_ab = make_policy("tree", cfg, ab, kernel).plan(start, np.random.default_rng(0))
    assert 3 in t_ab.poses.tolist()
    # The search charges the move, not the target: 0 -> 3 costs more than 1 -> 3 would.
    e03 = int(np.flatnonzero(ab.edge_target[: ab.edge_ptr[1]] == 3)[0])
    lo1 = int(ab.edge_ptr[1])
    e13 = lo1 + int(np.flatnonzero(ab.edge_target[lo1 : ab.edge_ptr[2]] == 3)[0])
    assert ab.edge_action[e03] == ab.edge_action[e13] and ab.edge_cost[e03] > ab.edge_cost[e13]


def test_travel_time_edge_costs_steer_the_movement_term() -> None:
    # c_m from an arm's move durations (planner.movement_cost = "travel_time"): with all the
    # weight on movement the search goes where the arm gets fastest, and NaN (a move the arm
    # cannot make) costs the most.
    from activetouch.planning.observation_model import travel_edge_cost

    model, kernel = lookahead_problem()
    P = model.n_poses
    cfg = PlannerConfig(horizon=1, simulations=2000, lam=1.0, movement_cost="travel_time")
    greedy = make_policy("greedy", cfg, model, kernel)
    assert greedy.movement_cost == "travel_time"
    for fast in range(1, P):
        seconds = np.full((P, P), 6.0)
        seconds[0, fast] = 1.5
        seconds[0, (fast % (P - 1)) + 1] = np.nan
        cost = travel_edge_cost(model, seconds)
        assert cost.min() == pytest.approx(0.25) and cost.max() == 1.0
        greedy.set_edge_cost(cost)
        assert greedy.plan(start_state(), np.random.default_rng(0)).poses.tolist() == [fast]
    with pytest.raises(ValueError):
        travel_edge_cost(model, np.zeros((P + 1, P + 1)))
    with pytest.raises(ValueError):
        greedy.set_edge_cost(np.zeros(3))
    make_policy("random", cfg, model, kernel).set_edge_cost(cost)  # no movement term: ignored
