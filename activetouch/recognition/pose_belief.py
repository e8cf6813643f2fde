"""A belief over class x object placement, weighed with each class's mesh.

The paper assumes the object stands exactly where the workcell says. A lab's object is a few
centimetres and degrees off, and then every grasp is compared with training grasps made at a
pose the hand was not at. This belief keeps hypotheses h = (dx, dy, yaw) of where the object
really stands (on the table: x, y and a turn about the vertical through the class's pivot,
the axis it is roundest about, so a mug turns about its body and not about its bounding box's
centre beside it) and weighs each grasp under each (class y, h) with y's mesh:

- every contact (a sensor site that read contact) should lie on the surface: a Gaussian in
  its distance to the surface, plus a floor so one stray contact cannot rule a class out;
- every place a finger passed through while closing, and every site that ended the grasp
  without contact, should be outside the object: a sensor site deeper inside than a margin
  says "the object is not there" (a finger would have stopped on it).

    log b(y, h) = sum over grasps g of log p(g | y, h),   p(y | grasps) = sum_h softmax(b)

The signed distance is the distance to the nearest of dense surface samples (a k-d tree
query), signed by the mesh's generalised winding number: inside where the surface turns around
the point. A sample's face normal is not enough: in a cup's or a bowl's cavity, farther from
every wall than the grid's cap, the nearest sample may lie on the outside of the floor, and the
open space a hand reaches into read as solid (the true placement of a mug then explained worse
than a shifted look-alike's).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from activetouch.config import RecognitionConfig
from activetouch.errors import ConfigError
from activetouch.interfaces import Grasp, Pose
from activetouch.models import bh8, reflex
from activetouch.models.reflex import ReflexGeometry
from activetouch.recognition.contacts import hand_to_object
from activetouch.recognition.grasp_likelihood import (
    GraspLikelihood,
    LikelihoodParams,
    finger_closure,
    poses_under_offsets,
    softmax_belief,
)

_DEFAULTS = RecognitionConfig()
_MAY_BE_ZERO = (
    "range_m",
    "contact_offset_m",
    "range_deg",
    "free_margin_m",
    "prior_sigma_m",
    "prior_sigma_deg",
    "grasps_weight",
    "drift_m",
    "alternate_share",
)


@dataclass(frozen=True)
class PoseParams:
    """The `recognition.pose_*` settings without their prefix."""

    range_m: float = _DEFAULTS.pose_range_m
    step_m: float = _DEFAULTS.pose_step_m
    range_deg: float = _DEFAULTS.pose_range_deg
    step_deg: float = _DEFAULTS.pose_step_deg
    contact_sigma_m: float = _DEFAULTS.pose_contact_sigma_m
    contact_offset_m: float = _DEFAULTS.pose_contact_offset_m
    free_margin_m: float = _DEFAULTS.pose_free_margin_m
    free_sigma_m: float = _DEFAULTS.pose_free_sigma_m
    floor: float = _DEFAULTS.pose_floor
    prior_sigma_m: float = _DEFAULTS.pose_prior_sigma_m
    prior_sigma_deg: float = _DEFAULTS.pose_prior_sigma_deg
    grasps_weight: float = _DEFAULTS.pose_grasps_weight
    drift_m: float = _DEFAULTS.pose_drift_m
    alternate_share: float = _DEFAULTS.pose_alternate_share

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            ok = isinstance(v, int | float) and np.isfinite(v)
            ok = ok and (v >= 0 if f.name in _MAY_BE_ZERO else v > 0)
            if not ok:
                bound = ">= 0" if f.name in _MAY_BE_ZERO else "> 0"
                raise ConfigError(f"recognition.pose_{f.name} must be a number {bound}, got {v!r}")

    @classmethod
    def from_config(cls, rc: RecognitionConfig) -> PoseParams:
        return cls(**{f.name: getattr(rc, f"pose_{f.name}") for f in fields(cls)})


def pose_grid(p: PoseParams) -> np.ndarray:
    """(H, 3) hypotheses dx (m), dy (m), yaw (rad) on a grid over +-range, zero included."""

    def axis(r: float, s: float) -> np.ndarray:
        n = int(np.floor(r / s + 1e-9))
        return np.arange(-n, n + 1) * s

    xy = axis(p.range_m, p.step_m)
    yaw = np.deg2rad(axis(p.range_deg, p.step_deg))
    g = np.stack(np.meshgrid(xy, xy, yaw, indexing="ij"), axis=-1).reshape(-1, 3)
    return g


def grid_axes(hyps: np.ndarray) -> list[np.ndarray]:
    """The dx, dy and yaw values of the grid `hyps` (`pose_grid` order), each ascending."""
    return [np.unique(hyps[:, i]) for i in range(3)]


def log_prior(hyps: np.ndarray, p: PoseParams) -> np.ndarray:
    """(H,) log p(h) up to a constant: Gaussian in dx, dy and yaw where a sigma is set."""
    out = np.zeros(len(hyps))
    if p.prior_sigma_m > 0:
        out -= 0.5 * (hyps[:, 0] ** 2 + hyps[:, 1] ** 2) / p.prior_sigma_m**2
    if p.prior_sigma_deg > 0:
        out -= 0.5 * (hyps[:, 2] / np.deg2rad(p.prior_sigma_deg)) ** 2
    return out


# Distances beyond this are not needed exactly: both terms saturate (contact: under the floor;
# free: the floor) well before it, and a bounded k-d tree query is ~30x faster.
DISTANCE_CAP_M = 0.025
SDF_VERSION = 2  # of the grid's construction: cached grids of another version are rebuilt
PIVOT_VERSION = 1  # of `roundest_axis`: a stored pivot of another version is found again


@dataclass
class ClassShape:
    """One class's signed distance (object frame, metres, negative inside, clipped to
    +-`DISTANCE_CAP_M`) on a voxel grid over its bounding box and the cap, read trilinearly.
    Built from dense surface samples signed by their face normals."""

    origin: np.ndarray  # (3,) the grid's first corner
    step: float
    values: np.ndarray  # (nx, ny, nz) float32
    pivot: np.ndarray | None = None  # (2,) `pivot_xy` once found (stored with the grid)

    @classmethod
    def from_mesh(
        cls, vertices: np.ndarray, faces: np.ndarray, step: float = 0.004, n: int = 20000
    ) -> ClassShape:
        # deferred: loads trimesh (with its optional backends)
        import trimesh

        mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, int), process=True)
        pts, _ = trimesh.sample.sample_surface(mesh, n, seed=0)
        lo = mesh.bounds[0] - DISTANCE_CAP_M
        shape = np.ceil((mesh.bounds[1] + DISTANCE_CAP_M - lo) / step).astype(int) + 1
        axes = [lo[k] + step * np.arange(shape[k]) for k in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        d, _ = cKDTree(np.asarray(pts)).query(grid, k=1, distance_upper_bound=DISTANCE_CAP_M)
        d = np.minimum(d, DISTANCE_CAP_M)  # inf beyond the bound
        inside = grid_inside(np.asarray(mesh.triangles, dtype=np.float64), grid, d, shape, step)
        sd = np.where(inside, -d, d)
        out = cls(lo, float(step), sd.reshape(shape).astype(np.float32))
        out.pivot = roundest_axis(out)
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {
            "origin": self.origin,
            "step": np.array([self.step]),
            "values": self.values,
            "pivot": self.pivot_xy,
            "pivot_version": np.array([PIVOT_VERSION]),
        }

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> ClassShape:
        origin = np.asarray(d["origin"], dtype=np.float64).reshape(3)
        values = np.asarray(d["values"], dtype=np.float32)
        step = float(np.asarray(d["step"]).reshape(-1)[0])
        if values.ndim != 3 or min(values.shape) < 2 or not step > 0:
            raise ValueError("malformed signed-distance grid")
        pivot = None
        if has_pivot(d):  # else (stored before it, or by another version) found when asked
            pivot = np.asarray(d["pivot"], dtype=np.float64).reshape(2)
        return cls(origin, step, values, pivot)

    @property
    def bottom_z(self) -> float:
        """The mesh's lowest point (the grid reaches the cap beyond the mesh's bounds)."""
        return float(self.origin[2]) + DISTANCE_CAP_M

    @property
    def pivot_xy(self) -> np.ndarray:
        """(2,) where the class turns on the table (object frame, metres): `roundest_axis`.
        The frame's origin is its bounding box's centre, 17 mm off a handle mug's body:
        turned about it, the body swings along an arc that meets the placements' 1 cm grid
        nearer to where the contacts fit best than a plain mug's body, which stands in one
        place however it is turned: an edge for the handle mugs that their shapes do not give
        them (docs/benchmark.md)."""
        if self.pivot is None:
            self.pivot = roundest_axis(self)
        return self.pivot

    def signed_distance(self, p: np.ndarray) -> np.ndarray:
        """(M,) at points (M, 3); +cap outside the grid (farther than the cap from it)."""
        u = (np.asarray(p, dtype=np.float64).reshape(-1, 3) - self.origin) / self.step
        return trilinear(self.values, u, DISTANCE_CAP_M)


# `roundest_axis`: the turn it tries, the candidates' spacing (coarse, then fine), how many
# surface points it turns, how near the surface a turned point counts as still on it, and
# the share of the surface that must stay on it for the class to count as round.
ROUND_TURN_RAD = np.deg2rad(15.0)
ROUND_STEPS_M = (0.004, 0.001)
ROUND_POINTS = 1000
ROUND_ON_M = 0.002
ROUND_SHARE = 0.5


def solid_centroid(shape: ClassShape) -> np.ndarray:
    """(2,) x and y of the solid's centroid, each grid node weighted by its depth inside (a
    node count would lean by the grid's placement, by up to half a step)."""
    w = np.maximum(-shape.values, 0.0).sum(axis=2)  # (nx, ny)
    total = float(w.sum())
    if total <= 0.0:
        return np.zeros(2)
    ix, iy = np.indices(w.shape)
    return shape.origin[:2] + shape.step * np.array([(w * ix).sum(), (w * iy).sum()]) / total


