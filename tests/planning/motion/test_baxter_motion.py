import time

import numpy as np
import pytest

from activetouch.errors import StoppedError, UnreachableError
from activetouch.interfaces import Pose
from activetouch.planning.grid import look_at_quaternion
from activetouch.planning.motion.baxter import (
    BAXTER_TABLE_CENTER,
    BAXTER_TABLE_SIZE,
    BaxterWristMotion,
    baxter_placement,
)
from activetouch.planning.motion.collision import CollisionScene
from activetouch.planning.motion.memory_arm import MemoryArm
from activetouch.planning.motion.robot import hand_pose

EXTENTS = np.array([0.12, 0.084, 0.098])  # a mug's box


def grasp(direction, distance=0.2, roll=0.0) -> Pose:
    """Hand on `direction` from the object centre, palm towards it."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    return Pose(d * distance, look_at_quaternion(-d, roll))


@pytest.fixture()
def motion(baxter):
    arm = MemoryArm(baxter.joint_names, baxter.limits(1.5), baxter.ready)
    pl = baxter_placement(float(EXTENTS[2]))
    return BaxterWristMotion(arm, pl, model=baxter, object_extents=EXTENTS)


def test_move_reaches_the_pose_and_trajectory_is_clean(motion, baxter):
    goals = [grasp([0, 0, 1]), grasp([-1, 0, 1]), grasp([-1, -0.3, 0.6], roll=np.pi / 2)]
    data = baxter.model.createData()
    for goal in goals:
        q_start = motion.current_q()
        motion.move_to(goal)
        traj = motion.arm.trajectories[-1]
        np.testing.assert_allclose(traj.positions[0], q_start, atol=1e-12)
        # The hand is where it was asked to be, in the object frame.
        got = motion.placement.to_object(hand_pose(baxter, data, motion.current_q()))
        assert np.linalg.norm(got.xyz - goal.xyz) < 5e-4
        assert abs(abs(got.quat @ goal.quat) - 1) < 1e-6
        # Limits and a dense re-check of what was executed (object ignored: the grasp touches).
        assert not baxter.limits(1.5).violations(baxter.joint_names, traj.positions)
        acc = traj.meta["accelerations"]
        assert np.all(np.abs(acc) <= 1.5 + 1e-6)
        t = np.arange(0, traj.times[-1], 0.001)
        qs = np.array([np.interp(t, traj.times, traj.positions[:, j]) for j in range(7)]).T
        exact = CollisionScene(baxter, BAXTER_TABLE_CENTER, BAXTER_TABLE_SIZE)  # no margin
        assert not any(exact.in_collision(q, False) for q in qs)
        assert traj.meta["duration_s"] == pytest.approx(traj.times[-1])


def test_unreachable_goals_say_why_quickly(motion):
    t = time.perf_counter()
    with pytest.raises(UnreachableError, match="no IK solution"):
        motion.plan(Pose([3.0, 0.0, 0.0], [0, 0, 0, 1]))
    # Beside the object, hand below the table top: IK converges, the hand is in the table.
    with pytest.raises(UnreachableError, match="collision at the goal"):
        motion.plan(Pose([-0.2, 0.0, -0.07], look_at_quaternion(np.array([1.0, 0, 0]), 0.0)))
    assert time.perf_counter() - t < 10.0  # bounded: restarts are capped
    # The arm has not moved.
    assert not motion.arm.trajectories


def test_reachable_marks_poses_and_feeds_the_seed_table(motion):
    poses = np.array([grasp([0, 0, 1]).as_array(), grasp([1, 0, 0.2]).as_array()])
    n = len(motion.seeds)
    ok = motion.reachable(poses)
    assert ok[0]  # from above
    assert not ok[1]  # from the far side, facing the robot: Baxter cannot
    assert len(motion.seeds) == n + 2 * int(ok.sum())


def test_stopped_arm_raises(motion):
    motion.arm.stop()
    with pytest.raises(StoppedError):
        motion.move_to(grasp([0, 0, 1]))
