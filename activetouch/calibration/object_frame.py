"""Object calibration: where the object really stands, from guarded touches around it.

Model. The workcell says where the object should be (its frame in the robot base frame:
`[workcell] object_xyz`, `object_yaw_deg`); it is really at x0 + dx, y0 + dy, turned by
yaw0 + dyaw about its vertical axis, standing on the table (z = table top + half its height:
not measured). The hand, fingers open, sensors facing the object and the thumb hanging straight
down in front of the palm (a 12 cm feeler), approaches it horizontally from `directions` sides
(`approach_rotation`): 0.5 mm steps until a sensor reports contact, then 0.1 mm steps pressing
<= 1.5 mm; the contact began where the pressure, linear in depth, extrapolates to zero
(`probing.guarded_descent`). The thumb has no sensor for 3.7 cm between its proximal and
distal sites, so each approach's hand height is chosen where the object's first contact (for
sideways placement errors up to `max_error_m`) meets a site most often (`start_pose`).

At the contact the hand's collision geometry (the twin URDF's boxes: housing, pad, swivels,
finger links, fingertips, at the measured joint angles) touches the object's surface (its
convex parts from the object library, sampled densely): one equation per touch,

    min over object surface points q, hand boxes b of  sdf_b( H_i^-1 T(dx, dy, dyaw) q ) = 0,

less a contact offset common to all touches (the skin and the onset extrapolation make the
touch report contact slightly early, ~0.8 mm in the twin; fitted, stored, bounded). (dx, dy,
offset) is found by soft-L1 least squares, first on a coarse sample of the surface, then on the
dense points near each touch; then (dx, dy, offset, dyaw) from several starting yaws, kept
only if the touches see yaw and it lowers the RMS residual by `yaw_gain_m` (a body of
revolution, or touches that miss a mug's handle, say nothing about yaw: it stays nominal).
A weak prior holds what the touches cannot see; the Jacobian's singular values are stored.

Refused: fewer than `min_touches` touches, the touches do not constrain x and y, an RMS
residual over `max_rms_m`, a correction over `max_correction_m` (5 cm) / `max_yaw_deg`, or a
contact offset over `max_offset_m` (another object, or another size, than the one named).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numba import njit
from scipy.optimize import least_squares
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from activetouch.calibration import store
from activetouch.calibration.probing import guarded_descent, in_contact_at_rest
from activetouch.calibration.store import CalibrationRecord
from activetouch.calibration.tactile import CalibrationRefusedError
from activetouch.interfaces import Hand, Pose
from activetouch.models.reflex import ReflexGeometry, collision_boxes
from activetouch.objects.library import read_obj_groups
from activetouch.planning.motion.base import Placement

if TYPE_CHECKING:
    from activetouch.calibration.probing import Flange
    from activetouch.models.reflex import ReflexGeometry
    from activetouch.objects.library import ObjectSpec

log = logging.getLogger(__name__)

IDENTITY = Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
DEFAULT_DEVICE = "workcell"  # the object record's device: the workcell, not a hand


@dataclass
class ObjectSettings:
    directions: int = 8  # horizontal approaches, evenly spaced around the expected place
    direction_offset_deg: float = 0.0  # the first approach comes from base +x turned by this
    bottom_clearance_m: float = 0.006  # the hand's lowest point at least this far above the table
    thumb_width_m: float = 0.014
    site_reach_m: float = 0.004  # a contact this close to a thumb site (along it) is felt
    max_error_m: float = 0.03  # placement error the start poses stay clear of (per axis)
    start_clearance_m: float = 0.015  # and this much more
    coarse_step_m: float = 0.0005
    fine_step_m: float = 0.0001
    press_m: float = 0.0015
    press_pressure: float = 120.0
    lift_clearance_m: float = 0.03  # transit between approaches this far above the object
    fit_yaw: bool = True
    yaw_starts_deg: list[float] = field(default_factory=lambda: [-60, -30, 0, 30, 60, 180])
    min_touches: int = 5
    min_xy_singular: float = 0.5  # smallest singular value over x, y, offset (unitless)
    min_yaw_sensitivity_m: float = 0.01  # |d residual / d yaw| (m/rad) below: yaw not observed
    xy_start_radius_m: float = 0.02  # the x-y fit also starts this far off along +-x, +-y
    yaw_gain_m: float = 0.0003  # yaw kept only if it lowers the RMS residual this much
    max_offset_m: float = 0.004  # |contact offset| above this: wrong object or size
    max_rms_m: float = 0.0015
    max_correction_m: float = 0.05
    max_yaw_deg: float = 90.0
    prior_weight: float = 1e-3  # metres of residual per metre / radian of correction
    surface_spacing_m: float = 0.0015  # object surface sample spacing (dense stage)
    coarse_points: int = 1500  # surface samples of the first stage


# -- geometry -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Boxes:
    """Oriented boxes in one frame: rotation (b, 3, 3), centre (b, 3), half sizes (b, 3)."""

    rot: np.ndarray
    centre: np.ndarray
    half: np.ndarray

    def __len__(self) -> int:
        return len(self.centre)


def hand_boxes(
    geom: ReflexGeometry | None = None,
    preshape: float = 0.0,
    proximal: Sequence[float] | np.ndarray | None = None,
    distal: Sequence[float] | np.ndarray | None = None,
) -> Boxes:
    """The hand's collision boxes (the twin URDF's, `models.reflex.collision_boxes`) in the
    hand frame at these joint angles (open by default), stacked for the distance kernels."""

    boxes = collision_boxes(geom, preshape, proximal, distal)
    return Boxes(
        np.stack([b.rotation for b in boxes]),
        np.stack([b.position for b in boxes]),
        np.stack([b.half for b in boxes]),
    )


def box_sdf(points: np.ndarray, boxes: Boxes) -> np.ndarray:
    """(n,) signed distance of each point (boxes' frame) to the union of the boxes."""
    local = np.matmul(points[None, :, :] - boxes.centre[:, None, :], boxes.rot)
    d = np.abs(local) - boxes.half[:, None, :]
    outside = np.linalg.norm(np.maximum(d, 0.0), axis=2)
    inside = np.minimum(d.max(axis=2), 0.0)
    return (outside + inside).min(axis=0)


@njit(cache=True)
def _min_sdf(points: np.ndarray, rot: np.ndarray, centre: np.ndarray, half: np.ndarray) -> float:
    best = np.inf
    for b in range(centre.shape[0]):
        for i in range(points.shape[0]):
            out = 0.0
            inside = -np.inf
            for k in range(3):
                v = 0.0
                for j in range(3):
                    v += (points[i, j] - centre[b, j]) * rot[b, j, k]
                dk = abs(v) - half[b, k]
                if dk > 0.0:
                    out += dk * dk
                if dk > inside:
                    inside = dk
            sd = np.sqrt(out) + min(inside, 0.0)
            if sd < best:
                best = sd
    return best


def min_box_sdf(points: np.ndarray, boxes: Boxes) -> float:
    """The smallest signed distance of `points` (boxes' frame) to the union of the boxes: the
    gap between a point set and the boxes (negative: the deepest point inside)."""
    return float(
        _min_sdf(
            np.ascontiguousarray(points, dtype=np.float64), boxes.rot, boxes.centre, boxes.half
        )
    )


@dataclass(frozen=True)
class ObjectShape:
    """What the fit knows of an object: surface samples of its convex parts (object frame)."""

    name: str
    extents: np.ndarray  # (3,) bounding-box size
    points: np.ndarray  # (n, 3) dense surface samples (part vertices included)
    coarse: np.ndarray  # (m, 3) a subset for the first stage

    @property
    def half_height(self) -> float:
        return float(self.extents[2]) / 2


def sample_parts(parts: list[np.ndarray], spacing: float, seed: int = 0) -> np.ndarray:
    """Vertices plus area-uniform samples (about one per spacing^2) of each part's convex
    hull surface."""
    rng = np.random.default_rng(seed)
    out = []
    for v in parts:
        hull = ConvexHull(v)
        tri = v[hull.simplices]  # (t, 3, 3)
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        n = int(np.ceil(area.sum() / spacing**2))
        idx = rng.choice(len(tri), size=n, p=area / area.sum())
        a, b = rng.random((2, n, 1))
        flip = (a + b) > 1
        a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
        t = tri[idx]
        out.append(t[:, 0] + a * (t[:, 1] - t[:, 0]) + b * (t[:, 2] - t[:, 0]))
        out.append(v[hull.vertices])
    return np.concatenate(out)


def object_shape(spec: ObjectSpec, spacing: float = 0.0015, coarse: int = 1500) -> ObjectShape:
    """The object's convex parts (what the twin collides with) as surface samples."""

    parts = [g for path in spec.collision_meshes for g in read_obj_groups(Path(path))]
    if not parts:
        raise CalibrationRefusedError(f"object {spec.name!r} has no collision parts to fit")
    pts = sample_parts(parts, spacing)
    rng = np.random.default_rng(1)
    sub = pts[rng.choice(len(pts), size=min(coarse, len(pts)), replace=False)]
    return ObjectShape(spec.name, np.asarray(spec.extents, dtype=np.float64), pts, sub)


# -- the fit --------------------------------------------------------------------------------


@dataclass(frozen=True)
class ObjectTouch:
    hand: Pose  # hand frame in the base frame where the contact began
    direction: np.ndarray  # (3,) approach direction, base frame
    sensor: int


def placement_at(nominal: Placement, x: np.ndarray) -> Placement:
    """The nominal placement moved by x = (dx, dy, offset[, dyaw]) (offset: not a placement)."""
    dyaw = float(x[3]) if len(x) > 3 else 0.0
    return Placement(nominal.xyz + np.array([x[0], x[1], 0.0]), nominal.yaw_rad + dyaw)


def touch_distances(
    touches: Sequence[ObjectTouch], points: Sequence[np.ndarray], boxes: Boxes, place: Placement
) -> np.ndarray:
    """(n,) signed distance between the hand (at each touch) and the object at `place`;
    `points[i]`: the object-frame surface samples used for touch i."""
    r = place.rotation
    out = np.empty(len(touches))
    for i, (t, p) in enumerate(zip(touches, points, strict=True)):
        world = r.apply(p) + place.xyz
        local = Rotation.from_quat(t.hand.quat).inv().apply(world - t.hand.xyz)
        out[i] = min_box_sdf(local, boxes)
    return out


@dataclass
class ObjectFit:
    placement: Placement
    correction_xy: np.ndarray  # (2,) metres
    correction_yaw_deg: float
    yaw_observed: bool  # yaw fitted (else kept nominal)
    offset_m: float  # contact offset: touches say contact this much before the geometry does
    residuals: np.ndarray  # (n,) metres
    rms_m: float
    rms_without_yaw_m: float  # the x-y fit's RMS (the yaw fit is kept if clearly better)
    singular_values: np.ndarray  # of the touch Jacobian over (x, y, offset[, yaw])
    yaw_sensitivity_m: float  # RMS over touches of d residual / d yaw (m/rad)


_X_SCALE = np.array([0.01, 0.01, 0.001, 0.2])


def _fit(
    touches: Sequence[ObjectTouch],
    shape: ObjectShape,
    boxes: Boxes,
    nominal: Placement,
    starts: list[np.ndarray],
    st: ObjectSettings,
):
    """Coarse samples from every start (lowest cost kept), then twice the dense samples near
    each touch. Returns (scipy result, dense samples per touch)."""

    def run(points: Sequence[np.ndarray], x0: np.ndarray, loss: str = "soft_l1"):
        def resid(x: np.ndarray) -> np.ndarray:
            d = touch_distances(touches, points, boxes, placement_at(nominal, x)) - x[2]
            return np.concatenate([d, st.prior_weight * x])

        return least_squares(
            resid, x0, loss=loss, f_scale=0.001, x_scale=_X_SCALE[: len(x0)], max_nfev=200
        )

    coarse = [shape.coarse] * len(touches)
    sol = min((run(coarse, x) for x in starts), key=lambda r: r.cost)
    for loss in ("soft_l1", "linear"):
        # Robust first (a stray touch cannot drag the start), then plain least squares: with
        # soft-L1 a lone touch that sees yaw (the handle) would count as an outlier.
        place = placement_at(nominal, sol.x)
        dense = [_near(shape, t, boxes, place, 0.01) for t in touches]
        sol = run(dense, sol.x, loss)
    return sol, dense


def _near(shape: ObjectShape, touch: ObjectTouch, boxes: Boxes, place: Placement, m: float):
    """The dense surface samples within `m` of the hand at this touch (object at `place`)."""
    world = place.rotation.apply(shape.points) + place.xyz
    local = Rotation.from_quat(touch.hand.quat).inv().apply(world - touch.hand.xyz)
    sel = box_sdf(local, boxes) < m
    return shape.points[sel] if sel.any() else shape.coarse


def solve_object(
    touches: Sequence[ObjectTouch],
    shape: ObjectShape,
    boxes: Boxes,
    nominal: Placement,
    settings: ObjectSettings | None = None,
) -> ObjectFit:
    """Least-squares placement from touches (see the module); CalibrationRefusedError when it
    is implausible."""
    st = settings or ObjectSettings()
    if len(touches) < st.min_touches:
        raise CalibrationRefusedError(
            f"object: {len(touches)} touches, need at least {st.min_touches}"
        )
    n = len(touches)
    # Several starts: the distance to the nearest surface point is not convex in x, y (a
    # handle or spout touched on the wrong side is a local minimum).
    r0 = st.xy_start_radius_m
    starts = [np.array([dx, dy, 0.0]) for dx, dy in ((0, 0), (r0, 0), (-r0, 0), (0, r0), (0, -r0))]
    sol, dense = _fit(touches, shape, boxes, nominal, starts, st)
    rms_xy = float(np.sqrt(np.mean(sol.fun[:n] ** 2)))
    x, jac, yaw_sens, yaw_used = np.append(sol.x, 0.0), sol.jac[:n], 0.0, False
    if st.fit_yaw:
        starts = [np.array([*sol.x, np.radians(a)]) for a in st.yaw_starts_deg]
        sol_y, dense_y = _fit(touches, shape, boxes, nominal, starts, st)
        rms_y = float(np.sqrt(np.mean(sol_y.fun[:n] ** 2)))
        yaw_sens = float(np.sqrt(np.mean(sol_y.jac[:n, 3] ** 2)))
        # Yaw is kept only when it explains the touches clearly better than x-y alone and
        # they see it (a body of revolution, or touches that miss the handle, do not).
        if yaw_sens >= st.min_yaw_sensitivity_m and rms_xy - rms_y > st.yaw_gain_m:
            x, jac, dense, yaw_used = sol_y.x, sol_y.jac[:n], dense_y, True
    place = placement_at(nominal, x)
    r = touch_distances(touches, dense, boxes, place) - x[2]
    rms = float(np.sqrt(np.mean(r**2)))
    sv = np.linalg.svd(jac, compute_uv=False)
    sv_xy = np.linalg.svd(jac[:, :3], compute_uv=False)  # x, y and the common offset
    dyaw = float(np.degrees(x[3]))
    fit = ObjectFit(place, x[:2].copy(), dyaw, yaw_used, float(x[2]), r, rms, rms_xy, sv, yaw_sens)
    problems = []
    if sv_xy.min() < st.min_xy_singular:
        problems.append(
            f"the touches do not pin x, y and the contact offset (singular value "
            f"{sv_xy.min():.2f} < "
            f"{st.min_xy_singular:g}): approach from more sides"
        )
    if rms > st.max_rms_m:
        problems.append(f"RMS residual {rms * 1e3:.2f} mm > {st.max_rms_m * 1e3:g} mm")
    if np.linalg.norm(x[:2]) > st.max_correction_m:
        problems.append(
            f"correction {np.linalg.norm(x[:2]) * 1e3:.1f} mm > {st.max_correction_m * 1e3:g} mm"
            " (is the object where the workcell says, is it the object named?)"
        )
    if abs(fit.offset_m) > st.max_offset_m:
        problems.append(
            f"contact offset {fit.offset_m * 1e3:.1f} mm > {st.max_offset_m * 1e3:g} mm (is it "
            "the object named, at the size the library has?)"
        )
    if abs(dyaw) > st.max_yaw_deg:
        problems.append(f"yaw correction {dyaw:.1f} deg > {st.max_yaw_deg:g} deg")
    if problems:
        raise CalibrationRefusedError("object placement refused: " + "; ".join(problems))
    return fit


# -- the touches ----------------------------------------------------------------------------

THUMB_BASE_HAND_X_DOWN = 0.03  # the thumb's base is this far below the hand origin (x up)


def approach_rotation(direction: np.ndarray) -> Rotation:
    """Hand orientation for a horizontal approach along `direction`: sensors (hand +z) facing
    along it, hand +x up, so the open thumb hangs straight down in front of the palm as a
    feeler whose sensor face (12 cm of finger, a site every 8 mm) meets the object first (the
    pad is 7 mm further back, the housing 22 mm; the palm's 11 sites are too sparse)."""
    z = np.asarray(direction, dtype=np.float64)
    z = z / np.linalg.norm(z)
    x = np.array([0.0, 0.0, 1.0])
    return Rotation.from_matrix(np.column_stack([x, np.cross(z, x), z]))


def approach_directions(st: ObjectSettings) -> np.ndarray:
    """(k, 3) approach directions (towards the object), evenly spaced."""
    phi = np.radians(st.direction_offset_deg) + 2 * np.pi * np.arange(st.directions) / st.directions
    return -np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])


