"""The floating wrist counts robot seconds: the durations of the trajectories it executed."""

from __future__ import annotations

import numpy as np
import pytest

from activetouch.config import WorkcellConfig
from activetouch.errors import StoppedError, UnreachableError
from activetouch.fakes.replay import fake_arm
from activetouch.interfaces import Pose
from activetouch.planning.motion.base import Placement, WristMotion
from activetouch.planning.motion.floating import (
    FloatingWristMotion,
    floating_limits,
    straight_trajectory,
)

UP = np.array([0.0, 0.0, 0.0, 1.0])


def test_wrist_motion_counters_default_to_zero() -> None:
    class Still(WristMotion):
        def move_to(self, pose: Pose) -> None:
            pass

    w = Still()
    w.move_to(Pose(np.zeros(3), UP))
    assert (w.robot_seconds, w.planning_seconds, w.moves) == (0.0, 0.0, 0)
    assert (w.last_motion_s, w.last_planning_s) == (0.0, 0.0)


def test_robot_seconds_are_the_executed_trajectories_durations() -> None:
    arm = fake_arm(floating_limits(WorkcellConfig()))
    wrist = FloatingWristMotion(arm, Placement(np.array([0.0, 0.0, 0.1])))
    other = FloatingWristMotion(fake_arm(floating_limits(WorkcellConfig())))
    expected = []
    for xyz in ([0.2, 0.0, 0.3], [0.0, -0.3, 0.2], [0.1, 0.1, 0.5]):
        pose = Pose(np.array(xyz), UP)
        start = arm.joint_state().position
        want = straight_trajectory(start, wrist.target_joints(pose), arm.limits.velocity)
        wrist.move_to(pose)
        expected.append(float(want.times[-1]))
        assert wrist.last_motion_s == pytest.approx(expected[-1], rel=1e-12)
    assert wrist.moves == 3 and wrist.robot_seconds == pytest.approx(sum(expected))
    assert 0.4 < wrist.robot_seconds < 10.0
    assert other.robot_seconds == 0.0  # counted per instance, not on the class

    # Motions that do not complete add nothing and leave last_motion_s at 0.
    total = wrist.robot_seconds
    with pytest.raises(UnreachableError):
        wrist.move_to(Pose(np.array([50.0, 0.0, 0.3]), UP))
    assert wrist.last_motion_s == 0.0
    arm.stop()
    with pytest.raises(StoppedError):
        wrist.move_to(Pose(np.array([0.0, 0.0, 0.3]), UP))
    assert wrist.last_motion_s == 0.0
    assert wrist.robot_seconds == total and wrist.moves == 3
