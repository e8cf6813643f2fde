"""The errors a free-standing object and stale calibration add to the twin: the object
nudged by a grasp, fingers whose angles read off, sensors whose zeros drift."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from activetouch.config import Config
from activetouch.errors import ConfigError, UnreachableError
from activetouch.interfaces import Pose
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.grid import training_grid
from activetouch.sim.nudge import nudge_step, shrink_until_clear
from activetouch.sim.twin import open_twin


def test_a_lone_push_slides_the_object_the_whole_bound_a_balanced_grip_not_at_all():
    np.testing.assert_allclose(nudge_step(np.array([[0.002, 0.0, 0.0]]), 0.01), [0.01, 0.0])
    balanced = np.array([[0.001, 0.0, 0.0], [-0.001, 0.0, 0.0], [0.0, 0.0, -0.003]])
    np.testing.assert_allclose(nudge_step(balanced, 0.01), [0.0, 0.0], atol=1e-15)
    two_thirds = nudge_step(np.array([[0.002, 0.0, 0.0], [-0.001, 0.0, 0.0], [0, 0.0, 0]]), 0.03)
    np.testing.assert_allclose(two_thirds, [0.01, 0.0])  # net 1 of 3 units of push
    assert not nudge_step(np.zeros((0, 3)), 0.01).any()
    assert not nudge_step(np.array([[1.0, 0, 0]]), 0.0).any()


def test_a_slide_that_would_meet_the_hand_is_halved_until_clear():
    tried = []

    def clear(s):
        tried.append(float(s[0]))
        return s[0] <= 0.003

    np.testing.assert_allclose(shrink_until_clear(np.array([0.01, 0.0]), clear), [0.0025, 0])
    assert tried == [0.01, 0.005, 0.0025]
    assert not shrink_until_clear(np.array([0.01, 0.0]), lambda s: not s.any()).any()


@pytest.fixture(scope="module")
def can(tmp_path_factory):
    d = tmp_path_factory.mktemp("nudge")
    mesh_file = d / "can.obj"
    trimesh.creation.cylinder(radius=0.035, height=0.12, sections=48).export(mesh_file)
    return ObjectLibrary(d / "objects").add("can", mesh_file)


def _grasps(can, cfg, seed=0, every=6):
    """(grasp, object offset after it) at every `every`-th reachable training pose."""
    out = []
    with open_twin(can, cfg.sim, seed=seed) as twin:
        for pose in training_grid(can.extents, cfg.grid).poses[::every]:
            twin.hand.open()
            try:
                twin.wrist.move_to(Pose.from_array(pose))
            except UnreachableError:
                continue
            g = twin.hand.guarded_close()
            twin.hand.open()
            assert twin.world.object_clear_of_hand(cfg.sim.wrist_penetration_tol_m)
            out.append((g, twin.world.object.offset.copy()))
    return out


def test_the_free_object_slides_on_the_table_up_to_the_bound_per_grasp(can):
    fixed = _grasps(can, Config())
    assert all(not off.any() for _, off in fixed)  # the paper's fixed object
    cfg = Config()
    cfg.sim.nudge_max_m = 0.01
    free = _grasps(can, cfg)
    offsets = np.array([np.zeros(3)] + [off for _, off in free])
    slides = np.linalg.norm(np.diff(offsets, axis=0), axis=1)
    assert np.all(slides <= 0.01 + 1e-12) and np.all(offsets[:, 2] == 0.0)
    assert (slides > 1e-4).sum() >= len(slides) // 2  # most grasps push it
    # The first grasp is felt before any push: it is the fixed object's grasp.
    np.testing.assert_array_equal(free[0][0].sensor_ids, fixed[0][0].sensor_ids)


def test_offset_fingers_report_their_contacts_where_they_believe_they_are(can):
    base = _grasps(can, Config())
    cfg = Config()
    cfg.sim.fault_finger_offset_rad = 0.05
    off = _grasps(can, cfg)
    moved = 0
    for (g0, _), (g1, _) in zip(base, off, strict=True):
        np.testing.assert_array_equal(g0.sensor_ids, g1.sensor_ids)  # the same physics
        d = np.asarray(g1.finger_angles) - np.asarray(g0.finger_angles)
        assert np.all(np.abs(d) <= 0.05) and np.ptp(d) > 0  # one offset per finger
        palm = g0.sensor_ids >= 27
        np.testing.assert_allclose(g1.xyz[palm], g0.xyz[palm])
        moved += int(np.abs(g1.xyz[~palm] - g0.xyz[~palm]).max(initial=0) > 1e-3)
    assert moved >= len(base) // 2


def test_nudge_out_of_range_is_a_config_error(can):
    cfg = Config()
    cfg.sim.nudge_max_m = 0.5
    with pytest.raises(ConfigError, match="nudge_max_m"), open_twin(can, cfg.sim, seed=0):
        pass