def box_corners(boxes: Boxes) -> np.ndarray:
    """(8 b, 3) corners of every box (boxes' frame)."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    local = signs[None, :, :] * boxes.half[:, None, :]
    return (np.einsum("bij,bkj->bki", boxes.rot, local) + boxes.centre[:, None, :]).reshape(-1, 3)


def thumb_sites(geom: ReflexGeometry | None = None) -> np.ndarray:
    """Distances of the thumb's sensor sites from its base along the open (straight) thumb."""

    g = geom or ReflexGeometry()
    return np.concatenate(
        [np.asarray(g.proximal_sensor_x), g.distal_on_proximal[0] + np.asarray(g.distal_sensor_x)]
    )


def first_contact_heights(
    shape: ObjectShape, nominal: Placement, direction: np.ndarray, max_error: float, width: float
) -> np.ndarray:
    """Heights (base frame) where a vertical bar `width` wide, coming along `direction` aimed
    at the expected centre, first meets the object (nominal placement) when the object is off
    sideways by each of 13 offsets within +-`max_error` (NaN: misses it)."""
    d = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    side = np.cross(np.array([0.0, 0.0, 1.0]), d)
    world = nominal.rotation.apply(shape.points) + nominal.xyz
    lat = (world - nominal.xyz) @ side
    ahead = world @ -d
    out = np.full(13, np.nan)
    for k, e in enumerate(np.linspace(-max_error, max_error, 13)):
        sel = np.flatnonzero(np.abs(lat + e) < width / 2)
        if sel.size:
            out[k] = world[sel[np.argmax(ahead[sel])], 2]
    return out


