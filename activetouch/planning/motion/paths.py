"""Joint-space paths: dense straight-line checks, and OMPL RRT-Connect where they collide."""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable

import numpy as np

from activetouch.planning.motion.collision import CollisionScene


def line_samples(q0: np.ndarray, q1: np.ndarray, step_rad: float) -> np.ndarray:
    """Points from q0 to q1 (both included), no joint moving more than `step_rad` between."""
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    n = max(1, int(np.ceil(np.max(np.abs(q1 - q0)) / step_rad)))
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    return q0 + s * (q1 - q0)


def segment_free(
    scene: CollisionScene,
    q0: np.ndarray,
    q1: np.ndarray,
    with_object: bool,
    step_rad: float,
    step_m: float,
    max_depth: int = 8,
) -> tuple[bool, np.ndarray | None]:
    """Check the straight segment densely: every joint step <= step_rad and, by bisection, every
    hand step <= step_m. Returns (free, first colliding configuration or None)."""
    qs = line_samples(q0, q1, step_rad)
    prev_q, prev_x = None, None
    for q in qs:
        if scene.in_collision(q, with_object):
            return False, q
        x = scene.hand_position()
        if prev_x is not None and np.linalg.norm(x - prev_x) > step_m:
            ok, bad = _bisect(scene, prev_q, q, prev_x, x, with_object, step_m, max_depth)
            if not ok:
                return False, bad
        prev_q, prev_x = q, x
    return True, None


def _bisect(scene, qa, qb, xa, xb, with_object, step_m, depth):
    if depth <= 0 or np.linalg.norm(xb - xa) <= step_m:
        return True, None
    qm = 0.5 * (qa + qb)
    if scene.in_collision(qm, with_object):
        return False, qm
    xm = scene.hand_position()
    ok, bad = _bisect(scene, qa, qm, xa, xm, with_object, step_m, depth - 1)
    if not ok:
        return ok, bad
    return _bisect(scene, qm, qb, xm, xb, with_object, step_m, depth - 1)


def path_free(
    scene: CollisionScene, waypoints: np.ndarray, with_object: bool, step_rad: float, step_m: float
) -> bool:
    wp = np.atleast_2d(waypoints)
    return all(
        segment_free(scene, a, b, with_object, step_rad, step_m)[0]
        for a, b in itertools.pairwise(wp)
    )


def rrt_connect(
    scene: CollisionScene,
    q0: np.ndarray,
    q1: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    time_s: float,
    step_rad: float,
    step_m: float,
    with_object: bool = True,
    clock: Callable[[], float] = time.perf_counter,
) -> np.ndarray | None:
    """A collision-free joint path q0 -> q1 (waypoints, re-checked densely) from OMPL's
    RRT-Connect with the coal check as validity: the shortcut path, else the raw one; None if
    none passes within `time_s` (by `clock`; OMPL's own search times itself)."""
    # deferred: OMPL only when a joint path is planned
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    n = len(q0)
    ou.setLogLevel(ou.LogLevel.LOG_ERROR)
    # OMPL's seed can be set only once per process, before any use: runs are not repeatable.
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(lower[i]))
        bounds.setHigh(i, float(upper[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    buf = np.empty(n)

    def valid(state) -> bool:
        for i in range(n):
            buf[i] = state[i]
        return not scene.in_collision(buf, with_object)

    ss.setStateValidityChecker(valid)
    si = ss.getSpaceInformation()
    extent = float(np.linalg.norm(np.asarray(upper) - np.asarray(lower)))
    si.setStateValidityCheckingResolution(min(0.05, 2 * step_rad / extent))
    start, goal = space.allocState(), space.allocState()
    for i in range(n):
        start[i] = float(q0[i])
        goal[i] = float(q1[i])
    ss.setStartAndGoalStates(start, goal)
    ss.setPlanner(og.RRTConnect(si))
    # OMPL checks its edges at discrete states and the shortcutter can cut a corner between
    # them, so a found path may fail the dense check. Then the raw path is tried, and failing
    # that the search starts again while time remains (giving up at once failed ~7 % of moves).
    deadline = clock() + float(time_s)
    while (left := deadline - clock()) > 0:
        ss.clear()
        if not ss.solve(left) or not ss.haveExactSolutionPath():
            return None
        raw = _states(ss.getSolutionPath(), n)
        candidates = [raw]
        left = deadline - clock()
        if left > 1e-3:  # OMPL reads a zero budget as "simplify without a time limit"
            ss.simplifySolution(min(0.2, left))
            candidates.insert(0, _states(ss.getSolutionPath(), n))
        for wp in candidates:
            if path_free(scene, wp, with_object, step_rad, step_m):
                return wp
    return None


def _states(path, n: int) -> np.ndarray:
    return np.array([[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())])
