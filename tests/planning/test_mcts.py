"""Tree search (paper Algs. 2-4) on hand-built decision problems and synthetic models."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from activetouch.errors import PlanningError
from activetouch.planning import mcts_kernels, simulated_belief
from activetouch.planning.mcts import TreeSearch, model_arrays
from activetouch.planning.observation_model import ObservationModel, outcome_probabilities
from activetouch.planning.synthetic import synthetic_problem
from activetouch.recognition.kernels import (
    KIND_LINEAR_OVR,
    KIND_NN_INNER,
    KIND_NN_INTERSECTION,
    ClassifierKernel,
    kernel_proba,
)

NO_POSES = np.zeros(0, dtype=np.int64)

# --------------------------------------------------------------------------------------------
# A hand-built problem where lookahead matters
#
# Two bins: 0 and 1; the classifier's confidence grows with the imbalance between them
# (p(class 0) = sigmoid(K_SLOPE * (share of bin 1 - 1/2))). The root histogram [1, 1] is
# ambiguous. Poses 0 (current) .. 4, every pose reaches every other; the action of an edge is
# its target pose id. Outcomes (the same for both classes, so transitions are deterministic):
#   OUT_MIX  = bins {0, 1}   cell C_MIX    no information
#   OUT_ONE  = bins {1}      cell C_ONE    mild evidence
#   OUT_SIX  = bins {1} x 6  cell C_SIX    strong evidence
#   OUT_KEY  = bins {0, 1}   cell C_KEY    no information, but it unlocks pose 3
# Rules out(action, cell): after C_ONE anything gives OUT_MIX; action 1 gives OUT_ONE;
# action 2 gives OUT_KEY; action 3 gives OUT_SIX after C_KEY, else OUT_MIX; action 4 OUT_MIX.
# Greedy (T = 1) goes to pose 1 (mild evidence now); the best 2-step path is 2 -> 3.
# --------------------------------------------------------------------------------------------

OUT_MIX, OUT_ONE, OUT_SIX, OUT_KEY = 0, 1, 2, 3
C_ROOT, C_MIX, C_ONE, C_KEY, C_SIX = 0, 1, 2, 3, 4
K_SLOPE = 10.0


def _rule(action: int, cell: int) -> int:
    if cell == C_ONE:
        return OUT_MIX
    if action == 1:
        return OUT_ONE
    if action == 2:
        return OUT_KEY
    if action == 3:
        return OUT_SIX if cell == C_KEY else OUT_MIX
    return OUT_MIX


def csr_rows(table: dict[int, list[tuple[int, float]]]) -> tuple[np.ndarray, ...]:
    """Sorted (key, ptr, out, cum) from {key: [(outcome, weight), ...]}."""
    keys = sorted(table)
    ptr, outs, cums = [0], [], []
    for k in keys:
        entries = sorted(table[k])
        w = np.array([e[1] for e in entries], dtype=float)
        outs.extend(e[0] for e in entries)
        c = np.cumsum(w) / w.sum()
        c[-1] = 1.0
        cums.extend(c)
        ptr.append(len(outs))
    return (
        np.array(keys, dtype=np.int64),
        np.array(ptr, dtype=np.int64),
        np.array(outs, dtype=np.int64),
        np.array(cums, dtype=np.float64),
    )


def hand_model(
    n_poses: int,
    action_cost: np.ndarray,
    outcome_bins: list[list[int]],
    outcome_cells: list[int],
    tally: dict[tuple[int, int, int], list[tuple[int, float]]],
    marg: dict[tuple[int, int], list[tuple[int, float]]],
    *,
    n_classes: int,
    n_cells: int,
    n_bins: int,
) -> ObservationModel:
    """A complete pose graph whose action ids are the target pose ids."""
    A = len(action_cost)
    src = np.repeat(np.arange(n_poses), n_poses - 1)
    off = np.tile(np.arange(n_poses - 1), n_poses)
    tgt = off + (off >= src)
    tk = {(y * A + a) * n_cells + z: v for (y, a, z), v in tally.items()}
    mk = {y * A + a: v for (y, a), v in marg.items()}
    tally_key, tally_ptr, tally_out, tally_cum = csr_rows(tk)
    marg_key, marg_ptr, marg_out, marg_cum = csr_rows(mk)
    lens = [len(b) for b in outcome_bins]
    model = ObservationModel(
        granularity="grasp",
        class_names=tuple(f"c{y}" for y in range(n_classes)),
        n_bins=n_bins,
        n_cells=n_cells,
        pose_xyz=np.zeros((n_poses, 3)),
        pose_quat=np.tile([0.0, 0.0, 0.0, 1.0], (n_poses, 1)),
        action_delta=np.zeros((A, 7)),
        action_cost=np.asarray(action_cost, dtype=np.float64),
        edge_ptr=np.arange(n_poses + 1, dtype=np.int64) * (n_poses - 1),
        edge_action=tgt.astype(np.int64),
        edge_target=tgt.astype(np.int64),
        out_cell=np.array(outcome_cells, dtype=np.int64),
        out_ptr=np.concatenate([[0], np.cumsum(lens)]).astype(np.int64),
        out_bin=np.array([b for bins in outcome_bins for b in bins], dtype=np.int64),
        tally_key=tally_key,
        tally_ptr=tally_ptr,
        tally_out=tally_out,
        tally_cum=tally_cum,
        marg_key=marg_key,
        marg_ptr=marg_ptr,
        marg_out=marg_out,
        marg_cum=marg_cum,
        cell_key=np.stack(
            [np.arange(n_cells), np.zeros(n_cells, int), np.zeros(n_cells, int)], 1
        ).astype(np.int64),
    )
    model.validate()
    return model


def two_bin_kernel(slope: float = K_SLOPE) -> ClassifierKernel:
    """score_0 = share of bin 1 - 1/2 = -score_1; p(class 0) = sigmoid(slope * score_0)."""
    return ClassifierKernel(
        kind=KIND_LINEAR_OVR,
        W=np.array([[0.0, 1.0], [0.0, -1.0]]),
        b=np.array([-0.5, 0.5]),
        row_class=np.array([0, 1], dtype=np.int64),
        platt_a=np.array([-slope, -slope]),
        platt_b=np.zeros(2),
        temperature=1.0,
        n_classes=2,
    )


def lookahead_problem(cost: float = 0.1) -> tuple[ObservationModel, ClassifierKernel]:
    n_poses, n_cells = 5, 5
    tally = {
        (y, a, z): [(_rule(a, z), 1.0)]
        for y in range(2)
        for a in range(1, n_poses)
        for z in range(n_cells)
    }
    marg = {(y, a): [(OUT_MIX, 1.0)] for y in range(2) for a in range(1, n_poses)}
    model = hand_model(
        n_poses,
        np.full(n_poses, cost),
        outcome_bins=[[0, 1], [1], [1] * 6, [0, 1]],
        outcome_cells=[C_MIX, C_ONE, C_SIX, C_KEY],
        tally=tally,
        marg=marg,
        n_classes=2,
        n_cells=n_cells,
        n_bins=2,
    )
    return model, two_bin_kernel()


ROOT_COUNTS = np.array([1.0, 1.0])
ROOT_CELLS = np.array([C_ROOT], dtype=np.int64)


def path_steps(
    model: ObservationModel, start: int, path: list[int], cell: int = C_ROOT
) -> list[tuple[int, int]]:
    """(action, outcome) of each step of `path` from `start` in a deterministic hand model
    (outcomes follow `_rule`), the reference the tree's values are checked against."""
    steps = []
    pose = start
    for target in path:
        lo = model.edge_ptr[pose]
        e = lo + int(np.flatnonzero(model.edge_target[lo : model.edge_ptr[pose + 1]] == target)[0])
        a = int(model.edge_action[e])
        o = _rule(a, cell)
        steps.append((a, o))
        cell = int(model.out_cell[o])
        pose = target
    return steps


