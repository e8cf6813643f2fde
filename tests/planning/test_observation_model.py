from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chisquare

from activetouch.config import ObservationConfig
from activetouch.errors import ConfigError, DataError
from activetouch.planning.observation_builder import build_observation_model, pose_spread
from activetouch.planning.observation_model import (
    ObservationModel,
    canonical_quat,
    discretise,
    movement_cost,
    outcome_probabilities,
    relative_pose,
    rotation_angle,
    sample_outcome,
)
from activetouch.recognition.histogram import HistogramSpec

IDENTITY = [0.0, 0.0, 0.0, 1.0]
# Three poses 0.13 m apart along x (translation cells 0, 2, 4), one off to the side.
P0, P1, P2 = (np.array([x, 0.0, 0.0, *IDENTITY]) for x in (0.0, 0.13, 0.26))
P3 = np.array([0.0, 0.3, 0.0, *IDENTITY])
# Triangles (l0, l1, a0) in distinct cells of 0.08: (0,0,18), (1,1,25), (1,0,32).
T1 = [0.05, 0.04, 1.5]
T3 = [0.10, 0.09, 2.0]
T4 = [0.13, 0.05, 2.6]
SPEC = HistogramSpec(lo=np.array([0.0, 0.0, 1.0]), hi=np.array([0.2, 0.2, 3.2]), bins=2)


def tri(*rows: list[float]) -> np.ndarray:
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def hand_built() -> list[tuple[str, np.ndarray, list[np.ndarray]]]:
    a = ("a", np.stack([P0, P1, P2]), [tri(T1, T1), tri(T1, T3), tri(T4)])
    b = ("b", np.stack([P0, P1, P3]), [tri(T1), tri(T4, T4, T3), tri()])
    return [a, b]


def action_of(model: ObservationModel, src: np.ndarray, dst: np.ndarray) -> int:
    p, q = model.pose_index_of(src), model.pose_index_of(dst)
    actions, targets = model.actions_from(p)
    return int(actions[list(targets).index(q)])


def row(model: ObservationModel, y: int, action: int, cell: int) -> dict[int, float]:
    code = (y * model.n_actions + action) * model.n_cells + cell
    r = int(np.searchsorted(model.tally_key, code))
    assert model.tally_key[r] == code
    lo, hi = model.tally_ptr[r], model.tally_ptr[r + 1]
    pmf = np.diff(np.concatenate([[0.0], model.tally_cum[lo:hi]]))
    return dict(zip(model.tally_out[lo:hi].tolist(), pmf.tolist(), strict=True))


def has_row(model: ObservationModel, y: int, action: int, cell: int) -> bool:
    code = (y * model.n_actions + action) * model.n_cells + cell
    return code in set(model.tally_key.tolist())


def triangle_outcome(model: ObservationModel, t: list[float]) -> int:
    c = int(model.cells_of(tri(t))[0])
    b = int(SPEC.bin_index(tri(t))[0])
    hits = [
        o
        for o in range(model.n_outcomes)
        if model.out_cell[o] == c and model.out_bin[model.out_ptr[o] : model.out_ptr[o + 1]] == [b]
    ]
    assert len(hits) == 1
    return hits[0]


