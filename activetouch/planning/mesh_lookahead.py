"""One grasp ahead on the class x placement belief, each class's mesh saying what it would feel.

The tree and greedy policies simulate a grasp from the training grasps of a class at the
nominal placement: they cannot see that a mug standing 1.7 cm off its frame would meet a finger
at its handle where a plain mug would leave the finger free. This policy (`planner.policy =
"mesh"`) asks, for every unvisited pose and each of the likeliest (class, placement)
hypotheses of the pose belief, how far each finger would close before a sensor site met the
class's surface at that placement (`closure_stops`, on the belief's own signed-distance
grids), and picks the pose whose predicted closures leave the class the most probable after it:

    V(a) = sum_i w_i max_y p(y | o_i(a)),   p(y | o) ~ sum_j w_j N(o; o_j(a), s) [y_j = y]

over hypotheses i, j with weights w (the belief), o the three fingers' closing angles. Where no
pose is predicted to tell the hypotheses apart (V no better than the belief's own maximum),
the greedy search on the training grasps decides: the mesh knows placement, the training grasps
know the fine contact patterns a close leaves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy.spatial.transform import Rotation

from activetouch.models import reflex
from activetouch.models.reflex import ReflexGeometry
from activetouch.recognition.grasp_likelihood import pose_at_offset
from activetouch.recognition.pose_belief import (
    DISTANCE_CAP_M,
    ClassShape,
    PoseBelief,
    trilinear_at,
)

# The proximal angles the predicted close steps through (rad): finer than the grasp
# likelihood's closure width (0.05 rad) is not needed to tell a handle from free space.
SWEEP_STEP_RAD = 0.04
SWEEP_LIMIT_RAD = 2.2  # beyond this a finger has closed on nothing (its fist)


@dataclass(frozen=True)
class PackedShapes:
    """Every class's signed-distance grid in one flat array, for compiled reads."""

    values: np.ndarray  # (sum of grid sizes,) float32
    dims: np.ndarray  # (K, 3) int64
    origins: np.ndarray  # (K, 3)
    steps: np.ndarray  # (K,)
    offsets: np.ndarray  # (K,) int64 where each class's grid starts in `values`


def pack_shapes(shapes: list[ClassShape]) -> PackedShapes:
    sizes = np.array([s.values.size for s in shapes], dtype=np.int64)
    return PackedShapes(
        values=np.concatenate([s.values.reshape(-1) for s in shapes]).astype(np.float32),
        dims=np.array([s.values.shape for s in shapes], dtype=np.int64).reshape(-1, 3),
        origins=np.array([s.origin for s in shapes], dtype=np.float64).reshape(-1, 3),
        steps=np.array([s.step for s in shapes], dtype=np.float64),
        offsets=np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64),
    )


def finger_sweeps(geom: ReflexGeometry, preshape: float, coupling: float) -> np.ndarray:
    """(3, J, 9, 3): each finger's nine sensor sites (hand frame) as the free finger closes,
    step j at proximal angle theta = (j + 1) * SWEEP_STEP_RAD and distal k * theta (the
    tendon's split)."""
    angles = np.arange(1, int(SWEEP_LIMIT_RAD / SWEEP_STEP_RAD) + 1) * SWEEP_STEP_RAD
    sites = np.empty((reflex.N_FINGERS, len(angles), reflex.SENSORS_PER_FINGER, 3))
    for f in range(reflex.N_FINGERS):
        for j, a in enumerate(angles):
            sites[f, j] = reflex.finger_sensor_positions(geom, f, preshape, a, coupling * a)
    return sites