def path_cost(
    model: ObservationModel,
    kernel: ClassifierKernel,
    start: int,
    path: list[int],
    counts: np.ndarray,
    cell: int,
    horizon: int,
    lam: float = 0.5,
    anytime: bool = False,
) -> float:
    """Eq. 1 for a deterministic hand model (every row has one outcome), computed directly;
    `anytime`: the recognition term averaged over the steps instead of taken at the end."""
    h = counts.astype(float).copy()
    move = 0.0
    unsure = 0.0
    for a, o in path_steps(model, start, path, cell):
        move += model.action_cost[a]
        np.add.at(h, model.out_bin[model.out_ptr[o] : model.out_ptr[o + 1]], 1.0)
        unsure += 1 - kernel.proba(h).max()
    if anytime:
        return (lam * move + (1 - lam) * unsure) / horizon
    return lam / horizon * move + (1 - lam) * (1 - kernel.proba(h).max())


def best_paths(model, kernel, horizon: int) -> tuple[list[int], float]:
    costs = {
        p: path_cost(model, kernel, 0, list(p), ROOT_COUNTS, C_ROOT, horizon)
        for p in itertools.permutations(range(1, model.n_poses), horizon)
    }
    best = min(costs, key=costs.get)
    return list(best), costs[best]


# --------------------------------------------------------------------------------------------