def test_pose_math_properties() -> None:
    rng = np.random.default_rng(0)
    a = np.concatenate([rng.normal(size=(50, 3)), Rotation.random(50, random_state=1).as_quat()], 1)
    b = np.concatenate([rng.normal(size=(50, 3)), Rotation.random(50, random_state=2).as_quat()], 1)
    rel = relative_pose(a, b)
    ra, rb = Rotation.from_quat(a[:, 3:]), Rotation.from_quat(b[:, 3:])
    # b = a o rel
    np.testing.assert_allclose(ra.apply(rel[:, :3]) + a[:, :3], b[:, :3], atol=1e-12)
    np.testing.assert_allclose(
        (ra * Rotation.from_quat(rel[:, 3:])).as_matrix(), rb.as_matrix(), atol=1e-12
    )
    assert np.all(rel[:, 6] >= 0)
    np.testing.assert_allclose(relative_pose(a, a)[:, 3:], np.tile(IDENTITY, (50, 1)), atol=1e-12)
    np.testing.assert_allclose(relative_pose(a, a)[:, :3], 0.0, atol=1e-12)
    # Broadcasting one pose against many.
    np.testing.assert_allclose(relative_pose(a[0], b), relative_pose(np.tile(a[0], (50, 1)), b))

    cost = movement_cost(rel, 5.0)
    assert np.all((cost >= 0) & (cost <= 1))
    np.testing.assert_allclose(cost, movement_cost(relative_pose(b, a), 5.0), atol=1e-12)
    flipped = rel.copy()
    flipped[:, 3:] *= -1
    np.testing.assert_allclose(movement_cost(flipped, 5.0), cost)
    assert movement_cost(np.array([[0, 0, 0, *IDENTITY]]), 1.0)[0] == 0.0
    assert movement_cost(np.array([[0.3, 0.4, 0, *IDENTITY]]), 0.5)[0] == pytest.approx(0.5)
    assert movement_cost(np.array([[3.0, 0, 0, *IDENTITY]]), 0.5)[0] == pytest.approx(0.5)
    half_turn = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])
    assert movement_cost(half_turn, 1.0)[0] == pytest.approx(0.5)
    assert rotation_angle(Rotation.from_rotvec([0, 0.7, 0]).as_quat()) == pytest.approx(0.7)


def test_discretise_and_canonical_quat() -> None:
    np.testing.assert_allclose(
        discretise(np.array([0.119, -0.119, 0.12, 0.0599, -0.0001]), 0.06),
        [0.06, -0.06, 0.12, 0.0, 0.0],
        atol=1e-15,
    )
    q = canonical_quat(np.array([[0.1, 0.2, 0.3, -0.9], [-1.0, 0.0, 0.0, 0.0], [0, -1, 0, 0]]))
    assert q[0, 3] > 0 and q[1, 0] > 0 and q[2, 1] > 0
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)


