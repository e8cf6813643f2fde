"""The belief over class x placement: signed distances of a box checked against its geometry,
hypotheses moved by hand, and a misplaced box found from contacts on its surface."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from activetouch.errors import ConfigError
from activetouch.interfaces import Grasp, Pose
from activetouch.models.reflex import ReflexGeometry
from activetouch.recognition.pose_belief import (
    DISTANCE_CAP_M,
    ClassShape,
    PoseBelief,
    PoseParams,
    class_frames,
    class_lifts,
    drifted,
    grasp_log_likelihood,
    in_object_frames,
    peak_offset,
    pose_grid,
    reflex_free_sites,
    rival_placement,
    roundest_axis,
)

BOX = (0.10, 0.06, 0.08)


def _shape(extents) -> ClassShape:
    m = trimesh.creation.box(extents=extents)
    return ClassShape.from_mesh(m.vertices, m.faces)


@pytest.fixture(scope="module")
def box() -> ClassShape:
    return _shape(BOX)


def test_grid_covers_the_range_with_zero_in_it():
    g = pose_grid(PoseParams(range_m=0.02, step_m=0.01, range_deg=15.0, step_deg=7.5))
    assert g.shape == (5 * 5 * 5, 3)
    assert np.any(np.all(g == 0.0, axis=1))
    assert g[:, 0].max() == pytest.approx(0.02) and np.rad2deg(g[:, 2]).min() == pytest.approx(-15)
    with pytest.raises(ConfigError, match="pose_step_m must be a number > 0"):
        PoseParams(step_m=0.0)
    with pytest.raises(ConfigError, match="pose_drift_m must be a number >= 0"):
        PoseParams(drift_m=-0.01)
    with pytest.raises(ConfigError, match="pose_alternate_share must be a number >= 0"):
        PoseParams(alternate_share=float("nan"))


def test_signed_distance_of_a_box(box):
    # Exact values from the box's geometry: faces at x = +-5 cm, y = +-3, z = +-4.
    q = np.array(
        [
            [0.0, 0.0, 0.0],  # centre: 3 cm inside, beyond the cap
            [0.04, 0.0, 0.0],  # 1 cm inside the +x face
            [0.06, 0.0, 0.0],  # 1 cm outside it
            [0.0, 0.03, 0.0],  # on the +y face
            [0.0, 0.0, 0.052],  # 1.2 cm over the top
            [0.5, 0.5, 0.5],  # far away
        ]
    )
    sd = box.signed_distance(q)
    want = [-DISTANCE_CAP_M, -0.01, 0.01, 0.0, 0.012, DISTANCE_CAP_M]
    assert sd == pytest.approx(want, abs=0.0025)  # samples 1-2 mm apart, a 4 mm grid


def test_hypotheses_move_points_into_the_displaced_objects_frame():
    hyps = np.array([[0.0, 0.0, 0.0], [0.02, -0.01, np.deg2rad(90.0)]])
    p = np.array([[0.02, -0.01 + 0.05, 0.1]])  # 5 cm along the turned object's own +x
    out = in_object_frames(p, hyps)
    assert out[0, 0] == pytest.approx(p[0])
    assert out[1, 0] == pytest.approx([0.05, 0.0, 0.1], abs=1e-12)


def _contacts_on(extents, dx, dy, yaw_deg, n, seed) -> np.ndarray:
    """Points on the surface of a box standing at (dx, dy) turned by yaw, nominal frame."""
    m = trimesh.creation.box(extents=extents)
    pts, _ = trimesh.sample.sample_surface(m, n, seed=seed)
    r = Rotation.from_euler("z", yaw_deg, degrees=True)
    return r.apply(np.asarray(pts)) + np.array([dx, dy, 0.0])


def _feel_box(belief: PoseBelief, truth: tuple[float, float, float]) -> None:
    """Eight grasps of six contacts each on BOX standing at `truth` (dx, dy, yaw deg)."""
    # Palm far above (hand frame = object frame shifted up 1 m): its quiet sites say nothing.
    up = Pose([0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0])
    for seed in range(8):
        c = _contacts_on(BOX, *truth, n=6, seed=seed) - up.xyz
        belief.update(
            Grasp(
                sensor_ids=np.arange(6),
                xyz=c,
                pressures=np.full(6, 50.0),
                finger_angles=np.zeros(3),
                preshape=0.0,
            ),
            up,
        )


def test_a_misplaced_box_is_found_and_told_from_a_larger_one(box):
    larger = _shape((0.12, 0.06, 0.08))
    belief = PoseBelief([box, larger], PoseParams(), reflex_free_sites())
    _feel_box(belief, (0.02, -0.01, 15.0))
    p = np.exp(belief.class_log_belief() - belief.class_log_belief().max())
    assert p[0] / p.sum() > 0.95
    est = belief.estimate(0)
    assert est.dx_m == pytest.approx(0.02, abs=0.005)
    assert est.dy_m == pytest.approx(-0.01, abs=0.005)
    assert est.yaw_deg == pytest.approx(15.0, abs=4.0)
    assert est.sd_x_m < 0.01


def test_a_finger_that_closed_through_the_hypothesis_rules_it_out():
    # An empty grasp whose first finger swept through a 3 cm cube at the nominal placement:
    # the cube cannot stand there, but it can 3 cm away.
    from activetouch.models.reflex import sensor_positions

    cube = _shape((0.03, 0.03, 0.03))
    belief = PoseBelief([cube], PoseParams(), reflex_free_sites())
    angles = np.full(3, 1.2)
    swept = sensor_positions(ReflexGeometry(), 0.0, angles * 0.7, np.zeros(3))
    at = Pose(-swept[2], [0.0, 0.0, 0.0, 1.0])  # finger 0's third site passed the origin
    empty = Grasp(
        sensor_ids=np.zeros(0, dtype=np.int64),
        xyz=np.zeros((0, 3)),
        pressures=np.zeros(0),
        finger_angles=angles,
        preshape=0.0,
    )
    belief.update(empty, at)
    lb = belief.log_b[0]
    zero = int(np.flatnonzero(np.all(belief.hyps == 0.0, axis=1))[0])
    assert lb[zero] < lb.max() - 5.0  # the nominal placement is ruled out
    assert lb.max() == 0.0  # somewhere nothing was in the way


def test_a_signed_distance_grid_round_trips_and_a_bad_one_is_refused(box):
    back = ClassShape.from_arrays(box.to_arrays())
    q = np.random.default_rng(0).uniform(-0.08, 0.08, (50, 3))
    assert np.array_equal(back.signed_distance(q), box.signed_distance(q))
    with pytest.raises(ValueError):
        ClassShape.from_arrays(
            {"origin": np.zeros(3), "step": np.array([0.0]), "values": box.values}
        )


def test_the_session_caches_each_meshs_grid_beside_it(tmp_path):
    from activetouch.objects.library import ObjectLibrary
    from activetouch.session.loop import _class_shape, class_shapes

    mesh = tmp_path / "box.obj"
    trimesh.creation.box(extents=BOX).export(mesh)
    lib = ObjectLibrary(tmp_path / "objects")
    lib.add("box", mesh)
    first = class_shapes(["box"], lib)[0]
    cached = list((tmp_path / "objects" / "box").glob(".sdf-v*.npz"))
    assert len(cached) == 1
    _class_shape.cache_clear()
    again = class_shapes(["box"], lib)[0]  # read from the file
    assert np.array_equal(again.values, first.values)


def _cup() -> trimesh.Trimesh:
    """An open cup: 4 cm outer radius, 3 mm wall, 5 mm floor, 10 cm tall (base at z = 0)."""
    outer = trimesh.creation.cylinder(radius=0.04, height=0.10, sections=48)
    inner = trimesh.creation.cylinder(radius=0.037, height=0.10, sections=48)
    inner.apply_translation([0.0, 0.0, 0.005])  # from the floor's top up past the rim
    cup = outer.difference(inner)
    cup.apply_translation([0.0, 0.0, 0.05])
    assert cup.is_watertight
    return cup


def test_a_cups_cavity_is_open_space():
    # A hand reaching into a cup or bowl must not read as pressing into solid: the cavity's
    # middle is farther from every wall than the grid's cap, where the sign is easiest to get
    # wrong. Each point's side comes from the mesh itself (winding number), checked here
    # against the cup's geometry.
    cup = _cup()
    shape = ClassShape.from_mesh(cup.vertices, cup.faces)
    axis = np.array([[0.0, 0.0, z] for z in np.linspace(0.01, 0.12, 23)])
    assert np.all(shape.signed_distance(axis) > 0.0)
    rng = np.random.default_rng(3)
    q = rng.uniform(cup.bounds[0] - 0.02, cup.bounds[1] + 0.02, size=(3000, 3))
    radial = np.linalg.norm(q[:, :2], axis=1)
    solid = (radial <= 0.04) & (q[:, 2] >= 0) & (q[:, 2] <= 0.1)
    solid &= (radial >= 0.037) | (q[:, 2] <= 0.005)
    sd = shape.signed_distance(q)
    clear = np.abs(sd) > 0.003  # away from the surface (a 4 mm grid read trilinearly)
    assert np.array_equal(sd[clear] < 0, solid[clear])


def test_a_taller_class_stands_on_the_table_and_a_grasp_over_the_top_rules_it_out():
    # The wrist poses are in the true object's frame (a box 8 cm tall, its centre 4 cm over
    # the table). A box 10 cm tall on the same table has its frame 1 cm higher and its top
    # 2 cm over the short one's. A finger swept 8 mm over the short box's top is then 12 mm
    # inside the tall box; centred at the short box's frame it would be only 2 mm inside.
    short, tall = _shape((0.06, 0.06, 0.08)), _shape((0.06, 0.06, 0.10))
    lifts = class_lifts([short, tall], support_z=-0.04)
    assert lifts == pytest.approx([0.0, 0.01], abs=1e-9)
    assert np.all(class_lifts([short, tall], None) == 0.0)
    contacts = np.array([[0.03, 0.0, 0.0], [-0.03, 0.0, 0.0]])  # both boxes' sides
    free = np.array([[x, y, 0.048] for x in (-0.02, 0.0, 0.02) for y in (-0.02, 0.0, 0.02)])
    hyps = np.zeros((1, 3))
    p = PoseParams()
    centred = grasp_log_likelihood([short, tall], hyps, contacts, free, p)[:, 0]
    standing = grasp_log_likelihood([short, tall], hyps, contacts, free, p, lifts)[:, 0]
    assert standing[0] == pytest.approx(centred[0])  # the true class does not move
    assert standing[1] < centred[1] - 5.0  # the tall box is ruled out only standing
    assert standing[0] > standing[1]


def test_the_contact_model_can_expect_sites_off_the_surface():
    # A sensor site sits under the skin: contacts read 2 mm outside the face they touch.
    box = _shape((0.06, 0.06, 0.08))
    contacts = np.array([[0.032, 0.0, 0.0], [-0.032, 0.01, 0.0], [0.0, 0.032, 0.01]])
    hyps, free = np.zeros((1, 3)), np.zeros((0, 3))
    at = PoseParams(contact_sigma_m=0.002, contact_offset_m=0.0)
    on = grasp_log_likelihood([box], hyps, contacts, free, at)
    off = grasp_log_likelihood(
        [box], hyps, contacts, free, PoseParams(contact_sigma_m=0.002, contact_offset_m=0.002)
    )
    assert off[0, 0] > on[0, 0] + 1.0
    with pytest.raises(ConfigError, match="pose_contact_offset_m"):
        PoseParams(contact_offset_m=-0.001)


def test_the_peak_is_found_between_grid_points_and_not_along_a_flat_axis():
    # A log belief quadratic in dx and dy (as Gaussian contacts give) peaks at its centre,
    # off the 1 cm grid; flat in yaw (a round object), its yaw is the posterior mean, 0.
    hyps = pose_grid(PoseParams())
    centre = np.array([0.013, -0.004])
    lb = -0.5 * np.sum((hyps[:, :2] - centre) ** 2, axis=1) / 0.004**2
    got = peak_offset(lb, hyps)
    np.testing.assert_allclose(got[:2], centre, atol=1e-12)
    assert abs(got[2]) < 1e-12
    # Curved in yaw too, about 10 deg: found between the 7.5 deg steps.
    lb2 = lb - 0.5 * (hyps[:, 2] - np.deg2rad(10.0)) ** 2 / np.deg2rad(6.0) ** 2
    np.testing.assert_allclose(peak_offset(lb2, hyps), [*centre, np.deg2rad(10.0)], atol=1e-12)
    # At the grid's edge there is no neighbour beyond: the edge point itself.
    edge = -0.5 * np.sum((hyps[:, :2] - 0.05) ** 2, axis=1) / 0.004**2
    np.testing.assert_allclose(peak_offset(edge, hyps)[:2], [0.03, 0.03])


class _FavourClass:
    """A training-grasp term that favours one class everywhere, as a look-alike's chance
    matches do once grasps land off their training poses."""

    def __init__(self, k: int, n_classes: int, nats: float) -> None:
        self.k, self.n, self.nats = k, n_classes, nats

    def log_likelihood_at_poses(
        self, grasp, poses, params, ignore=None, finger_sensors=0, class_groups=None
    ):
        out = np.zeros((np.shape(poses)[-2], self.n))
        out[:, self.k] = self.nats
        return out


def test_where_the_grasps_go_is_found_by_the_mesh_between_grid_points(box):
    # The box off the grid's points; a training-grasp term that favours the larger box makes
    # it the belief's class, but the placement the next grasps go to is the one the mesh
    # finds for the box, within a few millimetres and degrees of the truth.
    larger = _shape((0.12, 0.06, 0.08))
    favour = (_FavourClass(1, 2, 50.0), None)
    belief = PoseBelief([box, larger], PoseParams(), reflex_free_sites(), grasps=favour)
    _feel_box(belief, (0.013, -0.006, 11.0))
    assert np.argmax(belief.class_log_belief()) == 1  # the favoured look-alike leads
    dx, dy, yaw = belief.placement_peak()
    assert dx == pytest.approx(0.013, abs=0.003) and dy == pytest.approx(-0.006, abs=0.003)
    assert np.rad2deg(yaw) == pytest.approx(11.0, abs=3.0)
    grid_best = belief.hyps[np.argmax(belief.mesh_log_b[0])]
    assert np.hypot(dx - 0.013, dy + 0.006) < np.hypot(grid_best[0] - 0.013, grid_best[1] + 0.006)


def test_the_grasps_go_where_most_of_the_likely_classes_have_the_object(box):
    # One class, alone likelier than any other, puts the object at B (as a handle mug does
    # whose frame is off its body); three others, together likelier, agree it stands at A.
    # Grasps placed for A land on the training poses of three quarters of the belief.
    belief = PoseBelief([box] * 4, PoseParams(), reflex_free_sites())
    hyps = belief.hyps
    a, b = np.array([0.012, -0.008]), np.array([-0.02, 0.005])

    def peaked(at: np.ndarray, top: float) -> np.ndarray:
        xy = np.sum((hyps[:, :2] - at) ** 2, axis=1) / 0.003**2
        return top - 0.5 * xy - 0.5 * (hyps[:, 2] / np.deg2rad(5.0)) ** 2

    belief.mesh_log_b = np.stack([peaked(b, 0.0), *(peaked(a, -0.5) for _ in range(3))])
    np.testing.assert_allclose(belief.placement_peak()[:2], a, atol=1e-3)
    # B's class holds 0.29 of the mesh's probability against A's 0.71: under half of it, so
    # B is no rival at the default share and every grasp goes to A ...
    belief._grasps = 1
    np.testing.assert_allclose(belief.placement_peak()[:2], a, atol=1e-3)
    # ... but over 0.3 of it: every other grasp goes to B, so neither frame's training
    # grasps have the edge in all of them.
    belief.params = replace(belief.params, alternate_share=0.3)
    np.testing.assert_allclose(belief.placement_peak()[:2], b, atol=1e-3)
    belief._grasps = 2
    np.testing.assert_allclose(belief.placement_peak()[:2], a, atol=1e-3)
    belief._grasps = 0
    # With one of the three, B's class is the likelier and the grasps go to B.
    belief.mesh_log_b, belief.log_b = belief.mesh_log_b[:2], belief.log_b[:2]
    np.testing.assert_allclose(belief.placement_peak()[:2], b, atol=1e-3)


def test_a_belief_that_drifts_spreads_each_class_over_the_neighbouring_placements():
    hyps = pose_grid(PoseParams())  # +-3 steps in x and y
    centre = np.flatnonzero(np.all(hyps == 0.0, axis=1))[0]
    log_b = np.full((2, len(hyps)), -np.inf)
    log_b[0, centre], log_b[1] = 0.0, -3.0  # class 1: even, 3 nats under class 0's peak
    out = drifted(log_b, hyps, 0.01)
    p = np.exp(out[0])
    # One grid step of spread: the mass moves in x and y, not in yaw, and stays on the grid.
    assert p.sum() == pytest.approx(1.0, abs=1e-9)
    assert p[centre] == pytest.approx(_gauss(0) ** 2, rel=1e-9)
    beside = np.flatnonzero(np.all(np.isclose(hyps, [0.01, 0.0, 0.0]), axis=1))[0]
    assert p[beside] == pytest.approx(_gauss(1) * _gauss(0), rel=1e-9)
    assert p[hyps[:, 2] != 0.0].max() < 1e-290  # the floor that keeps every class alive
    # An even class stays even where the whole spread is on the grid; at a corner it loses
    # what would leave the grid (the object would be off it).
    assert out[1][centre] == pytest.approx(-3.0, abs=1e-9)
    corner = np.flatnonzero(np.all(np.isclose(hyps, [0.03, 0.03, 0.0]), axis=1))[0]
    edge = sum(_gauss(k) for k in range(-3, 1))  # the side of the Gaussian on the grid
    assert out[1][corner] == pytest.approx(-3.0 + 2 * np.log(edge), abs=1e-9)
    np.testing.assert_array_equal(drifted(log_b, hyps, 0.0), log_b)


def _gauss(k: int) -> float:
    """Weight at k steps of a Gaussian of one step's sigma, cut at 3 steps."""
    w = np.exp(-0.5 * np.arange(-3, 4) ** 2)
    return float(w[k + 3] / w.sum())


