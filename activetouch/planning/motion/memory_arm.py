"""A joint-level `Arm` in memory: follows a trajectory by jumping to its end, after checking it
against the limits (position, and velocity where given). For tests and benchmarks of the motion
layer without a simulator."""

from __future__ import annotations

import time

import numpy as np

from activetouch.errors import ActiveTouchError, UnreachableError
from activetouch.interfaces import Arm, JointLimits, JointState, JointTrajectory, StopLatch


class MemoryArm(Arm):
    def __init__(self, names: tuple[str, ...], limits: JointLimits, q0: np.ndarray) -> None:
        self._names = tuple(names)
        self._limits = limits
        self._q = np.asarray(q0, dtype=np.float64).copy()
        self.stop_latch = StopLatch()
        self.trajectories: list[JointTrajectory] = []

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._names

    @property
    def limits(self) -> JointLimits:
        return self._limits

    def connect(self) -> None:
        pass

    def disconnect(self) -> None:
        pass

    def joint_state(self) -> JointState:
        return JointState(self._names, self._q.copy(), np.zeros(len(self._q)), time.monotonic())

    def set_q(self, q: np.ndarray) -> None:
        self._q = np.asarray(q, dtype=np.float64).copy()

    def execute(self, trajectory: JointTrajectory) -> None:
        self.stop_latch.check("arm motion")
        if tuple(trajectory.names) != self._names:
            raise ActiveTouchError(f"joint names {trajectory.names} != {self._names}")
        q = np.atleast_2d(np.asarray(trajectory.positions, dtype=np.float64))
        bad = self._limits.violations(self._names, q)
        if trajectory.velocities is not None:
            v = np.abs(np.asarray(trajectory.velocities))
            over = np.nonzero(np.any(v > self._limits.velocity * (1 + 1e-6), axis=0))[0]
            bad += [f"{self._names[j]} velocity over its limit" for j in over]
        if bad:
            raise UnreachableError(f"trajectory outside the joint limits: {'; '.join(bad)}")
        self._q = q[-1].copy()
        self.trajectories.append(trajectory)

    def stop(self) -> None:
        self.stop_latch.set()

    def clear_stop(self) -> None:
        self.stop_latch.clear()