def test_hand_built_triangle_tallies() -> None:
    m = build_observation_model(
        hand_built(), SPEC, ObservationConfig(action_frame="relative", granularity="triangle")
    )
    m.validate()
    assert m.class_names == ("a", "b") and m.n_bins == 8
    assert m.n_poses == 4 and len(m.edge_action) == 4 * 3
    for p in range(4):
        _, targets = m.actions_from(p)
        assert sorted(targets.tolist()) == sorted(set(range(4)) - {p})
    a_plus = action_of(m, P0, P1)
    assert action_of(m, P1, P2) == a_plus  # same relative pose, same action
    a_pp, a_minus = action_of(m, P0, P2), action_of(m, P1, P0)
    assert action_of(m, P2, P1) == a_minus
    np.testing.assert_allclose(m.action_delta[a_plus], [0.12, 0, 0, 0, 0, 0, 1.0])
    c1, c3, c4 = m.cells_of(tri(T1, T3, T4)).tolist()
    assert m.n_cells == 3 and m.cells_of(tri([0.3, 0.3, 0.1])).tolist() == [-1]
    o1, o3, o4 = (triangle_outcome(m, t) for t in (T1, T3, T4))
    assert m.n_outcomes == 3

    # Class a, action +0.13: pair (0 -> 1) weighs n_0(c1) = 2, pair (1 -> 2) weighs 1.
    assert row(m, 0, a_plus, c1) == pytest.approx({o1: 0.4, o3: 0.4, o4: 0.2})
    assert row(m, 0, a_plus, c3) == pytest.approx({o4: 1.0})
    assert not has_row(m, 0, a_plus, c4)  # nothing lies beyond pose 2
    assert row(m, 0, a_pp, c1) == pytest.approx({o4: 1.0})
    assert row(m, 0, a_minus, c1) == pytest.approx({o1: 1.0})
    assert row(m, 0, a_minus, c4) == pytest.approx({o1: 0.5, o3: 0.5})
    # Class b: grasp 0 (one T1) -> grasp 1 (T4, T4, T3).
    assert row(m, 1, a_plus, c1) == pytest.approx({o4: 2 / 3, o3: 1 / 3})

    # Eq. 4 mixture, both classes have a row.
    p_y = np.array([0.3, 0.7])
    want = np.zeros(3)
    want[[o1, o3, o4]] = 0.3 * np.array([0.4, 0.4, 0.2]) + 0.7 * np.array([0, 1 / 3, 2 / 3])
    np.testing.assert_allclose(outcome_probabilities(m, c1, a_plus, p_y), want)
    # Only class a has a row for (a+, c3): p_y is renormalised onto it.
    np.testing.assert_allclose(outcome_probabilities(m, c3, a_plus, p_y)[o4], 1.0)
    # No class has (a+, c4): marginal rows. a: pairs (0->1) {T1, T3}, (1->2) {T4};
    # b: (0->1) {T4, T4, T3}.
    want = np.zeros(3)
    want[[o1, o3, o4]] = 0.3 * np.array([1, 1, 1]) / 3 + 0.7 * np.array([0, 1 / 3, 2 / 3])
    np.testing.assert_allclose(outcome_probabilities(m, c4, a_plus, p_y), want)
    np.testing.assert_allclose(outcome_probabilities(m, -1, a_plus, p_y), want)
    # Pose 3 exists only in class b, pose 2 only in class a: no data for that action.
    a_none = action_of(m, P2, P3)
    rng = np.random.default_rng(0)
    assert sample_outcome(m, c1, a_none, p_y, rng) == -1
    assert not outcome_probabilities(m, c1, a_none, p_y).any()
    # A class the classifier rules out is never drawn.
    draws = {sample_outcome(m, c1, a_plus, np.array([1.0, 0.0]), rng) for _ in range(200)}
    assert draws == {o1, o3, o4}
    draws = {sample_outcome(m, c1, a_plus, np.array([0.0, 1.0]), rng) for _ in range(200)}
    assert draws == {o3, o4}


def test_hand_built_grasp_tallies() -> None:
    m = build_observation_model(
        hand_built(), SPEC, ObservationConfig(action_frame="relative", granularity="grasp")
    )
    m.validate()
    a_plus = action_of(m, P0, P1)
    c1, c3, c4 = m.cells_of(tri(T1, T3, T4)).tolist()
    # Outcomes are (grasp, cell) pairs of grasps with triangles: a: g0{c1}, g1{c1,c3}, g2{c4};
    # b: g0{c1}, g1{c4,c3}.
    assert m.n_outcomes == 7
    bins = SPEC.bin_index(tri(T1, T3, T4)).tolist()

    def outcome(cell: int, grasp_bins: list[int]) -> int:
        hits = [
            o
            for o in range(m.n_outcomes)
            if m.out_cell[o] == cell
            and sorted(m.out_bin[m.out_ptr[o] : m.out_ptr[o + 1]].tolist()) == sorted(grasp_bins)
        ]
        assert len(hits) == 1
        return hits[0]

    a1_c1, a1_c3 = outcome(c1, [bins[0], bins[1]]), outcome(c3, [bins[0], bins[1]])
    a2_c4 = outcome(c4, [bins[2]])
    b1_c4 = outcome(c4, [bins[2], bins[2], bins[1]])
    b1_c3 = outcome(c3, [bins[2], bins[2], bins[1]])
    # a: (0 -> 1) weighs n_0(c1) = 2 times n_1(c') = 1 each; (1 -> 2) weighs 1 * 1.
    assert row(m, 0, a_plus, c1) == pytest.approx({a1_c1: 0.4, a1_c3: 0.4, a2_c4: 0.2})
    # b: (0 -> 1): grasp 1 has two triangles in c4, one in c3.
    assert row(m, 1, a_plus, c1) == pytest.approx({b1_c4: 2 / 3, b1_c3: 1 / 3})
    probs = outcome_probabilities(m, c1, a_plus, np.array([0.5, 0.5]))
    assert probs.sum() == pytest.approx(1.0)
    assert probs[b1_c4] == pytest.approx(1 / 3)


