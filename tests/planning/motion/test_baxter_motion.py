import numpy as np
import pytest

from activetouch.errors import StoppedError, UnreachableError
from activetouch.fakes.memory_arm import MemoryArm
from activetouch.interfaces import Pose
from activetouch.planning.grid import look_at_quaternion
from activetouch.planning.motion.baxter import (
    BAXTER_TABLE_CENTER,
    BAXTER_TABLE_SIZE,
    BaxterWristMotion,
    baxter_placement,
)
from activetouch.planning.motion.collision import CollisionScene
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
        acc = traj.accelerations
        assert np.all(np.abs(acc) <= 1.5 + 1e-6)
        t = np.arange(0, traj.times[-1], 0.001)
        qs = np.array([np.interp(t, traj.times, traj.positions[:, j]) for j in range(7)]).T
        exact = CollisionScene(baxter, BAXTER_TABLE_CENTER, BAXTER_TABLE_SIZE)  # no margin
        assert not any(exact.in_collision(q, False) for q in qs)
        assert traj.meta["duration_s"] == pytest.approx(traj.times[-1])


def test_unreachable_goals_say_why_quickly(motion):
    with pytest.raises(UnreachableError, match="no IK solution"):
        motion.plan(Pose([3.0, 0.0, 0.0], [0, 0, 0, 1]))
    # Quickly: the warm start, the table's nearest seeds and the capped restarts, no more.
    ik = motion.ik
    assert 0 < ik.stats.attempts <= 1 + ik.n_seeds + ik.restarts
    # Beside the object, hand below the table top: IK converges, the hand is in the table.
    with pytest.raises(UnreachableError, match="collision at the goal"):
        motion.plan(Pose([-0.2, 0.0, -0.07], look_at_quaternion(np.array([1.0, 0, 0]), 0.0)))
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


def test_robot_seconds_are_the_executed_durations(motion):
    motion.move_to(grasp([0, 0, 1]))
    motion.move_to(grasp([-1, 0, 1]))
    with pytest.raises(UnreachableError):
        motion.move_to(Pose([3.0, 0.0, 0.0], [0, 0, 0, 1]))
    done = motion.arm.trajectories
    assert motion.moves == len(done) == 2
    assert motion.robot_seconds == pytest.approx(sum(float(t.times[-1]) for t in done))
    assert motion.last_motion_s == 0.0  # the failed move took no robot time
    assert motion.planning_seconds > motion.last_planning_s > 0.0


def test_reachable_goals_are_reused_and_the_retreat_is_the_last_pre_grasp(motion):
    poses = np.array([grasp([0, 0, 1]).as_array(), grasp([-1, 0, 1]).as_array()])
    assert motion.reachable(poses).all()
    solved = dict(motion._goals)
    first = motion.plan(Pose.from_array(poses[0]))
    # No IK: the pose was solved by reachable(), and that solution is the goal.
    assert any(np.array_equal(first.goal, g[0]) for g in solved.values())
    np.testing.assert_array_equal(first.waypoints[-1], first.goal)
    motion.arm.execute(first.trajectory)
    second = motion.plan(Pose.from_array(poses[1]))
    # Leaving a grasp: straight back to the pre-grasp the approach came from.
    np.testing.assert_array_equal(second.waypoints[1], first.pre_grasp)
    # A new placement forgets the solutions (they were for the old scene).
    motion.set_placement(baxter_placement(float(EXTENTS[2]), xy=(0.62, 0.25)))
    assert not motion._goals and motion.last_plan is None


def test_travel_times_estimate_the_planned_moves(motion):
    # Grasp to grasp: retreat, straight transit, approach, timed as ruckig times them.
    poses = np.array(
        [
            grasp([0, 0, 1]).as_array(),
            grasp([0, 0, 1], roll=np.pi / 2).as_array(),
            grasp([-0.3, 0, 1]).as_array(),
            grasp([1, 0, 0.2]).as_array(),  # unreachable
        ]
    )
    ok = motion.reachable(poses)
    assert ok.tolist() == [True, True, True, False]
    est = motion.travel_times(poses)
    assert est.shape == (4, 4) and np.all(np.diag(est) == 0.0)
    assert np.isnan(est[3, :3]).all() and np.isnan(est[:3, 3]).all()
    np.testing.assert_allclose(est[:3, :3], est[:3, :3].T)  # the same path back
    motion.move_to(Pose.from_array(poses[0]))
    straight = 0
    for i, j in ((0, 1), (1, 2), (2, 0)):
        motion.move_to(Pose.from_array(poses[j]))
        plan = motion.last_plan
        if not plan.used_rrt and len(plan.waypoints) == 4:  # grasp, retreat, pre-grasp, goal
            assert plan.duration_s == pytest.approx(est[i, j], rel=1e-6)
            straight += 1
        else:  # a path round something takes longer than the straight estimate
            assert plan.duration_s >= est[i, j] * 0.999
    assert straight >= 1


def test_a_blocked_motion_counts_the_time_it_moved(motion, monkeypatch):
    from activetouch.errors import MotionBlockedError

    def blocked(trajectory):  # as the Baxter twin stops at a contact 1.25 s in
        raise MotionBlockedError("arm trajectory blocked at t = 1.260 s: contact", 1.25)

    monkeypatch.setattr(motion.arm, "execute", blocked)
    with pytest.raises(UnreachableError, match="blocked"):
        motion.move_to(grasp([0, 0, 1]))
    assert motion.robot_seconds == pytest.approx(1.25) and motion.moves == 0
    assert motion.last_motion_s == 0.0
