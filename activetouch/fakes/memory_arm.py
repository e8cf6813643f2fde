"""A joint-level `Arm` in memory: follows a trajectory by jumping to its end, after checking it
against the limits (position, and velocity where given), once `time_scale` x its duration has
passed (a stop cuts that short). The fake arm type's floating wrist, and the arm of tests and
benchmarks of the motion layer without a simulator."""

from __future__ import annotations

import time

import numpy as np

from activetouch.errors import UnreachableError
from activetouch.interfaces import Arm, JointLimits, JointState, JointTrajectory, StopLatch
from activetouch.planning.motion.base import trajectory_positions


class MemoryArm(Arm):
    def __init__(
        self,
        names: tuple[str, ...],
        limits: JointLimits,
        q0: np.ndarray,
        time_scale: float = 0.0,
    ) -> None:
        self._names = tuple(names)
        self._limits = limits
        self._q = np.asarray(q0, dtype=np.float64).copy()
        self.time_scale = time_scale  # 0: motions take no time; 1: real time
        self.stop_latch = StopLatch()
        self.trajectories: list[JointTrajectory] = []

    @property
    def executed(self) -> int:
        """Trajectories run to their end."""
        return len(self.trajectories)

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
        q = trajectory_positions(trajectory, self._names)
        bad = self._limits.violations(self._names, q)
        if trajectory.velocities is not None:
            order = [list(trajectory.names).index(n) for n in self._names]
            v = np.abs(np.atleast_2d(np.asarray(trajectory.velocities, dtype=np.float64)))[:, order]
            over = np.nonzero(np.any(v > self._limits.velocity * (1 + 1e-6), axis=0))[0]
            bad += [f"{self._names[j]} velocity over its limit" for j in over]
        if bad:
            raise UnreachableError(f"trajectory outside the joint limits: {'; '.join(bad)}")
        times = np.asarray(trajectory.times, dtype=np.float64).reshape(-1)
        duration = float(times[-1] - times[0]) * self.time_scale if len(times) else 0.0
        if duration > 0 and self.stop_latch.wait(duration):
            self.stop_latch.check("arm motion")
        self._q = q[-1].copy()
        self.trajectories.append(trajectory)

    def stop(self) -> None:
        self.stop_latch.set()

    def clear_stop(self) -> None:
        self.stop_latch.clear()