def random_objects(
    rng: np.random.Generator, n_objects: int = 3
) -> list[tuple[str, np.ndarray, list[np.ndarray]]]:
    # A regular grid (three positions x two yaws), so many pose pairs share an action, and
    # few triangle cells, so grasps hold several triangles per cell: the n_i(c) weights matter.
    yaws = Rotation.from_rotvec([[0, 0, 0], [0, 0, np.pi / 2]]).as_quat()
    grid = np.array([[x, 0.0, 0.0, *q] for x in (0.0, 0.13, 0.26) for q in yaws])
    objs = []
    for k in range(n_objects):
        pick = rng.choice(len(grid), size=len(grid) - 1, replace=False)
        tris = [
            np.column_stack(
                [rng.uniform(0.0, 0.2, n), rng.uniform(0.0, 0.2, n), rng.uniform(1.0, 1.3, n)]
            )
            for n in rng.integers(0, 9, len(pick))
        ]
        objs.append((f"obj{k}", grid[pick], tris))
    return objs


@pytest.mark.parametrize("granularity", ["triangle", "grasp"])
def test_tallies_match_brute_force(granularity: str) -> None:
    rng = np.random.default_rng(11)
    objs = random_objects(rng)
    m = build_observation_model(
        objs, SPEC, ObservationConfig(action_frame="relative", granularity=granularity)
    )
    m.validate()
    # Outcome ids by what they are, to rebuild the tallies with plain loops and dicts.
    out_of: dict[tuple, int] = {}
    for o in range(m.n_outcomes):
        out_of[
            (int(m.out_cell[o]), *sorted(m.out_bin[m.out_ptr[o] : m.out_ptr[o + 1]].tolist()))
        ] = o
    counts: dict[tuple[int, int, int], dict[int, float]] = defaultdict(lambda: defaultdict(float))
    marg: dict[tuple[int, int], dict[int, float]] = defaultdict(lambda: defaultdict(float))
    for y, (_, poses, tris) in enumerate(objs):
        for i in range(len(poses)):
            for j in range(len(poses)):
                pi, pj = m.pose_index_of(poses[i]), m.pose_index_of(poses[j])
                if pi == pj:
                    continue
                acts, targets = m.actions_from(pi)
                a = int(acts[list(targets).index(pj)])
                cells_j = m.cells_of(tris[j]).tolist()
                bins_j = SPEC.bin_index(tris[j]).tolist() if len(tris[j]) else []
                outs = []
                for cj, bj in zip(cells_j, bins_j, strict=True):
                    key = (cj, bj) if granularity == "triangle" else (cj, *sorted(bins_j))
                    outs.append(out_of[key])
                for o in outs:
                    marg[(y, a)][o] += 1
                for ci in m.cells_of(tris[i]).tolist():
                    for o in outs:
                        counts[(y, a, ci)][o] += 1
    got_rows = set()
    for r, code in enumerate(m.tally_key.tolist()):
        y, rest = divmod(code, m.n_actions * m.n_cells)
        a, c = divmod(rest, m.n_cells)
        want = counts[(y, a, c)]
        total = sum(want.values())
        assert row(m, y, a, c) == pytest.approx({o: v / total for o, v in want.items()})
        got_rows.add((y, a, c))
        assert m.tally_cum[m.tally_ptr[r + 1] - 1] == 1.0
    assert got_rows == {k for k, v in counts.items() if v}
    assert len(m.marg_key) == len([k for k, v in marg.items() if v])
    for r, code in enumerate(m.marg_key.tolist()):
        y, a = divmod(code, m.n_actions)
        lo, hi = m.marg_ptr[r], m.marg_ptr[r + 1]
        pmf = np.diff(np.concatenate([[0.0], m.marg_cum[lo:hi]]))
        total = sum(marg[(y, a)].values())
        want = {o: v / total for o, v in marg[(y, a)].items()}
        assert dict(zip(m.marg_out[lo:hi].tolist(), pmf.tolist(), strict=True)) == pytest.approx(
            want
        )