def test_a_rival_placement_is_one_apart_from_the_best_with_enough_support():
    scale = np.array([0.01, 0.01, np.deg2rad(7.5)])
    peaks = np.array([[0.0, 0.0, 0.0], [0.012, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.0, 0.5]])
    scores = np.array([1.0, 0.9, 0.5, 0.6])
    # 1.2 steps from the best is the same placement; of the two further off, the better one.
    assert rival_placement(peaks, scores, scale, 0, 0.5) == 3
    assert rival_placement(peaks, scores, scale, 0, 0.7) is None
    assert rival_placement(peaks, scores, scale, 0, 0.0) is None  # sharing off
    # The mesh alone gives the far placement under half the best's support, the whole belief
    # (the training grasps' term with it) twice the best's: it is a rival all the same.
    far = np.array([[0.0, 0.0, 0.0], [0.017, 0.0, 0.0], [0.0, 0.03, 0.0]])
    mesh, whole = np.array([1.0, 0.25, 0.2]), np.array([0.3, 0.6, 0.1])
    assert rival_placement(far, mesh, scale, 0, 0.5) is None
    assert rival_placement(far, mesh, scale, 0, 0.5, whole) == 1
    assert rival_placement(far, mesh, scale, 0, 0.5, np.array([0.9, 0.05, 0.05])) is None
    # Yaw wraps: 2 pi - 0.01 rad is 0.01 rad from 0, the same placement.
    wrapped = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2 * np.pi - 0.01]])
    assert rival_placement(wrapped, np.array([1.0, 1.0]), scale, 0, 0.5) is None