@njit(cache=True, parallel=True)
def closure_stops(
    values: np.ndarray,
    dims: np.ndarray,
    origins: np.ndarray,
    steps: np.ndarray,
    offsets: np.ndarray,
    lifts: np.ndarray,
    cls: np.ndarray,
    hyps: np.ndarray,
    sites: np.ndarray,
    touch_m: float,
    support_z: float,
) -> np.ndarray:
    """(P, M, 3) int: for the fingers' sweeps at each wrist pose (`sites` (P, 3, J, 9, 3), the
    nominal object frame) and hypotheses (class `cls` (M,), placement `hyps` (M, 3): dx, dy,
    yaw), the sweep step at which each finger's first site comes within `touch_m` of the
    class's surface or below the table (`support_z`); J where it closes on nothing. Steps are
    tried two at a time, then the one skipped (a site moves under 5 mm per step)."""
    P, F, J = sites.shape[0], sites.shape[1], sites.shape[2]
    M = len(cls)
    out = np.full((P, M, F), J, dtype=np.int64)
    for p in prange(P):
        for m in range(M):
            k = cls[m]
            n = dims[k, 0] * dims[k, 1] * dims[k, 2]
            grid = values[offsets[k] : offsets[k] + n].reshape((dims[k, 0], dims[k, 1], dims[k, 2]))
            # the class's frame where hypothesis m stands it, and its grid's corner and step
            at = (hyps[m, 0], hyps[m, 1], np.cos(hyps[m, 2]), np.sin(hyps[m, 2]), lifts[k])
            corner = (origins[k, 0], origins[k, 1], origins[k, 2], steps[k])
            for f in range(F):
                prev = -1
                for j in range(1, J + 1, 2):
                    jj = min(j, J - 1)
                    if _touches(grid, corner, at, sites[p, f, jj], touch_m, support_z):
                        first = jj
                        if jj - 1 > prev and _touches(
                            grid, corner, at, sites[p, f, jj - 1], touch_m, support_z
                        ):
                            first = jj - 1
                        out[p, m, f] = first
                        break
                    prev = jj
    return out


@njit(cache=True)
def _touches(
    grid: np.ndarray,
    corner: tuple[float, float, float, float],
    at: tuple[float, float, float, float, float],
    pts: np.ndarray,
    touch_m: float,
    support_z: float,
) -> bool:
    """Whether any of `pts` (S, 3, nominal frame) is below the table or within `touch_m` of
    the surface of a class (its signed distances `grid`, first corner and step `corner`)
    standing at `at` = (tx, ty, cos yaw, sin yaw, lift)."""
    tx, ty, c, s, lift = at
    ox, oy, oz, step = corner
    for q in range(pts.shape[0]):
        if pts[q, 2] < support_z:
            return True
        dx, dy = pts[q, 0] - tx, pts[q, 1] - ty
        x, y = c * dx + s * dy, -s * dx + c * dy  # R^T (p - t)
        d = trilinear_at(
            grid, (x - ox) / step, (y - oy) / step, (pts[q, 2] - lift - oz) / step, DISTANCE_CAP_M
        )
        if d < touch_m:
            return True
    return False


@njit(cache=True)
def expected_accuracy(
    closures: np.ndarray, w: np.ndarray, cls: np.ndarray, n_classes: int, sigma: float
) -> np.ndarray:
    """(P,) for predicted closing angles (P, M, 3) under hypotheses of weight `w` (M,, summing
    to 1) and class `cls` (M,): the expected probability of the likeliest class after the
    grasp, each hypothesis's prediction taken as what is felt, seen through a Gaussian of
    `sigma` per finger."""
    P, M, F = closures.shape
    out = np.zeros(P)
    post = np.zeros(n_classes)
    for p in range(P):
        v = 0.0
        for i in range(M):
            post[:] = 0.0
            for j in range(M):
                d2 = 0.0
                for f in range(F):
                    d = closures[p, i, f] - closures[p, j, f]
                    d2 += d * d
                post[cls[j]] += w[j] * np.exp(-0.5 * d2 / (sigma * sigma))
            v += w[i] * post.max() / post.sum()
        out[p] = v
    return out