def start_pose(
    shape: ObjectShape,
    boxes: Boxes,
    nominal: Placement,
    direction: np.ndarray,
    table_z: float,
    clearance: float,
    st: ObjectSettings,
    geometry: ReflexGeometry | None = None,
) -> Pose:
    """The hand pose for an approach along `direction`: the thumb's centre line in the vertical
    plane through the expected centre, at the lowest height (hand clear of the table) where
    the most first contacts land within `site_reach_m` of a thumb sensor, backed off until the
    hand clears the object (nominal placement) by `clearance`."""
    rot = approach_rotation(direction)
    d = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    lowest = float(rot.apply(box_corners(boxes))[:, 2].min())  # hand-origin relative
    z_min = table_z + st.bottom_clearance_m - lowest
    # The thumb has no sensor for 3.7 cm between its proximal and distal sites: put the hand
    # at the height where the most first contacts (over sideways placement errors) meet a site.
    heights = first_contact_heights(shape, nominal, d, st.max_error_m, st.thumb_width_m)
    heights = heights[np.isfinite(heights)]
    sites = thumb_sites(geometry)
    cands = z_min + np.arange(0.0, 0.15, 0.002)
    along = cands[:, None] - THUMB_BASE_HAND_X_DOWN - heights[None, :]  # (c, h) from the base
    near = np.abs(along[:, :, None] - sites[None, None, :]).min(axis=2) < st.site_reach_m
    z = float(cands[int(np.argmax(near.sum(axis=1)))]) if heights.size else z_min
    base = np.array([nominal.xyz[0], nominal.xyz[1], z])
    world = nominal.rotation.apply(shape.coarse) + nominal.xyz
    inv = rot.inv()

    def gap(s: float) -> float:
        return min_box_sdf(inv.apply(world - (base - s * d)), boxes) - clearance

    # Sphere tracing in from far away: the gap changes no faster than the hand moves, so a
    # step of the gap never jumps past the first pose (from outside) that is too close.
    s = far = 0.6
    if gap(far) < 0:
        raise CalibrationRefusedError(f"object: no clear start pose within {far} m")
    for _ in range(200):
        g = gap(s)
        if g < 1e-4 or s <= 0:
            break
        s = max(0.0, s - g)
    return Pose(base - s * d, rot.as_quat())