def test_tree_finds_the_best_path_and_its_value_is_the_path_cost() -> None:
    model, kernel = lookahead_problem()
    best, best_cost = best_paths(model, kernel, 2)
    assert best == [2, 3]  # the problem is built that way
    res = TreeSearch(model, kernel).search(
        0,
        NO_POSES,
        ROOT_COUNTS,
        ROOT_CELLS,
        horizon=2,
        simulations=20000,
        rng=np.random.default_rng(0),
    )
    assert not res.exhausted
    assert res.poses.tolist() == best
    assert res.actions.tolist() == best  # action id = target pose id in this model
    # The deepest edge's backed-up reward is exactly 1 - C of the path (transitions are
    # deterministic), and the root edge's running mean approaches it from below.
    assert res.value == pytest.approx(1.0 - best_cost, abs=1e-12)
    assert res.cost == pytest.approx(best_cost, abs=1e-12)
    assert res.step_values[0] <= res.value + 1e-12
    assert res.step_values[0] > 1.0 - best_cost - 0.02


def test_greedy_horizon_prefers_the_immediate_gain() -> None:
    model, kernel = lookahead_problem()
    best1, _ = best_paths(model, kernel, 1)
    assert best1 == [1]
    res = TreeSearch(model, kernel).search(
        0,
        NO_POSES,
        ROOT_COUNTS,
        ROOT_CELLS,
        horizon=1,
        simulations=200,
        rng=np.random.default_rng(0),
    )
    assert res.poses.tolist() == [1]
    assert res.value == pytest.approx(
        1 - path_cost(model, kernel, 0, [1], ROOT_COUNTS, C_ROOT, 1), abs=1e-12
    )


def test_every_extracted_path_cost_matches_its_value() -> None:
    """Fully expanded small trees (deterministic): the path's value is its Eq. 1 cost."""
    model, kernel = lookahead_problem(cost=0.3)
    ts = TreeSearch(model, kernel)
    for seed, horizon, lam in [(1, 1, 0.5), (2, 2, 0.2), (3, 3, 0.5), (4, 4, 0.9)]:
        res = ts.search(
            0,
            NO_POSES,
            ROOT_COUNTS,
            ROOT_CELLS,
            horizon=horizon,
            simulations=3000,
            rng=np.random.default_rng(seed),
            lam=lam,
        )
        assert len(res.poses) == horizon
        c = path_cost(model, kernel, 0, res.poses.tolist(), ROOT_COUNTS, C_ROOT, horizon, lam)
        assert res.value == pytest.approx(1.0 - c, abs=1e-12)


