"""Inverse kinematics: damped least squares on the SE(3) log error with the LOCAL frame
Jacobian, joint limits by clamping, a warm start from the current configuration, seeds from a
table of solved poses (nearest in pose), then random restarts; returns the accepted solution
nearest the current configuration."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from activetouch.planning.motion.robot import ArmModel

ORIENTATION_WEIGHT_M = 0.15  # metres of seed-feature distance per unit of axis difference


def pose_features(rotations: np.ndarray, translations: np.ndarray) -> np.ndarray:
    """(n, 9) features for nearest-pose lookup: position and the weighted x and z axes."""
    r = np.asarray(rotations).reshape(-1, 3, 3)
    t = np.asarray(translations).reshape(-1, 3)
    w = ORIENTATION_WEIGHT_M
    return np.hstack([t, w * r[:, :, 0], w * r[:, :, 2]])


def dls_step(jac: np.ndarray, err: np.ndarray, damping: float) -> np.ndarray:
    """Damped least squares: J^T (J J^T + damping I)^-1 err."""
    jjt = jac @ jac.T
    jjt[np.diag_indices_from(jjt)] += damping
    return jac.T @ np.linalg.solve(jjt, err)


def joint_distance(q: np.ndarray, ref: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Seconds-like distance: the slowest joint's travel time at full speed, per row of `q`."""
    return np.max(np.abs(np.atleast_2d(q) - ref) / velocity, axis=-1)


@dataclass
class IKStats:
    attempts: int = 0
    iterations: int = 0
    converged: int = 0  # solutions found before `accept`
    rejected: int = 0  # converged but refused by `accept`


class SeedTable:
    """Configurations indexed by their hand pose: the nearest ones seed IK."""

    def __init__(self, arm: ArmModel, q: np.ndarray) -> None:
        self.arm = arm
        self.q = np.empty((0, arm.nq))
        self.features = np.empty((0, 9))
        self._tree = None
        self.add(q)

    @classmethod
    def random(cls, arm: ArmModel, n: int, seed: int = 0) -> SeedTable:
        rng = np.random.default_rng(seed)
        return cls(arm, rng.uniform(arm.lower, arm.upper, (n, arm.nq)))

    def add(self, q: np.ndarray) -> None:
        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        q = np.atleast_2d(np.asarray(q, dtype=np.float64)).reshape(-1, self.arm.nq)
        if len(q) == 0:
            return
        data = self.arm.model.createData()
        rots, trans = np.empty((len(q), 3, 3)), np.empty((len(q), 3))
        for i, qi in enumerate(q):
            pin.forwardKinematics(self.arm.model, data, qi)
            m = pin.updateFramePlacement(self.arm.model, data, self.arm.hand_frame)
            rots[i], trans[i] = m.rotation, m.translation
        self.q = np.vstack([self.q, q])
        self.features = np.vstack([self.features, pose_features(rots, trans)])
        self._tree = cKDTree(self.features)

    def nearest(self, rotation: np.ndarray, translation: np.ndarray, k: int) -> np.ndarray:
        if self._tree is None or len(self.q) == 0 or k <= 0:
            return np.empty((0, self.arm.nq))
        k = min(k, len(self.q))
        _, idx = self._tree.query(pose_features(rotation, translation)[0], k=k)
        return self.q[np.atleast_1d(idx)]

    def __len__(self) -> int:
        return len(self.q)


class IKSolver:
    """DLS IK for the hand frame of one arm."""

    def __init__(
        self,
        arm: ArmModel,
        seeds: SeedTable | None = None,
        tol: float = 1e-4,
        max_iter: int = 40,
        damping: float = 1e-6,
        n_seeds: int = 8,
        restarts: int = 30,
        seed: int = 0,
    ) -> None:
        self.arm = arm
        self.data = arm.model.createData()
        self.seeds = seeds
        self.tol, self.max_iter, self.damping = tol, max_iter, damping
        self.n_seeds, self.restarts = n_seeds, restarts
        self.rng = np.random.default_rng(seed)
        self.stats = IKStats()

    def descend(self, target, q0: np.ndarray) -> tuple[np.ndarray, float, int]:
        """DLS from `q0` towards `target` (pinocchio SE3, base frame): (q, error norm, iters)."""
        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        model, data, f = self.arm.model, self.data, self.arm.hand_frame
        lo, hi = self.arm.lower, self.arm.upper
        q = np.clip(np.asarray(q0, dtype=np.float64), lo, hi)
        best = np.inf
        stall = 0
        for it in range(1, self.max_iter + 1):
            pin.computeJointJacobians(model, data, q)
            m = pin.updateFramePlacement(model, data, f)
            err = pin.log6(m.actInv(target)).vector
            e = float(np.linalg.norm(err))
            if e < self.tol:
                return q, e, it
            if e > best * 0.98:  # not improving: a joint stuck at a limit, or a bad basin
                stall += 1
                if stall >= 4:
                    return q, e, it
            else:
                stall = 0
            best = min(best, e)
            jac = pin.getFrameJacobian(model, data, f, pin.LOCAL)
            dq = dls_step(jac, err, self.damping + 1e-3 * e * e)
            step = np.max(np.abs(dq))
            if step > 0.5:  # keep steps local: the error is linearised
                dq *= 0.5 / step
            q = np.clip(q + dq, lo, hi)
        return q, e, self.max_iter

    def starts(self, target, q_current: np.ndarray | None):
        """Warm start, table seeds nearest in pose, then uniform random restarts."""
        if q_current is not None:
            yield np.asarray(q_current, dtype=np.float64)
        if self.seeds is not None:
            yield from self.seeds.nearest(
                np.array(target.rotation), np.array(target.translation), self.n_seeds
            )
        for _ in range(self.restarts):
            yield self.rng.uniform(self.arm.lower, self.arm.upper)

    def solve(
        self,
        target,
        q_current: np.ndarray | None = None,
        accept: Callable[[np.ndarray], bool] | None = None,
        max_solutions: int = 1,
    ) -> np.ndarray | None:
        """A configuration putting the hand at `target` (pinocchio SE3, base frame) that
        `accept` allows, nearest `q_current` among the first `max_solutions` found; None if
        none was found. `self.stats` tells what happened (converged but refused or not)."""
        self.stats = IKStats()
        found: list[np.ndarray] = []
        for q0 in self.starts(target, q_current):
            self.stats.attempts += 1
            q, e, it = self.descend(target, q0)
            self.stats.iterations += it
            if e >= self.tol:
                continue
            self.stats.converged += 1
            if accept is not None and not accept(q):
                self.stats.rejected += 1
                continue
            found.append(q)
            if len(found) >= max_solutions:
                break
        if not found:
            return None
        if q_current is None or len(found) == 1:
            return found[0]
        d = joint_distance(np.array(found), np.asarray(q_current), self.arm.velocity)
        return found[int(np.argmin(d))]