@pytest.mark.parametrize("granularity", ["triangle", "grasp"])
def test_sampling_matches_exact_mixture(granularity: str) -> None:
    rng = np.random.default_rng(5)
    objs = random_objects(rng)
    m = build_observation_model(
        objs, SPEC, ObservationConfig(action_frame="relative", granularity=granularity)
    )
    p_y = np.array([0.2, 0.5, 0.3])
    # Pick the (cell, action) with the most mixed classes and outcomes, plus a fallback query.
    codes = m.tally_key
    rest = codes % (m.n_actions * m.n_cells)
    a, c = np.divmod(rest, m.n_cells)
    pairs, n_classes = np.unique(a * m.n_cells + c, return_counts=True)
    best = pairs[np.argmax(n_classes)]
    queries = [(int(best % m.n_cells), int(best // m.n_cells)), (-1, int(a[0]))]
    for cell, action in queries:
        probs = outcome_probabilities(m, cell, action, p_y)
        assert probs.sum() == pytest.approx(1.0)
        n = 6000
        draws = np.array([sample_outcome(m, cell, action, p_y, rng) for _ in range(n)])
        support = np.flatnonzero(probs > 0)
        assert np.isin(draws, support).all()
        observed = np.bincount(draws, minlength=m.n_outcomes)[support]
        assert len(support) >= 2
        assert chisquare(observed, probs[support] * n).pvalue > 1e-3


def test_pose_dedupe_and_lookup() -> None:
    q = Rotation.from_rotvec([0, 0, 0.3]).as_quat()
    near = np.array([0.01, 0.0, 0.0, *q])
    flipped = np.array([0.02, 0.0, 0.0, *(-q)])  # same cell, same rotation with the other sign
    far = np.array([0.3, 0.0, 0.0, *q])
    objs = [("a", np.stack([near, far]), [tri(T1), tri(T3)]), ("b", flipped[None], [tri(T4)])]
    m = build_observation_model(
        objs, SPEC, ObservationConfig(granularity="triangle", action_frame="relative")
    )
    assert m.n_poses == 2
    np.testing.assert_allclose(m.pose_xyz[0], near[:3])  # the first pose met represents it
    assert m.pose_index_of(flipped) == 0
    assert m.pose_index_of(np.array([0.28, 0.01, 0.0, *q])) == 1
    assert m.max_translation == pytest.approx(0.29)
    assert np.all((m.action_cost >= 0) & (m.action_cost <= 1))
    # Each training pose's distance from the pose its pooled pose executes: the model's own.
    poses = np.stack([near, far, flipped])
    spread = pose_spread(poses, 0.06, ObservationConfig().quaternion_cell)
    executed = m.pose_xyz[[m.pose_index_of(p) for p in poses]]
    np.testing.assert_allclose(spread, np.linalg.norm(poses[:, :3] - executed, axis=1))
    np.testing.assert_allclose(spread, [0.0, 0.0, 0.01])
    np.testing.assert_allclose(pose_spread(poses, 0.01, 0.05), 0.0)  # finer cells: its own


def test_storage_round_trip_and_validation() -> None:
    m = build_observation_model(
        hand_built(), SPEC, ObservationConfig(action_frame="relative", granularity="grasp")
    )
    again = ObservationModel.from_parts(m.scalars(), m.arrays())
    assert again.scalars() == m.scalars()
    for k, v in m.arrays().items():
        np.testing.assert_array_equal(getattr(again, k), v)
    broken = dict(m.arrays(), tally_out=m.tally_out + m.n_outcomes)
    with pytest.raises(DataError, match="tally_out"):
        ObservationModel.from_parts(m.scalars(), broken)
    short = dict(m.arrays(), tally_cum=m.tally_cum[:-1])
    with pytest.raises(DataError, match="tally_cum"):
        ObservationModel.from_parts(m.scalars(), short)
    arrays = m.arrays()
    del arrays["edge_ptr"]
    with pytest.raises(DataError, match="lacks edge_ptr"):
        ObservationModel.from_parts(m.scalars(), arrays)


def test_bad_inputs() -> None:
    with pytest.raises(ConfigError, match="granularity"):
        build_observation_model(
            hand_built(), SPEC, ObservationConfig(action_frame="relative", granularity="pixel")
        )
    with pytest.raises(ConfigError, match="triangle_cell"):
        build_observation_model(
            hand_built(),
            SPEC,
            ObservationConfig(granularity="triangle", action_frame="relative", triangle_cell=0.0),
        )
    with pytest.raises(DataError, match="2 poses but 1"):
        build_observation_model(
            [("a", np.stack([P0, P1]), [tri(T1)])],
            SPEC,
            ObservationConfig(granularity="triangle", action_frame="relative"),
        )
    m = build_observation_model(
        hand_built(), SPEC, ObservationConfig(granularity="triangle", action_frame="relative")
    )
    with pytest.raises(ValueError, match="p_y"):
        outcome_probabilities(m, 0, action_of(m, P0, P1), np.array([1.0]))


# --- absolute actions (observation.action_frame = "absolute") ---------------------------------

# Class b's grid is class a's moved by 0.055 m in x: its pose near P1 lies in another
# translation cell (0.185 / 0.06 -> 3, 0.13 / 0.06 -> 2) but within absolute_near_m of P1.
B1 = np.array([0.185, 0.0, 0.0, *IDENTITY])


def absolute_objects() -> list[tuple[str, np.ndarray, list[np.ndarray]]]:
    a = ("a", np.stack([P0, P1, P2]), [tri(T1), tri(T3), tri(T4)])
    b = ("b", np.stack([P0, B1, P3]), [tri(T1), tri(T4, T4), tri(T3)])
    return [a, b]


def marg_row(model: ObservationModel, y: int, action: int) -> dict[int, float] | None:
    code = y * model.n_actions + action
    hits = np.flatnonzero(model.marg_key == code)
    if len(hits) == 0:
        return None
    lo, hi = model.marg_ptr[hits[0]], model.marg_ptr[hits[0] + 1]
    pmf = np.diff(np.concatenate([[0.0], model.marg_cum[lo:hi]]))
    return dict(zip(model.marg_out[lo:hi].tolist(), pmf.tolist(), strict=True))


def test_absolute_actions_give_every_class_near_the_target_a_row() -> None:
    m = build_observation_model(
        absolute_objects(), SPEC, ObservationConfig(granularity="triangle", action_frame="absolute")
    )
    assert m.action_frame == "absolute"
    assert m.n_poses == 5 and m.n_actions == 5  # one action per pooled pose: its own cell
    i0, i1, i2, i3, ib1 = (m.pose_index_of(p) for p in (P0, P1, P2, P3, B1))
    assert len({i0, i1, i2, i3, ib1}) == 5
    # Every edge into q carries q's action, whatever pose it leaves from.
    for q in range(m.n_poses):
        assert len(set(m.edge_action[m.edge_target == q].tolist())) == 1
    act = {q: int(m.edge_action[m.edge_target == q][0]) for q in range(m.n_poses)}
    assert len(set(act.values())) == m.n_poses
    o1, o3, o4 = (triangle_outcome(m, t) for t in (T1, T3, T4))
    # P1: a's own grasp (T3); b answers with its grasp at B1, 0.055 m away (T4).
    assert marg_row(m, 0, act[i1]) == pytest.approx({o3: 1.0})
    assert marg_row(m, 1, act[i1]) == pytest.approx({o4: 1.0})
    # B1: b's own grasp; a answers with its grasp at P1.
    assert marg_row(m, 0, act[ib1]) == pytest.approx({o3: 1.0})
    assert marg_row(m, 1, act[ib1]) == pytest.approx({o4: 1.0})
    # P0 is shared (T1 for both); P2 is 0.075 m from B1, P3 far from a: one class each.
    assert marg_row(m, 0, act[i0]) == marg_row(m, 1, act[i0]) == pytest.approx({o1: 1.0})
    assert marg_row(m, 0, act[i2]) == pytest.approx({o4: 1.0}) and marg_row(m, 1, act[i2]) is None
    assert marg_row(m, 1, act[i3]) == pytest.approx({o3: 1.0}) and marg_row(m, 0, act[i3]) is None
    # Tallies are conditioned on the cell of the other grasp i (never one at j's own pose):
    # b's pairs into P1 (j = B1) come from P0 (T1) and P3 (T3).
    c1, c3, c4 = (int(m.cells_of(tri(t))[0]) for t in (T1, T3, T4))
    assert row(m, 1, act[i1], c1) == pytest.approx({o4: 1.0})
    assert row(m, 1, act[i1], c3) == pytest.approx({o4: 1.0})
    assert not has_row(m, 1, act[i1], c4)
    assert row(m, 0, act[i1], c4) == pytest.approx({o3: 1.0})  # a's i at P2 -> j at P1
    # Without the nearness tolerance only exact cells count.
    exact = build_observation_model(
        absolute_objects(),
        SPEC,
        ObservationConfig(granularity="triangle", action_frame="absolute", absolute_near_m=0.0),
    )
    assert marg_row(exact, 1, act[i1]) is None and marg_row(exact, 0, act[ib1]) is None
    assert marg_row(exact, 0, act[i1]) == pytest.approx({o3: 1.0})


def test_edge_cost_is_the_cost_of_the_move() -> None:
    objs = absolute_objects()
    objs[1] = (
        "b",
        np.stack(
            [P0, B1, np.array([0.0, 0.3, 0.0, *Rotation.from_rotvec([0.0, 0.0, 1.2]).as_quat()])]
        ),
        objs[1][2],
    )
    rel = build_observation_model(
        objs, SPEC, ObservationConfig(granularity="triangle", action_frame="relative")
    )
    ab = build_observation_model(
        objs, SPEC, ObservationConfig(granularity="triangle", action_frame="absolute")
    )
    np.testing.assert_array_equal(ab.pose_xyz, rel.pose_xyz)
    # Relative actions: the paper's c_m(a) of the edge's action, derived rather than stored.
    assert len(rel.edge_cost) == 0
    np.testing.assert_array_equal(rel.edge_costs(), rel.action_cost[rel.edge_action])
    # Absolute actions: the cost of the exact move p -> q, edge by edge.
    src = np.repeat(np.arange(ab.n_poses), np.diff(ab.edge_ptr))
    pooled = np.concatenate([ab.pose_xyz, ab.pose_quat], axis=1)
    want = movement_cost(relative_pose(pooled[src], pooled[ab.edge_target]), ab.max_translation)
    np.testing.assert_allclose(ab.edge_cost, want, atol=1e-12)
    assert len(set(np.round(ab.edge_cost[ab.edge_action == ab.edge_action[0]], 9))) > 1
    # Saved and loaded, the edge costs and the frame survive.
    again = ObservationModel.from_parts(ab.scalars(), ab.arrays())
    assert again.action_frame == "absolute"
    np.testing.assert_array_equal(again.edge_costs(), ab.edge_cost)
    # A model saved before edge_cost existed derives it from its actions; one saved with
    # int64 edges and stored relative costs (before they were derived) loads as it was.
    old = {k: v for k, v in rel.arrays().items() if k != "edge_cost"}
    scal = {k: v for k, v in rel.scalars().items() if k != "action_frame"}
    loaded = ObservationModel.from_parts(scal, old)
    assert loaded.action_frame == "relative"
    np.testing.assert_array_equal(loaded.edge_costs(), rel.edge_costs())
    wide = dict(
        rel.arrays(),
        edge_action=rel.edge_action.astype(np.int64),
        edge_target=rel.edge_target.astype(np.int64),
        edge_cost=rel.edge_costs(),
    )
    np.testing.assert_array_equal(
        ObservationModel.from_parts(rel.scalars(), wide).edge_costs(), rel.edge_costs()
    )
    with pytest.raises(DataError, match="edge_cost"):
        ObservationModel.from_parts(ab.scalars(), dict(ab.arrays(), edge_cost=ab.edge_cost[:-1]))
    with pytest.raises(ConfigError, match="action_frame"):
        build_observation_model(
            objs, SPEC, ObservationConfig(granularity="triangle", action_frame="polar")
        )


@pytest.mark.parametrize("frame", ["relative", "absolute"])
def test_edges_built_in_blocks_are_the_edges_built_at_once(frame: str, monkeypatch) -> None:
    """The builder keys the all-pairs edges a block of source poses at a time (to keep memory
    bounded at thousands of poses); any block size gives the same model to the bit."""
    import activetouch.planning.observation_builder as om

    rng = np.random.default_rng(5)
    P = 40
    xyz = rng.uniform(-0.3, 0.3, (P, 3))
    quat = Rotation.random(P, random_state=6).as_quat()
    objs = [
        (f"o{k}", np.concatenate([xyz, quat], axis=1)[k::2], [tri([0.1, 0.1, 1.1])] * (P // 2))
        for k in range(2)
    ]
    cfg = ObservationConfig(granularity="triangle", action_frame=frame)
    whole = build_observation_model(objs, SPEC, cfg)
    assert whole.edge_action.dtype == np.int32 and whole.edge_target.dtype == np.int32
    calls = []

    def in_blocks(*a, **k):
        calls.append(1)
        return om_all_pairs(*a, **{**k, "chunk_edges": 97})

    om_all_pairs = om._all_pairs_edges
    monkeypatch.setattr(om, "_all_pairs_edges", in_blocks)
    blocks = build_observation_model(objs, SPEC, cfg)
    assert calls and P * (P - 1) // 97 > 10
    for name, arr in whole.arrays().items():
        np.testing.assert_array_equal(getattr(blocks, name), arr, err_msg=name)
    assert blocks.max_translation == whole.max_translation
    # Relative actions: the discretised pose of q in p's frame, edge by edge.
    if frame == "relative":
        src = np.repeat(np.arange(whole.n_poses), whole.n_poses - 1)
        pooled = np.concatenate([whole.pose_xyz, whole.pose_quat], axis=1)
        delta = relative_pose(pooled[src], pooled[whole.edge_target])
        want = np.concatenate(
            [discretise(delta[:, :3], 0.06), discretise(delta[:, 3:], 0.05)], axis=1
        )
        np.testing.assert_allclose(whole.action_delta[whole.edge_action], want, atol=1e-12)


def test_cells_follow_the_librarys_sizes_and_the_setting_when_asked() -> None:
    from activetouch.config import Config
    from activetouch.planning.grid import shared_grid
    from activetouch.planning.observation_builder import cells_for_library

    grid = Config().grid
    one = shared_grid({"a": np.array([0.08, 0.08, 0.10])}, grid).poses
    # Two sizes 2.2 cm apart on every ray: 6 cm cells pool each ray's two poses together.
    two = shared_grid(
        {"a": np.array([0.08, 0.08, 0.10]), "b": np.array([0.124, 0.124, 0.144])}, grid
    ).poses
    oc = ObservationConfig()
    assert oc.cells_from == "library" and oc.translation_cell_m == 0.06
    assert cells_for_library(one, oc) == 0.06  # one size: nothing to tell apart
    cell = cells_for_library(two, oc)
    assert cell < 0.06 and pose_spread(two, cell, oc.quaternion_cell).max() <= 0.015
    coarser = [c for c in (0.06, 0.04, 0.03, 0.02, 0.015) if c > cell]
    assert all(pose_spread(two, c, oc.quaternion_cell).max() > 0.015 for c in coarser)
    fixed = ObservationConfig(cells_from="setting")
    assert cells_for_library(two, fixed) == 0.06
    with pytest.raises(ConfigError, match="max_pose_shift_m"):
        cells_for_library(two, ObservationConfig(max_pose_shift_m=0.0))
