"""The synthetic problem behind the planner's tests and `bench planner`."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.planning.synthetic import QUATERNION_CELL, TRANSLATION_CELL_M, synthetic_problem


def test_every_edge_is_its_discretised_relative_pose() -> None:
    """Each edge's action holds the authors' discretisation of the target's pose in the source's
    frame, also for moves of several metres (100 classes put spheres up to 2.1 m apart, where
    translation cells reach +-70), and different moves never share an action."""
    m = synthetic_problem(240, 100, rng=np.random.default_rng(3)).model
    P = m.n_poses
    assert m.edge_action.dtype == np.int32 and m.edge_target.dtype == np.int32
    src = np.repeat(np.arange(P), P - 1)
    tgt = m.edge_target.astype(np.int64)
    np.testing.assert_array_equal(
        tgt, np.concatenate([np.delete(np.arange(P), p) for p in range(P)])
    )
    r_src = Rotation.from_quat(m.pose_quat[src])
    t_rel = r_src.inv().apply(m.pose_xyz[tgt] - m.pose_xyz[src])
    q_rel = (r_src.inv() * Rotation.from_quat(m.pose_quat[tgt])).as_quat()
    q_rel *= np.where(q_rel[:, 3:4] < 0, -1.0, 1.0)
    cells = np.concatenate(
        [np.trunc(t_rel / TRANSLATION_CELL_M), np.trunc(q_rel / QUATERNION_CELL)], axis=1
    )
    got = np.round(
        m.action_delta[m.edge_action] / ([TRANSLATION_CELL_M] * 3 + [QUATERNION_CELL] * 4)
    )
    # scipy and the builder round differently at a cell's edge (and flip q's sign when w ~ 0):
    # translations differ by one cell at most, and nearly every edge agrees exactly.
    assert np.abs(got[:, :3] - cells[:, :3]).max() <= 1
    assert np.all(got == cells, axis=1).mean() > 0.98
    # ... including moves beyond 64 cells, which a base-128 key carried into the next cell.
    assert (np.abs(cells[:, :3]) > 64).any()
    # One action, one discretised move: the actions' deltas are distinct.
    assert len(np.unique(m.action_delta, axis=0)) == m.n_actions
