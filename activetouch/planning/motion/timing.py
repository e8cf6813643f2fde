"""Timing with ruckig: jerk-limited rest-to-rest segments between the path's waypoints.

Each segment moves along the straight joint-space line between its waypoints (a 1-D ruckig
profile of the path parameter), so the timed motion is the segment that was collision-checked.
Segments are chained state to state; ruckig's `intermediate_positions` are never used (the community
build sends them to a remote service)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    """One rest-to-rest segment on the straight line start -> end: q(t) = start + u(t) (end -
    start), with u a jerk-limited 1-D ruckig profile from 0 to 1 whose limits are the tightest
    of the joints' limits scaled by their travel (so every joint stays within its own)."""

    start: np.ndarray
    end: np.ndarray
    duration: float
    trajectory: object  # ruckig.Trajectory of the 1-D path parameter u

    def at_time(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint position, velocity and acceleration at `t` s into the segment."""
        u, du, ddu = self.trajectory.at_time(float(t))
        d = self.end - self.start
        return self.start + u[0] * d, du[0] * d, ddu[0] * d


def path_limits(
    delta: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray, jerk: np.ndarray
) -> tuple[float, float, float]:
    """Limits on u (0 -> 1 along `delta`) that keep every joint within its own limits."""
    d = np.maximum(np.abs(np.asarray(delta, dtype=np.float64)), 1e-12)
    return (
        float(np.min(np.asarray(velocity) / d)),
        float(np.min(np.asarray(acceleration) / d)),
        float(np.min(np.asarray(jerk) / d)),
    )


def rest_to_rest(
    q0: np.ndarray,
    q1: np.ndarray,
    velocity: np.ndarray,
    acceleration: np.ndarray,
    jerk: np.ndarray,
) -> Segment:
    """Time-optimal jerk-limited straight-line motion from rest at `q0` to rest at `q1`.

    (ruckig's own multi-DoF phase synchronisation falls back to time synchronisation, which
    leaves the straight line, for most 7-DoF pairs: measured up to 0.17 rad off the line.)"""
    # deferred: ruckig only when a trajectory is timed
    import ruckig

    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    n = len(q0)
    vmax, amax, jmax = path_limits(
        q1 - q0,
        np.broadcast_to(velocity, n),
        np.broadcast_to(acceleration, n),
        np.broadcast_to(jerk, n),
    )
    inp = ruckig.InputParameter(1)
    inp.current_position = [0.0]
    inp.current_velocity = [0.0]
    inp.current_acceleration = [0.0]
    inp.target_position = [1.0]
    inp.target_velocity = [0.0]
    inp.target_acceleration = [0.0]
    inp.max_velocity = [vmax]
    inp.max_acceleration = [amax]
    inp.max_jerk = [jmax]
    traj = ruckig.Trajectory(1)
    result = ruckig.Ruckig(1).calculate(inp, traj)
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise ValueError(f"ruckig could not time the segment: {result}")
    return Segment(q0, q1, float(traj.duration), traj)


def time_path(
    waypoints: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray, jerk: np.ndarray
) -> list[Segment]:
    """Rest-to-rest segments through `waypoints` (m, n); zero-length steps are skipped."""
    wp = np.atleast_2d(np.asarray(waypoints, dtype=np.float64))
    out = []
    for a, b in itertools.pairwise(wp):
        if np.max(np.abs(b - a)) > 1e-9:
            out.append(rest_to_rest(a, b, velocity, acceleration, jerk))
    return out


def sample(segments: list[Segment], dt: float) -> tuple[np.ndarray, ...]:
    """(times, positions, velocities, accelerations) every `dt` s and at each segment's end.
    (Vectorised per segment: ruckig gives u(t), the joints follow as start + u (end - start).)"""
    if not segments:
        raise ValueError("no segments to sample")
    times, pos, vel, acc = [], [], [], []
    t0 = 0.0
    for k, seg in enumerate(segments):
        ts = np.arange(0.0, seg.duration, dt)
        if k > 0:
            ts = ts[1:] if len(ts) and ts[0] == 0.0 else ts  # the previous end is this start
        ts = np.append(ts, seg.duration)
        at = seg.trajectory.at_time
        prof = np.array([[v[0] for v in at(float(t))] for t in ts])  # (n, 3): u, du, ddu
        d = (seg.end - seg.start)[None, :]
        times.append(t0 + ts)
        pos.append(seg.start[None, :] + prof[:, :1] * d)
        vel.append(prof[:, 1:2] * d)
        acc.append(prof[:, 2:3] * d)
        t0 += seg.duration
    return np.concatenate(times), np.vstack(pos), np.vstack(vel), np.vstack(acc)


def straight_duration(
    delta: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray, jerk: np.ndarray
) -> np.ndarray:
    """Duration of `rest_to_rest` moves by `delta` (..., n), in closed form (no ruckig): the
    time-optimal jerk-limited rest-to-rest profile of the path parameter u from 0 to 1 under
    `path_limits`. What a move costs before it is planned (the planner's travel-time c_m)."""
    d = np.maximum(np.abs(np.asarray(delta, dtype=np.float64)), 1e-12)
    v = np.min(np.asarray(velocity) / d, axis=-1)
    a = np.min(np.asarray(acceleration) / d, axis=-1)
    j = np.min(np.asarray(jerk) / d, axis=-1)
    # Reaching v: with the acceleration limit (t = v/a + a/j) or on jerk alone (2 sqrt(v/j));
    # accelerating to v and back covers v * t; a longer move cruises the rest at v.
    reach_a = v * j >= a * a
    t_v = np.where(reach_a, v / a + a / j, 2.0 * np.sqrt(v / j))
    cruise = 1.0 / v + t_v
    # v not reached: with a reached (distance >= 2 a^3 / j^2), half of the move is a jerk-up,
    # constant-a, jerk-down of x + 2 a/j s; otherwise four jerk phases of (1 / (2 j))^(1/3).
    c = a / j
    x = (-3.0 * c + np.sqrt(c * c + 4.0 / a)) / 2.0
    short = np.where(2.0 * a * c * c <= 1.0, 2.0 * (x + 2.0 * c), 4.0 * np.cbrt(0.5 / j))
    out = np.where(v * t_v <= 1.0, cruise, short)
    return np.where(np.abs(np.asarray(delta)).max(axis=-1) > 1e-9, out, 0.0)