def kept_on_surface(shape: ClassShape, pts: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(C,) for each vertical axis through `axes` (C, 2), the share of the surface points
    `pts` (N, 3) within `ROUND_ON_M` of the surface once turned by +-`ROUND_TURN_RAD` about
    it (the two turns' mean)."""
    kept = np.zeros(len(axes))
    for turn in (ROUND_TURN_RAD, -ROUND_TURN_RAD):
        # the class turned about each axis; its surface read in that frame: turned back
        turned = class_frames(np.array([[0.0, 0.0, turn]]), axes)[:, 0]  # (C, 3)
        moved = in_object_frames(pts, turned)  # (C, N, 3)
        sd = shape.signed_distance(moved.reshape(-1, 3)).reshape(len(axes), -1)
        kept += 0.5 * np.mean(np.abs(sd) <= ROUND_ON_M, axis=1)
    return kept


def roundest_axis(shape: ClassShape) -> np.ndarray:
    """(2,) where the class turns, to the millimetre: the vertical axis most of its surface
    stays on when turned by +-`ROUND_TURN_RAD` about it (a mug's body's axis, which only the
    handle leaves), where more than `ROUND_SHARE` does and noticeably more than about its
    solid's centroid; else that centroid (a box, which no axis keeps, turns about its
    centre; a round class's axis is its centroid, not a millimetre beside it by chance)."""
    centroid = solid_centroid(shape)
    near = np.argwhere(np.abs(shape.values) < 0.5 * shape.step)
    if not len(near):
        return np.round(centroid, 3) + 0.0
    near = near[:: max(1, len(near) // ROUND_POINTS)]
    pts = shape.origin + shape.step * near
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    best, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    for step in ROUND_STEPS_M:
        grid = [np.arange(best[i] - half[i], best[i] + half[i] + 1e-9, step) for i in range(2)]
        cands = np.stack(np.meshgrid(*grid, indexing="ij"), axis=-1).reshape(-1, 2)
        kept = kept_on_surface(shape, pts, cands)
        best = cands[int(np.argmax(kept))]
        half = np.full(2, 2.0 * ROUND_STEPS_M[0])
    at_best, at_centroid = kept_on_surface(shape, pts, np.stack([best, centroid]))
    round_about = at_best > ROUND_SHARE and at_best > at_centroid + 0.01
    return np.round(best if round_about else centroid, 3) + 0.0


def has_pivot(d: dict[str, np.ndarray]) -> bool:
    """Whether stored grid arrays `d` hold a pivot found by this `roundest_axis`."""
    version = d.get("pivot_version")
    return "pivot" in d and version is not None and int(np.ravel(version)[0]) == PIVOT_VERSION


@njit(cache=True)
def trilinear(values: np.ndarray, u: np.ndarray, outside: float) -> np.ndarray:
    """(M,) `values` (nx, ny, nz) read trilinearly at grid coordinates `u` (M, 3); `outside`
    where a point is off the grid. Compiled: the belief reads every class at every
    hypothesis's points, millions of reads per grasp."""
    out = np.empty(len(u))
    for m in range(len(u)):
        out[m] = trilinear_at(values, u[m, 0], u[m, 1], u[m, 2], outside)
    return out


@njit(cache=True)
def trilinear_at(values: np.ndarray, x: float, y: float, z: float, outside: float) -> float:
    """`values` (nx, ny, nz) read trilinearly at one point's grid coordinates; `outside` off
    the grid."""
    nx, ny, nz = values.shape
    if not (0.0 <= x <= nx - 1 and 0.0 <= y <= ny - 1 and 0.0 <= z <= nz - 1):
        return outside
    i, j, k = (
        min(int(np.floor(x)), nx - 2),
        min(int(np.floor(y)), ny - 2),
        min(int(np.floor(z)), nz - 2),
    )
    fx, fy, fz = x - i, y - j, z - k
    acc = 0.0
    for dx in range(2):
        wx = fx if dx else 1.0 - fx
        for dy in range(2):
            wy = fy if dy else 1.0 - fy
            for dz in range(2):
                wz = fz if dz else 1.0 - fz
                acc += wx * wy * wz * values[i + dx, j + dy, k + dz]
    return acc


def grid_inside(
    triangles: np.ndarray, grid: np.ndarray, d: np.ndarray, shape: np.ndarray, step: float
) -> np.ndarray:
    """(M,) whether each grid point (M, 3; a grid of `shape`, `d` its distances to the
    surface samples) is inside the mesh. Points near the surface get their own winding number;
    a connected region of points all farther than 1.5 steps from it cannot cross the surface
    between neighbours, so one winding number signs the whole region (a large mesh's grid in
    a second, not a minute)."""
    # deferred: scipy.ndimage is loaded only to build a grid
    from scipy import ndimage

    far = (d > 1.5 * step).reshape(tuple(shape))
    regions, _ = ndimage.label(far)
    regions = regions.reshape(-1)
    near = np.flatnonzero(regions == 0)
    first = np.unique(regions, return_index=True)[1][1:]  # one point of each region 1..n
    w = winding_numbers(triangles, grid[np.concatenate([near, first])])
    inside = np.empty(len(grid), dtype=bool)
    inside[near] = w[: len(near)] > 0.5
    region_inside = np.concatenate([[False], w[len(near) :] > 0.5])
    inside[regions > 0] = region_inside[regions[regions > 0]]
    return inside


@njit(cache=True)
def winding_numbers(triangles: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(M,) generalised winding number of each point of `q` (M, 3) for the triangles (T, 3, 3)
    (outward-facing): 1 inside a closed surface, 0 outside, in between near holes. Each
    triangle adds its solid angle seen from the point over 4 pi (Van Oosterom and Strackee)."""
    out = np.zeros(len(q))
    for m in range(len(q)):
        acc = 0.0
        for t in range(len(triangles)):
            ax = triangles[t, 0, 0] - q[m, 0]
            ay = triangles[t, 0, 1] - q[m, 1]
            az = triangles[t, 0, 2] - q[m, 2]
            bx = triangles[t, 1, 0] - q[m, 0]
            by = triangles[t, 1, 1] - q[m, 1]
            bz = triangles[t, 1, 2] - q[m, 2]
            cx = triangles[t, 2, 0] - q[m, 0]
            cy = triangles[t, 2, 1] - q[m, 1]
            cz = triangles[t, 2, 2] - q[m, 2]
            la = np.sqrt(ax * ax + ay * ay + az * az)
            lb = np.sqrt(bx * bx + by * by + bz * bz)
            lc = np.sqrt(cx * cx + cy * cy + cz * cz)
            det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
            den = (
                la * lb * lc
                + (ax * bx + ay * by + az * bz) * lc
                + (bx * cx + by * cy + bz * cz) * la
                + (cx * ax + cy * ay + cz * az) * lb
            )
            acc += 2.0 * np.arctan2(det, den)
        out[m] = acc / (4.0 * np.pi)
    return out


def yaw_rotation(yaw: np.ndarray) -> np.ndarray:
    """(H, 3, 3) rotations about z."""
    c, s = np.cos(yaw), np.sin(yaw)
    r = np.zeros((len(yaw), 3, 3))
    r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1], r[:, 2, 2] = c, -s, s, c, 1.0
    return r


def in_object_frames(points: np.ndarray, hyps: np.ndarray) -> np.ndarray:
    """(H, M, 3): points of the nominal object frame in the frame of the object as it stands
    under each hypothesis (moved by dx, dy and turned by yaw about the vertical)."""
    t = np.zeros((len(hyps), 1, 3))
    t[:, 0, :2] = hyps[:, :2]
    r = yaw_rotation(hyps[:, 2])
    return np.einsum("hji,hmj->hmi", r, points[None, :, :] - t)  # R^T (p - t)


def class_frames(hyps: np.ndarray, pivots: np.ndarray) -> np.ndarray:
    """(K, H, 3) each class's frame offset (dx, dy, yaw of its origin) under each hypothesis
    `hyps` (H, 3), a hypothesis being a move of the class's pivot (`pivots` (K, 2)) by dx,
    dy and a turn by yaw about it: the origin moves by d + p - R(yaw) p."""
    r = yaw_rotation(hyps[:, 2])[:, :2, :2]  # (H, 2, 2)
    out = np.repeat(hyps[None, :, :], len(pivots), axis=0)
    out[:, :, :2] += pivots[:, None, :] - np.einsum("hij,kj->khi", r, pivots)
    return out


def pivot_groups(pivots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct `pivots` (G, 2) and each class's index among them (K,)."""
    unique, groups = np.unique(pivots, axis=0, return_inverse=True)
    return unique, groups.reshape(-1)


# Where a grasp shows the object is not: hand-frame points from the grasp (its hand's model).
# A masked sensor's site stays among them: leaving it out (its silence says nothing) cost
# 0.14 [0.03, 0.27] grasps on the tuning seeds (docs/benchmark.md), as such a site is free
# far more often than it is pressed into the object unheard.
FreeSites = Callable[[Grasp], np.ndarray]


def reflex_free_sites(geom: ReflexGeometry | None = None) -> FreeSites:
    g = geom or ReflexGeometry()
    return lambda grasp: reflex.grasp_free_sites(
        g, grasp.preshape, finger_closure(grasp), grasp.sensor_ids
    )


def bh8_free_sites(grasp: Grasp) -> np.ndarray:
    return bh8.grasp_free_sites(grasp.preshape, finger_closure(grasp), grasp.sensor_ids)


def free_sites_for(family: str) -> FreeSites:
    """The free-space points of hand family `family` ("reflex" or "bh8")."""
    return bh8_free_sites if family == "bh8" else reflex_free_sites()


def grasp_points(grasp: Grasp, pose: Pose, free_sites: FreeSites) -> tuple[np.ndarray, np.ndarray]:
    """(contacts (C, 3), free (F, 3)) in the nominal object frame: the contacts the grasp
    reported, and the points its hand's model says the grasp found free (sensor sites left
    without contact, and those the fingers swept through on their way)."""
    contacts = hand_to_object(pose, np.asarray(grasp.xyz, dtype=np.float64).reshape(-1, 3))
    return contacts, hand_to_object(pose, free_sites(grasp))


def grasp_log_likelihood(
    shapes: list[ClassShape],
    hyps: np.ndarray,
    contacts: np.ndarray,
    free: np.ndarray,
    p: PoseParams,
    lifts: np.ndarray | None = None,
    groups: np.ndarray | None = None,
) -> np.ndarray:
    """(K, H) log p(grasp | class, hypothesis) from its contacts and free points. `hyps`:
    the object frame's offsets (H, 3), or with `groups` (K,) those of each pivot group
    (G, H, 3: `class_frames` of the distinct pivots), class k's being hyps[groups[k]].
    `lifts` (K,): how far each class's frame stands above the nominal one (`class_lifts`)."""
    H, nc = hyps.shape[-2], len(contacts)
    both = np.concatenate([contacts, free])
    if groups is None:
        hyps, groups = hyps[None], np.zeros(len(shapes), dtype=np.int64)
    moved = [in_object_frames(both, h).reshape(-1, 3) for h in hyps]  # once per group
    log_floor = np.log(p.floor)
    out = np.zeros((len(shapes), H))
    for k, shape in enumerate(shapes):
        pts = moved[groups[k]]
        q = pts if lifts is None or lifts[k] == 0.0 else pts - np.array([0.0, 0.0, lifts[k]])
        sd = shape.signed_distance(q).reshape(H, -1)
        if nc:
            on = np.exp(-0.5 * ((sd[:, :nc] - p.contact_offset_m) / p.contact_sigma_m) ** 2)
            out[k] += np.log(on + p.floor).sum(axis=1)
        depth = np.maximum(0.0, -sd[:, nc:] - p.free_margin_m) / p.free_sigma_m
        out[k] += np.maximum(-0.5 * depth**2, log_floor).sum(axis=1)
    return out


def class_lifts(shapes: list[ClassShape], support_z: float | None) -> np.ndarray:
    """(K,) the height of each class's frame above the nominal object frame when the class
    stands on the table at `support_z` (the table plane in the nominal frame): its mesh's
    lowest point on the plane. None (no table known): zeros."""
    if support_z is None:
        return np.zeros(len(shapes))
    bottoms = np.array([s.bottom_z for s in shapes])
    return float(support_z) - bottoms


def logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    return np.squeeze(m, axis) + np.log(np.sum(np.exp(a - m), axis=axis))


@dataclass
class PoseEstimate:
    """The object's placement under the most likely class: posterior mean and spread."""

    dx_m: float
    dy_m: float
    yaw_deg: float
    sd_x_m: float
    sd_y_m: float
    sd_yaw_deg: float

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


def drifted(log_b: np.ndarray, hyps: np.ndarray, sigma_m: float) -> np.ndarray:
    """(K, H) the belief `log_b` over the grid `hyps` (`pose_grid` order) after the object
    may have slid on the table by a Gaussian of `sigma_m` in x and y: each class's
    probability spread over the neighbouring placements of each yaw (mass the grid cannot
    hold is lost: the object is off it). No placement falls under 1e-300 of its class's best,
    so later grasps can still bring one back."""
    if sigma_m <= 0:
        return log_b
    # deferred: scipy.ndimage is loaded only by a belief that drifts
    from scipy import ndimage

    axes = grid_axes(hyps)
    if len(axes[0]) < 2:
        return log_b
    step = axes[0][1] - axes[0][0]
    top = log_b.max(axis=1, keepdims=True)
    p = np.exp(log_b - top).reshape(len(log_b), *(len(a) for a in axes))
    s = sigma_m / step
    q = ndimage.gaussian_filter(p, sigma=(0.0, s, s, 0.0), mode="constant", truncate=3.0)
    return np.log(np.maximum(q.reshape(len(log_b), -1), 1e-300)) + top


def mean_and_spread(log_b: np.ndarray, hyps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) posterior mean and (3,) standard deviation of the hypotheses `hyps` (H, 3) under
    one class's log belief `log_b` (H,)."""
    w = softmax_belief(log_b)
    mean = w @ hyps
    return mean, np.sqrt(np.maximum(0.0, w @ (hyps - mean) ** 2))


def pose_estimate(log_b: np.ndarray, hyps: np.ndarray, k: int) -> PoseEstimate:
    """Posterior mean and standard deviation of the hypotheses of class `k`."""
    mean, sd = mean_and_spread(log_b[k], hyps)
    return PoseEstimate(
        float(mean[0]),
        float(mean[1]),
        float(np.rad2deg(mean[2])),
        float(sd[0]),
        float(sd[1]),
        float(np.rad2deg(sd[2])),
    )


def peak_offset(log_b: np.ndarray, hyps: np.ndarray) -> np.ndarray:
    """(3,) where one class stands (dx, dy, yaw) by its log belief over the grid `hyps`
    (`pose_grid` order), between grid points. Along an axis the belief has pinned down (its
    spread under a step) the best hypothesis moves to the vertex of the parabola through it
    and its two neighbours (at most half a step); along one it has not (a round object's yaw)
    the posterior mean stands, which does not pick an edge of the grid by chance. Grasps
    placed on it land nearer where training grasped than on the grid's 1 cm."""
    axes = grid_axes(hyps)
    shape = tuple(len(a) for a in axes)
    lb = np.asarray(log_b, dtype=np.float64).reshape(-1)
    mean, sd = mean_and_spread(lb, hyps)
    grid = lb.reshape(shape)
    at = np.unravel_index(int(np.argmax(lb)), shape)
    out = mean.copy()
    for i in range(3):
        step = axes[i][1] - axes[i][0] if shape[i] > 1 else 0.0
        if shape[i] == 1 or sd[i] > step:
            continue
        out[i] = axes[i][at[i]]
        if not 0 < at[i] < shape[i] - 1:
            continue
        lo, hi = list(at), list(at)
        lo[i] -= 1
        hi[i] += 1
        a, b, c = grid[tuple(lo)], grid[at], grid[tuple(hi)]
        curve = a - 2.0 * b + c
        if np.isfinite(curve) and curve < -1e-9:
            out[i] += float(np.clip(0.5 * (a - c) / curve, -0.5, 0.5)) * step
    return out


def wrist_under_hypotheses(pose: Pose, hyps: np.ndarray) -> np.ndarray:
    """(H, 7) the wrist `pose` (nominal object frame) relative to the object as it stands
    under each hypothesis: T_h^-1 * pose (x y z qx qy qz qw)."""
    return poses_under_offsets(np.concatenate([pose.xyz, pose.quat]), hyps)


# The nominal placement within this many nats of the best: the grasps stay on it. A peak a few
# millimetres off by chance would move every grasp off the training poses of an object that
# stands where it should (the hard library, nominal, tuning seeds 100-102: 97 % following it,
# against 100 % without).
NOMINAL_NATS = 1.0
# Classes under this share of the mesh's class marginal have no say in where the grasps go.
COALITION_WEIGHT = 1e-3


def placement_gaps(a: np.ndarray, b: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """How far placements `a` are from `b` (..., 3: dx, dy, yaw; broadcast), in units of
    `scale` (3,) along each axis together, the yaw difference wrapped to +-pi."""
    d = a - b
    d[..., 2] = np.angle(np.exp(1j * d[..., 2]))
    return np.sqrt(np.sum((d / scale) ** 2, axis=-1))


def coalition_scores(peaks: np.ndarray, weights: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(n,) for each class's placement (`peaks` (n, 3): dx, dy, yaw), the probability of the
    classes (`weights` (n,)) whose own placements put the object within about `scale` (3,)
    of it: grasps placed there land on their training poses for all of them."""
    near = np.exp(-0.5 * placement_gaps(peaks[:, None, :], peaks[None, :, :], scale) ** 2)
    return near @ weights


# Placements closer than this (in grid steps of x, y and yaw together) are one placement.
APART_STEPS = 1.5


def rival_placement(
    peaks: np.ndarray,
    scores: np.ndarray,
    scale: np.ndarray,
    best: int,
    share: float,
    whole: np.ndarray | None = None,
) -> int | None:
    """The index of the placement most of the classes agree on after `best` (`peaks` (n, 3),
    `scores` (n,) from `coalition_scores`) among those more than `APART_STEPS` of `scale`
    from it, if its score is at least `share` of the best's, or its score by the whole
    belief (`whole` (n,), the same coalitions weighed by the class marginal with the training
    grasps' term) is; else None. A grasp placed for one group of classes lands on their
    training poses and off the others', whose training grasps then read blurred and lose to
    the group's: grasps shared between two rival placements give neither that edge. The
    mesh cannot tell a plain mug from three handle mugs whose handles no finger reached, so
    by it alone the plain mug's frame had a quarter of their support while the training
    grasps made it the likeliest class, and every grasp went to their frame until theirs won."""
    if share <= 0:
        return None
    apart = np.flatnonzero(placement_gaps(peaks, peaks[best], scale) > APART_STEPS)
    if not apart.size:
        return None
    support = scores[apart] / scores[best]
    if whole is not None and whole[best] > 0:
        support = np.maximum(support, whole[apart] / whole[best])
    i = int(np.argmax(support))
    return int(apart[i]) if support[i] >= share else None


# Hypotheses whose best class is this far (nats) below the best pair get no training-grasp
# term (they are ruled out already; it is the costly part).
PRUNE_NATS = 15.0


@dataclass
class PoseBelief:
    """log b(y, h) over the model's classes and the placement hypotheses, grasp by grasp:
    the mesh term, plus (with `grasps`) the grasp likelihood of the training grasps at the
    wrist pose each hypothesis implies, where the mesh cannot tell look-alikes apart (a
    handle the fingers did not reach, how far each finger closed)."""

    shapes: list[ClassShape]
    params: PoseParams
    free_sites: FreeSites
    grasps: tuple[GraspLikelihood, LikelihoodParams] | None = None
    support_z: float | None = None  # the table in the nominal frame: classes stand on it
    finger_sensors: int = 0  # the hand's sensors per finger (`GraspLikelihood.log_likelihood`)

    def __post_init__(self) -> None:
        self.hyps = pose_grid(self.params)  # moves of each class's pivot
        self.pivots = np.array([s.pivot_xy for s in self.shapes]).reshape(-1, 2)
        self._pivots, self._groups = pivot_groups(self.pivots)
        self._group_frames = class_frames(self.hyps, self._pivots)  # (G, H, 3)
        self.frames = self._group_frames[self._groups]  # (K, H, 3) where each frame stands
        self.log_b = np.tile(log_prior(self.hyps, self.params), (len(self.shapes), 1))
        self.lifts = class_lifts(self.shapes, self.support_z)
        self._nominal = int(np.flatnonzero(np.all(self.hyps == 0.0, axis=1))[0])  # h = 0
        # The mesh's term alone: where the object stands by geometry (`placement_peak`).
        self.mesh_log_b = self.log_b.copy()
        self._grasps = 0  # weighed so far

    def update(self, grasp: Grasp, pose: Pose, ignore: np.ndarray | None = None) -> None:
        if self._grasps and self.params.drift_m > 0:  # it may have slid since the last
            self.log_b = drifted(self.log_b, self.hyps, self.params.drift_m)
            self.mesh_log_b = drifted(self.mesh_log_b, self.hyps, self.params.drift_m)
        self._grasps += 1
        contacts, free = grasp_points(grasp, pose, self.free_sites)
        mesh = grasp_log_likelihood(
            self.shapes, self._group_frames, contacts, free, self.params, self.lifts, self._groups
        )
        self.mesh_log_b = self.mesh_log_b + mesh
        total = self.log_b + mesh
        if self.grasps is not None:
            model_l, lp = self.grasps
            best = total.max(axis=0)
            live = np.flatnonzero(best >= best.max() - PRUNE_NATS)
            x = np.stack([wrist_under_hypotheses(pose, f[live]) for f in self._group_frames])
            train = model_l.log_likelihood_at_poses(
                grasp, x, lp, ignore, self.finger_sensors, self._groups
            )  # (L, K)
            term = np.full(total.shape, float(train.min()))
            term[:, live] = train.T
            total = total + self.params.grasps_weight * term
        self.log_b = total

    def class_log_belief(self) -> np.ndarray:
        """(K,) log of the class marginal (up to a constant)."""
        return logsumexp(self.log_b, axis=1)

    def class_probabilities(self) -> np.ndarray:
        """(K,) p(y | the grasps so far): the class marginal, normalised."""
        return softmax_belief(self.class_log_belief())

    def estimate(self, k: int) -> PoseEstimate:
        return pose_estimate(self.log_b, self.frames[k], k)

    def placement_peak(self) -> np.ndarray:
        """(3,) where the object most likely stands by the mesh's term alone: the nominal
        placement while, over all classes, it is within `NOMINAL_NATS` of the best (after a
        grasp or two the likeliest class is a guess: a mug 1.4 cm off fits a ball's side as
        well as the ball does where it stands); else, of the classes' own peaks
        (`peak_offset`), the one most of that term's class probability agrees with
        (`coalition_scores`). A placement is a class's frame: a handle mug's is off its body,
        so where it puts a round body is not where a round class does, and grasps placed for
        the one land off the other's training poses, whose term then reads at its floor
        (following the likeliest class alone, a handle mug drew the grasps to its frame and
        took a round object's runs). Not by the whole belief: the training grasps' term
        favours wherever a class's grasps happen to match, so a look-alike's chance match would
        pull the next grasps to its placement, away from where the true class's could match."""
        anyone = logsumexp(self.mesh_log_b, axis=0)
        if anyone[self._nominal] >= anyone.max() - NOMINAL_NATS:
            return np.zeros(3)  # where training grasped is as good as any: stay on it
        w = softmax_belief(logsumexp(self.mesh_log_b, axis=1))
        whole = self.class_probabilities()
        live = np.flatnonzero((w >= COALITION_WEIGHT) | (whole >= COALITION_WEIGHT))
        peaks = np.array(
            [self._frame_of(peak_offset(self.mesh_log_b[k], self.hyps), k) for k in live]
        )
        scale = np.array([self.params.step_m, self.params.step_m, np.deg2rad(self.params.step_deg)])
        scores = coalition_scores(peaks, w[live], scale)
        best = int(np.argmax(scores))
        if self._grasps % 2 == 1:  # every other grasp: the rival placement, if there is one
            rival = rival_placement(
                peaks,
                scores,
                scale,
                best,
                self.params.alternate_share,
                coalition_scores(peaks, whole[live], scale),
            )
            if rival is not None:
                return peaks[rival]
        return peaks[best]

    def _frame_of(self, h: np.ndarray, k: int) -> np.ndarray:
        """(3,) class `k`'s frame offset when its pivot is moved by the hypothesis `h`."""
        return class_frames(h[None, :], self.pivots[k : k + 1])[0, 0]