def lift_height(boxes: Boxes, rot: Rotation, top_z: float) -> float:
    """Hand-origin height that puts the hand's lowest point at `top_z`."""
    return float(top_z - rot.apply(box_corners(boxes))[:, 2].min())


def lifted(pose: Pose, z: float) -> Pose:
    return Pose(np.array([pose.xyz[0], pose.xyz[1], max(float(pose.xyz[2]), z)]), pose.quat)


def probe_object(
    hand: Hand,
    flange: Flange,
    shape: ObjectShape,
    boxes: Boxes,
    nominal: Placement,
    table_z: float,
    st: ObjectSettings,
    mount: Pose = IDENTITY,
    threshold: float = 20.0,
    geometry: ReflexGeometry | None = None,
) -> tuple[list[ObjectTouch], list[str]]:
    """One guarded horizontal approach per direction; between them the hand rises above the
    object. Returns the touches and, for each approach that found nothing, why."""

    to_flange = mount.inverse()
    clear = st.max_error_m * np.sqrt(2) + st.start_clearance_m
    search = clear + st.max_error_m * np.sqrt(2) + 0.02
    top = table_z + float(shape.extents[2]) + st.lift_clearance_m
    touches: list[ObjectTouch] = []
    missed: list[str] = []

    def rise(hand_pose: Pose) -> None:
        """Straight up (hand frame kept) until the hand's lowest point clears the object."""
        z = lift_height(boxes, Rotation.from_quat(hand_pose.quat), top)
        flange.move_to(lifted(hand_pose, z).compose(to_flange))

    rise(flange.pose().compose(mount))
    ignore = in_contact_at_rest(hand)  # above the object, touching nothing
    if len(ignore):
        log.warning(
            "object calibration: sensors %s read contact with nothing touching them: ignored",
            ignore.tolist(),
        )
    for d in approach_directions(st):
        start_hand = start_pose(shape, boxes, nominal, d, table_z, clear, st, geometry)
        start = start_hand.compose(to_flange)
        rise(flange.pose().compose(mount))
        rise(start_hand)
        try:
            res = guarded_descent(
                hand,
                flange,
                start,
                st.coarse_step_m,
                st.fine_step_m,
                st.press_m,
                st.press_pressure,
                search,
                threshold,
                direction=d,
                ignore=ignore,
            )
        except CalibrationRefusedError as e:
            missed.append(f"approach along {np.round(d[:2], 3).tolist()}: {e}")
            flange.move_to(start)
            continue
        touches.append(ObjectTouch(res.flange.compose(mount), d.copy(), res.sensor))
    rise(flange.pose().compose(mount))
    return touches, missed


