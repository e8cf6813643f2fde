"""The twin as a whole: an imported mesh becomes an object the hand can grasp."""

from __future__ import annotations

import numpy as np
import trimesh

from activetouch.config import Config
from activetouch.errors import UnreachableError
from activetouch.interfaces import Pose
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.grid import training_grid
from activetouch.sim.twin import open_twin


def test_imported_obj_is_grasped_at_its_training_poses(tmp_path):
    mesh_file = tmp_path / "can.obj"
    trimesh.creation.cylinder(radius=0.035, height=0.12, sections=48).export(mesh_file)
    lib = ObjectLibrary(tmp_path / "objects")
    spec = lib.add("can", mesh_file)
    np.testing.assert_allclose(spec.extents, [0.07, 0.07, 0.12], atol=2e-3)
    cfg = Config()
    grid = training_grid(spec.extents, cfg.grid)
    contacts = []
    with open_twin(spec, cfg.sim, seed=0) as twin:
        for pose in grid.poses[::4]:
            twin.hand.open()
            try:
                twin.wrist.move_to(Pose.from_array(pose))
            except UnreachableError:  # over the table: skipped, as in training
                continue
            contacts.append(twin.hand.guarded_close().n_contacts)
    assert len(contacts) >= 5
    assert np.mean(contacts) >= 3  # enough contacts for triangles
    assert min(contacts) >= 1  # every reachable pose touches the can


def test_empty_twin_has_no_object():
    with open_twin(None, Config().sim) as twin:
        assert twin.world.object is None
        g = twin.hand.guarded_close()
        assert g.n_contacts == 0
