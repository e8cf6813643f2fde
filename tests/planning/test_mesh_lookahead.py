"""The mesh policy's predictions, against a sphere's closed-form distance and by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from activetouch.models import reflex
from activetouch.models.reflex import ReflexGeometry
from activetouch.planning.mesh_lookahead import (
    SWEEP_STEP_RAD,
    PlacementBelief,
    closure_stops,
    expected_accuracy,
    finger_sweeps,
    pack_shapes,
    predicted_values,
    top_hypotheses,
)
from activetouch.planning.policies import MeshPolicy, Plan, PlanningState, Policy
from activetouch.recognition.pose_belief import (
    ClassShape,
    PoseBelief,
    PoseParams,
    reflex_free_sites,
)

R = 0.04  # the sphere's radius
TOUCH = 0.002
# The hand under the sphere, fingers up around it: the palm pad 1 cm below its bottom.
PALM_Z = ReflexGeometry().palm_sensor_z
WRIST = np.array([0.0, 0.0, -R - 0.01 - PALM_Z, 0.0, 0.0, 0.0, 1.0])


def _shape(mesh: trimesh.Trimesh) -> ClassShape:
    return ClassShape.from_mesh(mesh.vertices, mesh.faces, step=0.003)


@pytest.fixture(scope="module")
def sphere() -> ClassShape:
    return _shape(trimesh.creation.icosphere(subdivisions=4, radius=R))


def _sites(pose: np.ndarray, sweeps: np.ndarray) -> np.ndarray:
    """(1, 3, J, 9, 3) the sweeps at a wrist pose with no rotation."""
    return np.ascontiguousarray((sweeps + pose[:3])[None])


def _stops(shapes, hyps, cls, pose=WRIST, support=-np.inf) -> np.ndarray:
    p = pack_shapes(shapes)
    sweeps = finger_sweeps(ReflexGeometry(), 0.0, 0.25)
    return closure_stops(
        p.values,
        p.dims,
        p.origins,
        p.steps,
        p.offsets,
        np.zeros(len(shapes)),
        np.asarray(cls, dtype=np.int64),
        np.asarray(hyps, dtype=np.float64),
        _sites(pose, sweeps),
        TOUCH,
        support,
    )[0]


def _sphere_stop(centre: np.ndarray) -> np.ndarray:
    """Each finger's first sweep step whose sites come within TOUCH of a sphere at `centre`
    (wrist frame = object frame here), from the hand model and |x - c| - R alone."""
    out = []
    geom = ReflexGeometry()
    for f in range(3):
        j = 0
        while True:
            a = (j + 1) * SWEEP_STEP_RAD
            s = reflex.finger_sensor_positions(geom, f, 0.0, a, 0.25 * a) + WRIST[:3]
            if np.min(np.linalg.norm(s - centre, axis=1)) - R < TOUCH or a > 2.2:
                break
            j += 1
        out.append(j)
    return np.array(out)


def test_each_finger_stops_where_it_meets_the_sphere(sphere):
    got = _stops([sphere], [[0.0, 0.0, 0.0]], [0])[0]
    assert np.abs(got - _sphere_stop(np.zeros(3))).max() <= 1  # one step: the grid's reading


def test_a_sphere_standing_off_its_frame_meets_the_fingers_where_it_stands(sphere):
    hyps = [[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, -0.015, 0.0]]
    got = _stops([sphere], hyps, [0, 0, 0])
    for m, h in enumerate(hyps):
        want = _sphere_stop(np.array([h[0], h[1], 0.0]))
        assert np.abs(got[m] - want).max() <= 1
    assert not np.array_equal(got[0], got[1])  # the shift changes what the fingers feel


def test_a_finger_that_would_go_under_the_table_stops_there(sphere):
    free = _stops([sphere], [[0.5, 0.0, 0.0]], [0])[0]  # the sphere far away
    assert np.all(free == free.max())  # every finger closes on nothing ...
    # A table between the sites' height at the first step and their lowest (the fingers
    # rise, then their tips curl back down past where they started)
    sweeps = finger_sweeps(ReflexGeometry(), 0.0, 0.25)
    start, lowest = sweeps[:, 0, :, 2].min(), sweeps[:, :, :, 2].min()
    assert lowest < start
    table = _stops([sphere], [[0.5, 0.0, 0.0]], [0], support=WRIST[2] + (start + lowest) / 2)[0]
    assert np.all((table > 0) & (table < free))  # ... unless the table is in the way


def test_expected_accuracy_by_hand():
    w = np.array([0.6, 0.4])
    cls = np.array([0, 1])
    apart = np.array([[[1.0, 1.0, 1.0], [1.5, 1.0, 1.0]]])  # told apart by finger 0
    same = np.array([[[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]])
    v = expected_accuracy(np.concatenate([apart, same]), w, cls, 2, 0.05)
    assert v[0] == pytest.approx(1.0, abs=1e-12)
    assert v[1] == pytest.approx(0.6)  # nothing learned: the belief's own maximum
    # 0.05 rad apart at sigma 0.05: each outcome is evidence e^-0.5 against the other class
    near = np.array([[[1.0, 1.0, 1.0], [1.05, 1.0, 1.0]]])
    e = np.exp(-0.5)
    want = 0.6 * 0.6 / (0.6 + 0.4 * e) + 0.4 * 0.4 / (0.4 + 0.6 * e)
    assert expected_accuracy(near, w, cls, 2, 0.05)[0] == pytest.approx(want)


def test_top_hypotheses_are_the_likeliest_pairs_normalised():
    log_b = np.log(np.array([[0.1, 0.5, 0.05], [0.3, 0.02, 0.03]]))
    k, h, w = top_hypotheses(log_b, 2)
    order = np.argsort(-w)
    assert list(zip(k[order], h[order], strict=True)) == [(0, 1), (1, 0)]
    assert w[order] == pytest.approx([0.5 / 0.8, 0.3 / 0.8])


class _Fallback(Policy):
    name = "greedy"

    def __init__(self) -> None:
        self.calls = 0

    def plan(self, state, rng) -> Plan:
        self.calls += 1
        one = np.array([0], dtype=np.int64)
        return Plan(self.name, one, one, 0.0)


def _knobbed(sphere_mesh: trimesh.Trimesh) -> tuple[ClassShape, np.ndarray]:
    """The sphere with a 1.5 cm knob where finger 0's tip passes halfway to the plain
    sphere, and that tip position."""
    j0 = _sphere_stop(np.zeros(3))[0]
    a = (j0 // 2 + 1) * SWEEP_STEP_RAD
    tip = reflex.finger_sensor_positions(ReflexGeometry(), 0, 0.0, a, 0.25 * a)[8] + WRIST[:3]
    knob = trimesh.creation.box(extents=(0.015, 0.015, 0.015))
    knob.apply_translation(tip)
    return _shape(trimesh.util.concatenate([sphere_mesh, knob])), tip


def test_the_policy_grasps_where_the_classes_differ_and_defers_where_none_do(sphere):
    knobbed, _ = _knobbed(trimesh.creation.icosphere(subdivisions=4, radius=R))
    # Three poses: 0 where the arm is now; 1 a metre off (nothing there for either class);
    # 2 the hand under the object, where finger 0 meets the knob early.
    far = WRIST.copy()
    far[0] += 1.0
    poses = np.stack([far, far, WRIST])
    model = SimpleNamespace(
        n_poses=3,
        edge_ptr=np.array([0, 2, 4, 6]),
        edge_target=np.array([1, 2, 0, 2, 0, 1]),
        edge_action=np.array([10, 11, 12, 13, 14, 15]),
        pose_xyz=poses[:, :3],
        pose_quat=poses[:, 3:],
    )
    belief = PoseBelief(
        [sphere, knobbed], PoseParams(range_m=0.0, range_deg=0.0), reflex_free_sites()
    )
    fallback = _Fallback()
    policy = MeshPolicy(model, fallback, hypotheses=8, sigma_rad=0.05, min_gain=0.01)
    state = PlanningState(
        pose=0,
        visited=np.array([0], dtype=np.int64),
        counts=np.zeros(1),
        cells=np.zeros(0, dtype=np.int64),
        placement=PlacementBelief(belief, np.zeros(3), 0.0),
    )
    plan = policy.plan(state, np.random.default_rng(0))
    assert plan.policy == "mesh" and plan.poses.tolist() == [2] and plan.actions.tolist() == [11]
    assert plan.value == pytest.approx(1.0, abs=1e-6) and fallback.calls == 0
    v, now = predicted_values(belief, poses, 0.0, np.zeros(3), hypotheses=8, sigma_rad=0.05)
    assert now == pytest.approx(0.5) and v[1] == pytest.approx(0.5)  # far: nothing to learn
    # With the far pose the only one left, no pose tells the classes apart: greedy decides.
    visited = PlanningState(
        pose=0,
        visited=np.array([0, 2]),
        counts=np.zeros(1),
        cells=np.zeros(0, dtype=np.int64),
        placement=state.placement,
    )
    assert policy.plan(visited, np.random.default_rng(0)).policy == "greedy"
    # Without a placement belief (another belief, another hand): greedy decides.
    bare = PlanningState.start(0, np.zeros(1), np.zeros(0))
    assert policy.plan(bare, np.random.default_rng(0)).policy == "greedy"
    assert fallback.calls == 2


def test_bad_settings_are_clear_errors():
    from activetouch.errors import ConfigError

    m = SimpleNamespace(pose_xyz=np.zeros((1, 3)), pose_quat=np.array([[0.0, 0, 0, 1]]))
    with pytest.raises(ConfigError, match="mesh_hypotheses"):
        MeshPolicy(m, _Fallback(), hypotheses=0, sigma_rad=0.05, min_gain=0.01)
    with pytest.raises(ConfigError, match="mesh_sigma_rad"):
        MeshPolicy(m, _Fallback(), hypotheses=8, sigma_rad=0.0, min_gain=0.01)
    with pytest.raises(ConfigError, match="mesh_min_gain"):
        MeshPolicy(m, _Fallback(), hypotheses=8, sigma_rad=0.05, min_gain=-0.1)


def test_a_turned_placement_reads_as_the_mesh_turned_and_shifted():
    # The knobbed sphere standing 1 cm off in x, turned 40 deg: the same stops as that mesh
    # moved there by trimesh and read at the nominal placement.
    mesh = trimesh.util.concatenate(
        [
            trimesh.creation.icosphere(subdivisions=4, radius=R),
            trimesh.creation.box((0.05, 0.015, 0.015)),
        ]
    )
    mesh.vertices[-8:] += [0.045, 0.0, 0.0]  # the box: a bar out of the sphere's side
    moved = mesh.copy()
    yaw, dx = np.deg2rad(40.0), 0.01
    moved.apply_transform(trimesh.transformations.rotation_matrix(yaw, [0, 0, 1]))
    moved.apply_translation([dx, 0.0, 0.0])
    turned = _stops([_shape(mesh)], [[dx, 0.0, yaw]], [0])[0]
    direct = _stops([_shape(moved)], [[0.0, 0.0, 0.0]], [0])[0]
    assert np.abs(turned - direct).max() <= 1
    straight = _stops([_shape(mesh)], [[dx, 0.0, 0.0]], [0])[0]
    assert not np.array_equal(straight, direct)  # the turn mattered