def test_anytime_objective_values_and_best_paths() -> None:
    """The anytime objective: the value of an extracted path is its own cost, it finds the
    exhaustive optimum of that cost, and with T = 1 it is Eq. 1."""
    model, kernel = lookahead_problem(cost=0.3)
    ts = TreeSearch(model, kernel, anytime=True)
    paper = TreeSearch(model, kernel)
    for seed, horizon, lam in [(1, 1, 0.5), (2, 2, 0.2), (3, 3, 0.5)]:
        kw = dict(horizon=horizon, simulations=3000, lam=lam)
        res = ts.search(
            0,
            NO_POSES,
            ROOT_COUNTS,
            ROOT_CELLS,
            rng=np.random.default_rng(seed),
            **kw,
        )
        c = path_cost(
            model, kernel, 0, res.poses.tolist(), ROOT_COUNTS, C_ROOT, horizon, lam, anytime=True
        )
        assert res.value == pytest.approx(1.0 - c, abs=1e-12)
        if horizon == 1:
            final = paper.search(
                0, NO_POSES, ROOT_COUNTS, ROOT_CELLS, rng=np.random.default_rng(seed), **kw
            )
            assert final.poses.tolist() == res.poses.tolist()
            assert final.value == pytest.approx(res.value, abs=1e-12)
    # A well-explored tree finds the exhaustive optimum of the anytime cost.
    res = ts.search(
        0,
        NO_POSES,
        ROOT_COUNTS,
        ROOT_CELLS,
        horizon=2,
        simulations=20000,
        rng=np.random.default_rng(0),
    )
    costs = {
        p: path_cost(model, kernel, 0, list(p), ROOT_COUNTS, C_ROOT, 2, anytime=True)
        for p in itertools.permutations(range(1, model.n_poses), 2)
    }
    assert tuple(res.poses.tolist()) == min(costs, key=costs.get)


def test_visited_poses_are_never_planned_and_paths_stop_when_poses_run_out() -> None:
    model, kernel = lookahead_problem()
    ts = TreeSearch(model, kernel)
    # Pose 2 already executed: the key pose is gone, pose 3 is useless now.
    res = ts.search(
        0,
        np.array([2]),
        ROOT_COUNTS,
        ROOT_CELLS,
        horizon=2,
        simulations=2000,
        rng=np.random.default_rng(0),
    )
    assert 2 not in res.poses and 0 not in res.poses
    # Only poses 3 and 4 left with horizon 5: paths have at most 2 steps.
    res = ts.search(
        0,
        np.array([1, 2]),
        ROOT_COUNTS,
        ROOT_CELLS,
        horizon=5,
        simulations=500,
        rng=np.random.default_rng(0),
    )
    assert len(res.poses) == 2
    assert set(res.poses.tolist()) == {3, 4}
    # Rollouts cannot continue either: the path's value counts exactly its two moves.
    c = path_cost(model, kernel, 0, res.poses.tolist(), ROOT_COUNTS, C_ROOT, horizon=5)
    assert res.value == pytest.approx(1.0 - c, abs=1e-12)


def test_exhausted_root_says_so() -> None:
    model, kernel = lookahead_problem()
    res = TreeSearch(model, kernel).search(
        0,
        np.array([1, 2, 3, 4]),
        ROOT_COUNTS,
        ROOT_CELLS,
        horizon=3,
        simulations=100,
        rng=np.random.default_rng(0),
    )
    assert res.exhausted
    assert len(res.poses) == 0 and np.isnan(res.value)


def test_bad_arguments_raise_planning_errors() -> None:
    model, kernel = lookahead_problem()
    ts = TreeSearch(model, kernel)
    rng = np.random.default_rng(0)
    kw = {"horizon": 2, "simulations": 10, "rng": rng}
    with pytest.raises(PlanningError, match="pose id"):
        ts.search(9, NO_POSES, ROOT_COUNTS, ROOT_CELLS, **kw)
    with pytest.raises(PlanningError, match="bins"):
        ts.search(0, NO_POSES, np.zeros(3), ROOT_CELLS, **kw)
    with pytest.raises(PlanningError, match="horizon"):
        ts.search(0, NO_POSES, ROOT_COUNTS, ROOT_CELLS, horizon=0, simulations=10, rng=rng)
    with pytest.raises(PlanningError, match="classes"):
        TreeSearch(synthetic_problem(12, 3, rng=rng).model, kernel)


