"""Timing with ruckig: jerk-limited rest-to-rest segments between the path's waypoints.

Each segment is phase-synchronised (every joint starts, peaks and stops together), so the
timed motion stays on the straight joint-space segment that was collision-checked. Segments
are chained state to state; ruckig's `intermediate_positions` are never used (the community
build sends them to a remote service)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    """One rest-to-rest segment: start, end, duration and the ruckig trajectory."""

    start: np.ndarray
    end: np.ndarray
    duration: float
    trajectory: object  # ruckig.Trajectory


def rest_to_rest(
    q0: np.ndarray,
    q1: np.ndarray,
    velocity: np.ndarray,
    acceleration: np.ndarray,
    jerk: np.ndarray,
) -> Segment:
    """Time-optimal jerk-limited motion from rest at `q0` to rest at `q1`."""
    import ruckig

    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    n = len(q0)
    inp = ruckig.InputParameter(n)
    inp.current_position = q0.tolist()
    inp.current_velocity = [0.0] * n
    inp.current_acceleration = [0.0] * n
    inp.target_position = q1.tolist()
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = np.broadcast_to(velocity, n).tolist()
    inp.max_acceleration = np.broadcast_to(acceleration, n).tolist()
    inp.max_jerk = np.broadcast_to(jerk, n).tolist()
    inp.synchronization = ruckig.Synchronization.Phase
    traj = ruckig.Trajectory(n)
    result = ruckig.Ruckig(n).calculate(inp, traj)
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
    """(times, positions, velocities, accelerations) every `dt` s and at each segment's end."""
    if not segments:
        raise ValueError("no segments to sample")
    times, pos, vel, acc = [], [], [], []
    t0 = 0.0
    for k, seg in enumerate(segments):
        ts = np.arange(0.0, seg.duration, dt)
        if k > 0:
            ts = ts[1:] if len(ts) and ts[0] == 0.0 else ts  # the previous end is this start
        ts = np.append(ts, seg.duration)
        for t in ts:
            p, v, a = seg.trajectory.at_time(float(t))
            times.append(t0 + float(t))
            pos.append(p)
            vel.append(v)
            acc.append(a)
        t0 += seg.duration
    return np.array(times), np.array(pos), np.array(vel), np.array(acc)


def duration_estimate(
    q0: np.ndarray, q1: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray
) -> float:
    """Lower bound on a rest-to-rest move's duration (trapezoid, per joint), before planning."""
    d = np.abs(np.asarray(q1) - np.asarray(q0))
    v, a = np.asarray(velocity), np.asarray(acceleration)
    t_tri = 2 * np.sqrt(d / a)
    t_trap = d / v + v / a
    return float(np.max(np.where(d < v * v / a, t_tri, t_trap)))