def object_record(
    device: str,
    fit: ObjectFit,
    shape: ObjectShape,
    nominal: Placement,
    touches: Sequence[ObjectTouch],
    missed: Sequence[str],
    settings: ObjectSettings,
    table_z: float,
) -> CalibrationRecord:
    p = fit.placement
    return CalibrationRecord(
        kind="object",
        device=device,
        values={
            "object": shape.name,
            "xyz": [round(float(v), 6) for v in p.xyz],
            "yaw_deg": round(float(np.degrees(p.yaw_rad)), 4),
            "yaw_observed": bool(fit.yaw_observed),
            "frame": "object frame (bounding-box centre, z up) in the robot base frame; z = "
            "table top + half the object's height",
        },
        quality={
            "n_touches": len(touches),
            "missed_approaches": list(missed),
            "rms_residual_mm": round(fit.rms_m * 1e3, 4),
            "max_residual_mm": round(float(np.max(np.abs(fit.residuals))) * 1e3, 4),
            "correction_xy_mm": [round(float(v) * 1e3, 3) for v in fit.correction_xy],
            "correction_yaw_deg": round(fit.correction_yaw_deg, 4),
            "yaw_sensitivity_m_per_rad": round(fit.yaw_sensitivity_m, 5),
            "singular_values": [round(float(v), 6) for v in fit.singular_values],
        },
        method={
            "procedure": "object",
            "nominal_xyz": [float(v) for v in nominal.xyz],
            "nominal_yaw_deg": float(np.degrees(nominal.yaw_rad)),
            "table_z": float(table_z),
            "extents": [float(v) for v in shape.extents],
            "model": "horizontal palm approaches; the hand's collision boxes touch the object's "
            "convex parts at the pressure onset; soft-L1 least squares over x, y (and yaw) with "
            "a weak prior to the nominal placement",
            "touches": [
                {
                    "hand_xyz": [round(float(v), 6) for v in t.hand.xyz],
                    "hand_quat_xyzw": [round(float(v), 8) for v in t.hand.quat],
                    "sensor": int(t.sensor),
                }
                for t in touches
            ],
            "settings": asdict(settings),
        },
    )