# --------------------------------------------------------------------------------------------
# Synthetic models: tree invariants, determinism, sampling


@pytest.fixture(scope="module")
def synth():
    return synthetic_problem(84, 7, rng=np.random.default_rng(5))


def _root(synth, pose: int = 0) -> tuple[np.ndarray, np.ndarray]:
    return synth.observe(pose)


def test_tree_invariants_on_a_synthetic_model(synth) -> None:
    m = synth.model
    counts, cells = _root(synth)
    visited = np.array([0, 5, 17, 40, 41])
    sims = 3000
    res = TreeSearch(m, synth.kernel).search(
        0,
        visited,
        counts,
        cells,
        horizon=5,
        simulations=sims,
        rng=np.random.default_rng(1),
        keep_tree=True,
    )
    t = res.tree
    n, r = res.n_nodes, res.n_edge_records
    assert 1 < n <= sims + 1 and r <= sims  # at most one new node per simulation
    assert t.node_vis[0] == sims and t.node_sel[0] == sims
    root_recs = np.flatnonzero(t.rec_node[:r] == 0)
    assert t.rec_n[root_recs].sum() == sims
    assert len(root_recs) == m.n_poses - len(visited)  # unvisited edges first: all tried
    # Every node's pose sequence from the root repeats no pose and avoids the executed ones.
    for node in range(1, n):
        poses = []
        k = node
        while k != 0:
            poses.append(int(t.node_pose[k]))
            k = int(t.rec_node[t.node_in[k]])
        assert len(poses) == t.node_depth[node] <= 5
        assert len(set(poses)) == len(poses)
        assert not set(poses) & set(visited.tolist())
    # Node visits equal the visits of the edge leading to them, summed over the edge's children.
    for rec in range(r):
        kids = np.flatnonzero(t.node_in[1:n] == rec) + 1
        assert t.node_vis[kids].sum() == t.rec_n[rec]
    # Q stays a mean of rewards in [0, 1].
    assert np.all((t.rec_q[:r] >= 0) & (t.rec_q[:r] <= 1))
    # The extracted path.
    assert len(set(res.poses.tolist())) == len(res.poses) <= 5
    assert not set(res.poses.tolist()) & set(visited.tolist())
    assert res.value == res.step_values[-1]
    assert sum(res.observation_sources) > 0


def test_equal_seeds_give_equal_plans(synth) -> None:
    m = synth.model
    counts, cells = _root(synth)
    a = TreeSearch(m, synth.kernel)
    b = TreeSearch(m, synth.kernel)
    kw = {"horizon": 5, "simulations": 400}
    r1 = a.search(0, NO_POSES, counts, cells, rng=np.random.default_rng(7), **kw)
    r2 = b.search(0, NO_POSES, counts, cells, rng=np.random.default_rng(7), **kw)
    r3 = a.search(0, NO_POSES, counts, cells, rng=np.random.default_rng(7), **kw)  # reused tree
    for r in (r2, r3):
        assert r.poses.tolist() == r1.poses.tolist()
        assert r.value == r1.value and r.n_nodes == r1.n_nodes
        assert r.observation_sources == r1.observation_sources
    others = {
        tuple(a.search(0, NO_POSES, counts, cells, rng=np.random.default_rng(s), **kw).poses)
        for s in range(8, 14)
    }
    assert len(others) > 1  # the seed matters


def test_both_granularities_plan() -> None:
    for gran in ("triangle", "grasp"):
        pr = synthetic_problem(42, 3, rng=np.random.default_rng(2), granularity=gran)
        counts, cells = _root(pr)
        res = TreeSearch(pr.model, pr.kernel).search(
            0, NO_POSES, counts, cells, horizon=4, simulations=300, rng=np.random.default_rng(0)
        )
        assert 1 <= len(res.poses) <= 4
        assert 0.0 <= res.value <= 1.0


