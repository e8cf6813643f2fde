import numpy as np
import pytest

from activetouch.planning.motion.base import Placement
from activetouch.planning.motion.baxter import BAXTER_TABLE_CENTER, BAXTER_TABLE_SIZE
from activetouch.planning.motion.collision import CollisionScene
from activetouch.planning.motion.ik import IKSolver, SeedTable, dls_step
from activetouch.planning.motion.robot import pose_to_se3, se3_to_pose


@pytest.fixture(scope="module")
def scene(baxter):
    return CollisionScene(baxter, BAXTER_TABLE_CENTER, BAXTER_TABLE_SIZE)


@pytest.mark.parametrize(
    ("q", "expected"),
    [
        ([0.0, -0.55, 0.0, 1.25, 0.0, 0.87, 0.0], set()),  # ready: free
        ([-1.5, 0.0, 0.0, 2.4, 0.0, 0.0, 0.0], {("torso_0", "left_wrist_0")}),  # wrist in torso
        (
            [-0.8, 0.3, 0.0, 0.5, 0.0, 1.5, 0.0],
            {("left_wrist_0", "table"), ("reflex_housing", "table")},
        ),
    ],
)
def test_hand_placed_verdicts(scene, q, expected):
    q = np.array(q)
    pairs = set(scene.colliding_pairs(q))
    assert expected <= pairs
    assert scene.in_collision(q) == bool(pairs)


def test_hand_pushed_down_into_the_table_collides_with_the_hand_boxes(scene):
    pairs = scene.colliding_pairs(np.array([-1.2, -0.5, 0.0, 2.0, 0.0, 0.0, 0.0]))
    assert ("reflex_pad", "table") in pairs
    assert all(b == "table" for _, b in pairs)


def test_object_counts_only_when_asked(baxter):
    import pinocchio as pin

    data = baxter.model.createData()
    pin.forwardKinematics(baxter.model, data, baxter.ready)
    palm = pin.updateFramePlacement(baxter.model, data, baxter.hand_frame)
    # A 6 cm box right on the palm pad.
    centre = palm.translation + palm.rotation[:, 2] * 0.1
    sc = CollisionScene(
        baxter,
        BAXTER_TABLE_CENTER,
        BAXTER_TABLE_SIZE,
        Placement(centre),
        object_extents=np.full(3, 0.06),
    )
    assert sc.in_collision(baxter.ready, with_object=True)
    assert not sc.in_collision(baxter.ready, with_object=False)
    assert any("object" in p for p in sc.colliding_pairs(baxter.ready, True))
    hull = np.array(
        [[x, y, z] for x in (-0.03, 0.03) for y in (-0.03, 0.03) for z in (-0.03, 0.03)]
    )
    sc.set_object(Placement(centre), hull_points=hull)
    assert sc.in_collision(baxter.ready, with_object=True)
    sc.set_object(Placement(centre + np.array([0.0, 0.0, 0.5])), hull_points=hull)
    assert not sc.in_collision(baxter.ready, with_object=True)


def test_broadphase_agrees_with_all_pairs(baxter, scene):
    rng = np.random.default_rng(3)
    for q in rng.uniform(baxter.lower, baxter.upper, (200, 7)):
        assert scene.in_collision(q) == bool(scene.colliding_pairs(q))


def test_dls_step_solves_a_square_system():
    rng = np.random.default_rng(0)
    j = rng.normal(size=(6, 6))
    e = rng.normal(size=6)
    np.testing.assert_allclose(j @ dls_step(j, e, 1e-12), e, atol=1e-6)


def test_ik_reaches_forward_kinematics_targets(baxter, scene):
    import pinocchio as pin

    rng = np.random.default_rng(7)
    data = baxter.model.createData()
    ik = IKSolver(baxter, SeedTable.random(baxter, 2000, seed=1))
    solved = 0
    n = 0
    while n < 40:
        q = rng.uniform(baxter.lower, baxter.upper)
        if scene.in_collision(q):
            continue
        n += 1
        pin.forwardKinematics(baxter.model, data, q)
        target = pin.updateFramePlacement(baxter.model, data, baxter.hand_frame).copy()
        sol = ik.solve(target, baxter.ready)
        if sol is None:
            continue
        solved += 1
        assert np.all(sol >= baxter.lower) and np.all(sol <= baxter.upper)
        got = se3_to_pose(pin.updateFramePlacement(baxter.model, data, baxter.hand_frame))
        pin.forwardKinematics(baxter.model, data, sol)
        got = se3_to_pose(pin.updateFramePlacement(baxter.model, data, baxter.hand_frame))
        want = se3_to_pose(target)
        assert np.linalg.norm(got.xyz - want.xyz) < 2e-4
        assert abs(abs(got.quat @ want.quat) - 1) < 1e-7
    assert solved >= 39


def test_ik_returns_the_nearest_of_its_solutions(baxter):
    import pinocchio as pin

    data = baxter.model.createData()
    q_true = np.array([-0.3, -0.4, 0.2, 1.4, -0.2, 0.8, 0.3])
    pin.forwardKinematics(baxter.model, data, q_true)
    target = pin.updateFramePlacement(baxter.model, data, baxter.hand_frame).copy()
    ik = IKSolver(baxter, None, restarts=30, seed=2)
    sol = ik.solve(target, q_true + 0.05, max_solutions=4)
    assert sol is not None
    np.testing.assert_allclose(sol, q_true, atol=5e-3)  # the warm start's basin, not another


def test_ik_accept_rejects_and_reports(baxter):
    ik = IKSolver(baxter, None, restarts=3)
    target = pose_to_se3(se3_to_pose(_fk(baxter, baxter.ready)))
    assert ik.solve(target, baxter.ready, accept=lambda q: False) is None
    assert ik.stats.converged >= 1 and ik.stats.rejected == ik.stats.converged


def _fk(arm, q):
    import pinocchio as pin

    data = arm.model.createData()
    pin.forwardKinematics(arm.model, data, q)
    return pin.updateFramePlacement(arm.model, data, arm.hand_frame).copy()