def nominal_placement(workcell, extents: np.ndarray) -> Placement:
    """Where the workcell says the object is: its x, y and yaw; z from the table top and the
    object's height (the twin stands every object on the table the same way)."""
    x, y = float(workcell.object_xyz[0]), float(workcell.object_xyz[1])
    z = float(workcell.table_top_z) + float(extents[2]) / 2
    return Placement(np.array([x, y, z]), float(np.radians(workcell.object_yaw_deg)))


def open_joint_angles(hand: Hand) -> tuple[float, np.ndarray]:
    s = hand.state()
    return float(s.preshape), np.asarray(s.finger_angles, dtype=np.float64)


def calibrate_object(
    hand: Hand,
    flange: Flange,
    spec: ObjectSpec,
    nominal: Placement,
    table_z: float,
    device: str = DEFAULT_DEVICE,
    settings: ObjectSettings | None = None,
    mount: Pose = IDENTITY,
    geometry: ReflexGeometry | None = None,
    threshold: float = 20.0,
) -> tuple[CalibrationRecord, ObjectFit, list[ObjectTouch]]:
    """Touch the object from every direction of `approach_directions` and fit its placement.
    `flange` is a `probing.Flange`, `mount` the hand in the flange frame (identity for a
    floating wrist). The hand is opened first; its open geometry is the probe."""
    st = settings or ObjectSettings()
    hand.open()
    preshape, prox = open_joint_angles(hand)
    boxes = hand_boxes(geometry, preshape, prox)
    shape = object_shape(spec, st.surface_spacing_m, st.coarse_points)
    touches, missed = probe_object(
        hand, flange, shape, boxes, nominal, table_z, st, mount, threshold, geometry
    )
    for m in missed:
        log.info("object calibration: %s", m)
    fit = solve_object(touches, shape, boxes, nominal, st)
    rec = object_record(device, fit, shape, nominal, touches, missed, st, table_z)
    return rec, fit, touches


def placement_from_record(record: CalibrationRecord) -> Placement:
    v = record.values
    return Placement(np.asarray(v["xyz"], dtype=np.float64), float(np.radians(v["yaw_deg"])))


def stored_placement(
    root: Path, object_name: str, device: str = DEFAULT_DEVICE
) -> Placement | None:
    """The stored placement of `object_name`, or None when there is none or it is another
    object's; a missing, foreign or stale record is a warning naming the command."""

    rec = store.load(root, "object", device)
    cmd = f"`activetouch calibrate object --object {object_name}`"
    if rec is not None and rec.values.get("object") != object_name:
        log.warning(
            "calibration: the stored object placement is of %r, not %r: run %s",
            rec.values.get("object"),
            object_name,
            cmd,
        )
        return None
    why = store.staleness(rec, "object")
    if why:
        log.warning("calibration: %s", why.replace("`activetouch calibrate object`", cmd))
    if rec is None:
        return None
    path = store.record_path(root, "object", device)
    log.info("calibration: object placement from %s (measured %s)", path, rec.measured_at)
    return placement_from_record(rec)