def _mug(body_x: float) -> trimesh.Trimesh:
    """A cup (`_cup`) with a handle on its +x side, its body's axis at x = `body_x`."""
    handle = trimesh.creation.box(extents=(0.03, 0.012, 0.06))
    handle.apply_translation([0.05, 0.0, 0.05])  # 2.5 cm out from the wall
    mug = _cup().union(handle)
    mug.apply_translation([body_x, 0.0, 0.0])
    assert mug.is_watertight
    return mug


def test_a_class_turns_about_its_bodys_axis_or_a_boxs_centre(box):
    # A mug's frame is off its body (the bounding box's centre, with the handle): turned
    # about the body's axis only the handle leaves the surface. No axis keeps a box: its
    # centre. Each found from the signed distances alone, checked against the geometry.
    mug = _mug(-0.017)
    shape = ClassShape.from_mesh(mug.vertices, mug.faces)
    np.testing.assert_allclose(shape.pivot_xy, [-0.017, 0.0], atol=1.01e-3)
    np.testing.assert_allclose(roundest_axis(box), [0.0, 0.0], atol=1e-9)
    shifted = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=48)
    shifted.apply_translation([0.011, -0.004, 0.0])
    cyl = ClassShape.from_mesh(shifted.vertices, shifted.faces)
    np.testing.assert_allclose(cyl.pivot_xy, [0.011, -0.004], atol=1.01e-3)
    # Stored with the grid, and found again for a grid stored before it was.
    back = ClassShape.from_arrays(shape.to_arrays())
    assert np.array_equal(back.pivot_xy, shape.pivot_xy)
    old = {k: v for k, v in shape.to_arrays().items() if k != "pivot"}
    assert np.array_equal(ClassShape.from_arrays(old).pivot_xy, shape.pivot_xy)
    other = {**shape.to_arrays(), "pivot": np.ones(2), "pivot_version": np.array([0])}
    assert np.array_equal(ClassShape.from_arrays(other).pivot_xy, shape.pivot_xy)


def test_a_hypothesis_moves_and_turns_each_class_about_its_pivot():
    hyps = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, np.deg2rad(90.0)]])
    pivots = np.array([[0.0, 0.0], [-0.017, 0.0]])
    frames = class_frames(hyps, pivots)
    np.testing.assert_allclose(frames[:, 0], 0.0)  # no move: every frame where it was
    np.testing.assert_allclose(frames[0, 1], hyps[1])  # about the origin: the hypothesis
    # About (-17 mm, 0): the origin turns a quarter round the pivot to (-17, 17) mm, then
    # moves 1 cm in x; the body's axis itself only moves the 1 cm.
    np.testing.assert_allclose(frames[1, 1], [-0.007, 0.017, np.deg2rad(90.0)], atol=1e-12)
    axis = np.array([[-0.017, 0.0, 0.05]])
    moved = axis + np.array([0.01, 0.0, 0.0])  # where the body's axis stands under the hypothesis
    np.testing.assert_allclose(in_object_frames(moved, frames[1, 1:])[0, 0], axis[0], atol=1e-12)