def top_hypotheses(log_b: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(class (n,), hypothesis index (n,), weight (n,) summing to 1): the `m` likeliest (class,
    placement) pairs of the log belief (K, H)."""
    flat = log_b.reshape(-1)
    n = min(m, flat.size)
    top = np.argpartition(-flat, n - 1)[:n]
    w = np.exp(flat[top] - flat[top].max())
    k, h = np.divmod(top, log_b.shape[1])
    return k.astype(np.int64), h.astype(np.int64), w / w.sum()


def wrist_frames(poses: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (P, 3, 3), translations (P, 3)): the training poses (P, 7) as the session
    executes them, on the object believed to stand at `offset` (dx, dy, yaw)."""
    if np.any(offset):
        poses = np.array([pose_at_offset(p, offset) for p in poses])
    return Rotation.from_quat(poses[:, 3:]).as_matrix(), np.ascontiguousarray(poses[:, :3])


@dataclass(frozen=True)
class PlacementBelief:
    """What the session tells the mesh policy: its class x placement belief, where it will
    place the next grasp (the believed offset, dx dy yaw) and the preshape it grasps with."""

    belief: PoseBelief
    offset: np.ndarray
    preshape: float


def predicted_closures(
    belief: PoseBelief,
    poses: np.ndarray,
    preshape: float,
    offset: np.ndarray,
    cls: np.ndarray,
    frames: np.ndarray,
    *,
    coupling: float = 0.25,
    geom: ReflexGeometry | None = None,
    packed: PackedShapes | None = None,
) -> np.ndarray:
    """(P, M, 3) the proximal angle (rad) at which each finger's first sensor site meets class
    `cls[m]` with its frame at `frames[m]` (dx, dy, yaw; `belief.frames` rows), the hand at
    each of `poses` (P, 7, training poses) placed on the object believed at `offset`;
    `SWEEP_LIMIT_RAD` where it closes on nothing. `packed`: `pack_shapes(belief.shapes)`."""
    packed = packed or pack_shapes(belief.shapes)
    sweeps = finger_sweeps(geom or ReflexGeometry(), preshape, coupling)
    rot, trans = wrist_frames(poses, offset)
    # every pose's sweeps in the nominal object frame, once for all hypotheses
    sites = np.ascontiguousarray(
        np.einsum("pij,fksj->pfksi", rot, sweeps) + trans[:, None, None, None, :]
    )
    support = -np.inf if belief.support_z is None else float(belief.support_z)
    stops = closure_stops(
        packed.values,
        packed.dims,
        packed.origins,
        packed.steps,
        packed.offsets,
        np.asarray(belief.lifts, dtype=np.float64),
        np.asarray(cls, dtype=np.int64),
        np.ascontiguousarray(frames, dtype=np.float64),
        sites,
        belief.params.contact_offset_m,
        support,
    )
    return (stops + 1.0) * SWEEP_STEP_RAD


def predicted_values(
    belief: PoseBelief,
    poses: np.ndarray,
    preshape: float,
    offset: np.ndarray,
    *,
    hypotheses: int,
    sigma_rad: float,
    coupling: float = 0.25,
    geom: ReflexGeometry | None = None,
    packed: PackedShapes | None = None,
) -> tuple[np.ndarray, float]:
    """(V (P,) for each of `poses` (P, 7, training poses), the belief's own maximum class
    probability now) on `belief`'s `hypotheses` likeliest (class, placement) pairs. `packed`:
    `pack_shapes(belief.shapes)`, if the caller keeps it."""
    cls, hidx, w = top_hypotheses(belief.log_b, hypotheses)
    angles = predicted_closures(
        belief,
        poses,
        preshape,
        offset,
        cls,
        belief.frames[cls, hidx],
        coupling=coupling,
        geom=geom,
        packed=packed,
    )
    v = expected_accuracy(angles, w, cls, len(belief.shapes), sigma_rad)
    now = np.bincount(cls, weights=w, minlength=len(belief.shapes)).max()
    return v, float(now)
