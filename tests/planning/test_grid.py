import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from activetouch.config import GridConfig
from activetouch.planning.grid import (
    look_at_quaternion,
    object_grids,
    shared_grid,
    training_grid,
)


def test_palm_faces_centre_and_lies_on_ellipsoid():
    ext = np.array([0.08, 0.12, 0.2])
    cfg = GridConfig()
    g = training_grid(ext, cfg)
    assert len(g) > 20
    radii = ext / 2 + cfg.margin_m
    for pose in g.poses:
        z_axis = Rotation.from_quat(pose[3:]).as_matrix()[:, 2]
        towards_centre = -pose[:3] / np.linalg.norm(pose[:3])
        np.testing.assert_allclose(z_axis, towards_centre, atol=1e-9)
        palm = pose[:3] + z_axis * cfg.palm_offset_m
        assert np.sum((palm / radii) ** 2) == pytest.approx(1.0, abs=1e-9)


def test_rolls_make_distinct_orientations_and_ids_are_unique():
    g = training_grid(np.array([0.1, 0.1, 0.1]), GridConfig(rolls_deg=[0.0, 90.0]))
    assert len(np.unique(g.pose_ids)) == len(g)
    keys = {tuple(np.round(p, 6)) for p in g.poses}
    assert len(keys) == len(g)


def test_poses_below_the_table_are_dropped_but_ids_stay_stable():
    low = GridConfig(min_elevation_deg=-50.0)
    full = training_grid(np.array([0.1, 0.1, 0.1]), low)
    assert np.all(full.poses[:, 2] + 0.05 >= low.min_wrist_height_m)
    # Same directions, so the ids of kept poses match the default grid's where they overlap.
    default = training_grid(np.array([0.1, 0.1, 0.1]), GridConfig())
    assert len(full) >= len(default)


def test_finer_step_gives_more_poses():
    coarse = training_grid(np.array([0.1, 0.1, 0.1]), GridConfig(step_deg=45))
    fine = training_grid(np.array([0.1, 0.1, 0.1]), GridConfig(step_deg=25))
    assert len(fine) > len(coarse)


def test_bad_extents_are_rejected():
    with pytest.raises(ValueError):
        training_grid(np.array([0.1, 0.0, 0.1]), GridConfig())


def test_look_at_straight_down_is_well_defined():
    q = look_at_quaternion(np.array([0.0, 0.0, -1.0]), 0.0)
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix()[:, 2], [0, 0, -1], atol=1e-12)


def test_shared_grid_is_the_union_with_stable_content_ids():
    cfg = GridConfig()
    small, big = np.array([0.06, 0.06, 0.1]), np.array([0.2, 0.2, 0.25])
    both = shared_grid({"a": small, "b": big}, cfg)
    own_a, own_b = training_grid(small, cfg), training_grid(big, cfg)
    assert len(both) == len(own_a) + len(own_b)
    assert len(np.unique(both.pose_ids)) == len(both)
    # Adding an object keeps the ids (and poses) of the ones already there.
    more = shared_grid({"a": small, "b": big, "c": np.array([0.1, 0.1, 0.1])}, cfg)
    assert set(both.pose_ids.tolist()) <= set(more.pose_ids.tolist())
    ids = dict(zip(more.pose_ids.tolist(), map(tuple, more.poses), strict=True))
    for pid, pose in zip(both.pose_ids.tolist(), both.poses, strict=True):
        assert ids[pid] == tuple(pose)
    # Equal objects contribute equal poses once.
    assert len(shared_grid({"a": small, "a2": small}, cfg)) == len(own_a)


def test_object_grids_follow_the_layout():
    ext = {"a": np.array([0.06, 0.06, 0.1]), "b": np.array([0.2, 0.2, 0.25])}
    shared = object_grids(ext, GridConfig(layout="shared"))
    assert shared["a"] is shared["b"]
    own = object_grids(ext, GridConfig(layout="per_object"))
    np.testing.assert_array_equal(own["a"].poses, training_grid(ext["a"], GridConfig()).poses)


def test_center_offset_puts_the_object_between_fingers_and_thumb() -> None:
    """With `center_offset_m` the object centre lies on the hand's approach axis shifted to
    hand x = +offset (between the pointer fingers at +0.06 and the thumb at -0.03), at the
    same distance along the hand's z as without it."""
    from activetouch.config import GridConfig
    from activetouch.planning.grid import training_grid

    ext = np.array([0.1, 0.12, 0.08])
    base = training_grid(ext, GridConfig())
    moved = training_grid(ext, GridConfig(center_offset_m=0.015))
    # The hand moves by the offset, so a pose may drop below min_wrist_height: compare by id.
    assert set(moved.pose_ids) <= set(base.pose_ids) and len(moved) > 0.8 * len(base)
    where = {int(p): i for i, p in enumerate(base.pose_ids)}
    for pid, p1 in zip(moved.pose_ids, moved.poses, strict=True):
        p0 = base.poses[where[int(pid)]]
        R = Rotation.from_quat(p1[3:]).as_matrix()
        centre_in_hand = R.T @ (np.zeros(3) - p1[:3])
        centre_in_hand0 = Rotation.from_quat(p0[3:]).as_matrix().T @ (-p0[:3])
        np.testing.assert_allclose(centre_in_hand[:2], [0.015, 0.0], atol=1e-9)
        np.testing.assert_allclose(centre_in_hand[2], centre_in_hand0[2], atol=1e-9)


def test_small_object_overrides_load() -> None:
    from activetouch.config import load_config
    from activetouch.planning.grid import SMALL_OBJECT_GRID, small_object_overrides

    cfg = load_config(None, small_object_overrides())
    for k, v in SMALL_OBJECT_GRID.items():
        assert getattr(cfg.grid, k) == v