def _sampler_at(synth, root: int) -> tuple:
    """What the compiled Eq. 4 sampler takes after the training grasp at `root`: (model arrays,
    kernel tuple, histogram counts, p(y | h), incremental scores)."""
    kern = simulated_belief.kernel_tuple(synth.kernel)
    counts, _ = _root(synth, root)
    S = np.empty(kern[1].shape[0] + 2)
    simulated_belief.scores_init(kern, counts, S)
    return model_arrays(synth.model), kern, counts, synth.kernel.proba(counts), S


def _draws(n: int, *args) -> np.ndarray:
    """`n` outcomes of `mcts_kernels._sample_outcome(*args)`."""
    return np.array([mcts_kernels._sample_outcome(*args) for _ in range(n)])


def _classes_per_pair(m: ObservationModel) -> dict[tuple[int, int], int]:
    """How many classes have a tally row for each (cell, action)."""
    A, C = m.n_actions, m.n_cells
    by_pair: dict[tuple[int, int], int] = {}
    for k in m.tally_key:
        key = (int(k % C), int(k // C % A))
        by_pair[key] = by_pair.get(key, 0) + 1
    return by_pair


def test_sampled_observations_follow_eq4(synth) -> None:
    """The compiled sampler's outcome frequencies match the reference p(z' | z, a) of Eq. 4
    (tally rows, marginal fallback, and nothing when no class has data)."""
    m = synth.model
    mt, kern, counts, p_y, S = _sampler_at(synth, 3)
    rng = np.random.default_rng(0)
    # One (cell, action) per table kind.
    A, C = m.n_actions, m.n_cells
    tally_code = m.tally_key[rng.integers(len(m.tally_key))]
    cases = {"tally": (int(tally_code % C), int(tally_code // C % A))}
    seen_marg = set((m.marg_key % A).tolist())
    seen_tally = {(int(k // C % A), int(k % C)) for k in m.tally_key}
    a_marg = next(a for a in sorted(seen_marg) if (a, 0) not in seen_tally)
    cases["marg"] = (0, a_marg)
    cases["none"] = (0, next(a for a in range(A) if a not in seen_marg))
    mcts_kernels.seed_numba(123)
    for kind, (cell, action) in cases.items():
        counters = np.zeros(3, dtype=np.int64)
        n = 20000
        draws = _draws(n, mt, kern, action, cell, counts, S, counters, False)
        expect = outcome_probabilities(m, cell, action, p_y)
        idx = ["tally", "marg", "none"].index(kind)
        assert counters[idx] == n
        if kind == "none":
            assert np.all(draws == -1) and expect.sum() == 0
            continue
        freq = np.bincount(draws, minlength=m.n_outcomes) / n
        assert set(np.flatnonzero(freq)) <= set(np.flatnonzero(expect))
        assert np.abs(freq - expect).max() < 0.02


@pytest.mark.parametrize("kind", [KIND_LINEAR_OVR, KIND_NN_INNER, KIND_NN_INTERSECTION])
def test_incremental_scores_equal_kernel_proba(kind: int, synth) -> None:
    rng = np.random.default_rng(kind)
    D, K = 40, 4
    W = rng.random((6, D))
    if kind == KIND_NN_INNER:
        W /= np.linalg.norm(W, axis=1, keepdims=True)
    elif kind == KIND_NN_INTERSECTION:
        W /= W.sum(axis=1, keepdims=True)
    else:
        W -= 0.5
    kernel = ClassifierKernel(
        kind=kind,
        W=W,
        b=rng.normal(size=6),
        row_class=np.array([0, 1, 2, 3, 0, 2], dtype=np.int64),
        platt_a=-rng.random(6) * 5,
        platt_b=rng.normal(size=6),
        temperature=0.3,
        n_classes=K,
    )
    kern = simulated_belief.kernel_tuple(kernel)
    out_ptr = np.array([0, 1, 4, 7], dtype=np.int64)
    out_bin = np.array([3, 0, 0, 39, 5, 6, 7], dtype=np.int64)
    # Empty, counts, and tiny values whose squares underflow (kernel_proba rescales those).
    for start in (np.zeros(D), rng.integers(0, 4, D).astype(float), rng.random(D) * 1e-170):
        h = start.copy()
        S = np.empty(8)
        simulated_belief.scores_init(kern, h, S)
        for o in rng.integers(0, 3, 12):
            p_inc = simulated_belief.proba_scores(kern, h, S)
            p_ref = kernel_proba(
                kind, W, kernel.b, kernel.row_class, kernel.platt_a, kernel.platt_b, 0.3, K, h
            )
            np.testing.assert_allclose(p_inc, p_ref, rtol=0, atol=1e-9)
            simulated_belief.scores_add(kern, out_ptr, out_bin, int(o), h, S)
        if kind != KIND_NN_INTERSECTION:
            assert S[6] == pytest.approx(h.sum()) and S[7] == pytest.approx(h @ h)


def test_per_class_backoff_follows_its_reference(synth) -> None:
    """planner.eq4_sampling = "per_class": y from the full p(y|h), its own row, else its
    action-only row, else nothing; frequencies (nothing included) match the reference."""
    from activetouch.planning.observation_model import outcome_probabilities_per_class

    m = synth.model
    mt, kern, counts, p_y, S = _sampler_at(synth, 5)
    # A (cell, action) where some but not all classes have a tally row: the two readings differ.
    by_pair = _classes_per_pair(m)
    cell, action = next(p for p, n in by_pair.items() if n < m.n_classes)
    counters = np.zeros(3, dtype=np.int64)
    mcts_kernels.seed_numba(7)
    n = 20000
    draws = _draws(n, mt, kern, action, cell, counts, S, counters, True)
    expect = outcome_probabilities_per_class(m, cell, action, p_y)
    freq = np.bincount(draws[draws >= 0], minlength=m.n_outcomes) / n
    assert np.abs(freq - expect).max() < 0.02
    assert abs(np.mean(draws < 0) - (1.0 - expect.sum())) < 0.02
    # The renormalising reading never answers "nothing" when some class has a row.
    assert not np.allclose(expect, outcome_probabilities(m, cell, action, p_y))


def test_tempered_eq4_draws_classes_from_the_flattened_belief(synth) -> None:
    """planner.belief_temperature tau: the sampler's outcome frequencies follow Eq. 4's
    reference with p(y|h)^(1/tau) normalised in place of p(y|h); tau = 1 is Eq. 4 itself."""
    m = synth.model
    mt, kern, counts, p_y, S = _sampler_at(synth, 3)
    by_pair = _classes_per_pair(m)
    cell, action = max(by_pair, key=by_pair.get)  # the pair most classes answer
    tau = 4.0
    flat = p_y ** (1 / tau) / np.sum(p_y ** (1 / tau))
    np.testing.assert_allclose(mcts_kernels._tempered(p_y, 1 / tau), flat, atol=1e-12)
    assert mcts_kernels._tempered(p_y, 1.0) is p_y
    expect = outcome_probabilities(m, cell, action, flat)
    assert np.abs(expect - outcome_probabilities(m, cell, action, p_y)).max() > 0.05
    mcts_kernels.seed_numba(11)
    counters = np.zeros(3, dtype=np.int64)
    n = 20000
    draws = _draws(n, mt, kern, action, cell, counts, S, counters, False, 1 / tau)
    freq = np.bincount(draws, minlength=m.n_outcomes) / n
    assert np.abs(freq - expect).max() < 0.02
    with pytest.raises(PlanningError, match="temperature"):
        TreeSearch(m, synth.kernel).search(
            0,
            NO_POSES,
            counts,
            np.zeros(0, np.int64),
            horizon=2,
            simulations=5,
            rng=np.random.default_rng(0),
            belief_temperature=0.0,
        )
