"""Training grid of wrist poses around an object (paper Alg. 1, the authors' layout).

Poses lie on an ellipsoid around the object centre in horizontal rings, the palm facing the
centre (hand +z towards the centre), with wrist-roll variants. Poses whose hand frame would be
below the table are dropped. Pure math: no simulator, so the real robot uses the same grid.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.config import GridConfig
from activetouch.poses import look_at_axes


@dataclass(frozen=True)
class GridPoses:
    pose_ids: np.ndarray  # (N,) int64, stable ids: resuming a collection skips done ids
    poses: np.ndarray  # (N, 7) hand frame in the object frame: x y z qx qy qz qw
    preshapes: np.ndarray  # (N,) rad

    def __len__(self) -> int:
        return len(self.pose_ids)


def look_at_quaternion(direction: np.ndarray, roll: float) -> np.ndarray:
    """Quaternion (x y z w) of a frame whose +z is `direction`, rolled by `roll` about it.

    Zero roll puts the frame's x axis in the vertical plane containing +z (pointing up where
    possible), so roll variants are comparable across the grid."""
    x, y, z = look_at_axes(np.asarray(direction, dtype=np.float64).reshape(3))
    base = Rotation.from_matrix(np.column_stack([x, y, z]))
    return (base * Rotation.from_rotvec([0.0, 0.0, roll])).as_quat()


def ring_directions(step_deg: float, min_elevation_deg: float) -> np.ndarray:
    """Unit vectors from the object centre: rings every `step_deg` of elevation up to the top,
    azimuths spaced about `step_deg` apart along each ring."""
    dirs: list[np.ndarray] = []
    elevations = np.arange(min_elevation_deg, 90.0 - 1e-9, step_deg)
    for el in np.deg2rad(elevations):
        n_az = max(1, round(360.0 * np.cos(el) / step_deg))
        for az in np.arange(n_az) * (2 * np.pi / n_az):
            dirs.append(np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]))
    dirs.append(np.array([0.0, 0.0, 1.0]))  # straight from above
    return np.array(dirs)


def training_grid(extents: np.ndarray, cfg: GridConfig) -> GridPoses:
    """Grid for an object with bounding-box `extents` (x, y, z sizes, metres) standing on the
    table with its centre at height extents[2] / 2."""
    ext = np.asarray(extents, dtype=np.float64).reshape(3)
    if np.any(ext <= 0) or not np.all(np.isfinite(ext)):
        raise ValueError(f"object extents must be positive, got {ext}")
    if cfg.step_deg <= 0 or cfg.step_deg > 90:
        raise ValueError(f"grid step must be in (0, 90] degrees, got {cfg.step_deg}")
    radii = ext / 2 + cfg.margin_m  # ellipsoid the palm pad lies on
    poses, preshapes, ids = [], [], []
    pid = 0
    for d in ring_directions(cfg.step_deg, cfg.min_elevation_deg):
        # Point on the ellipsoid along d, then back off so the palm pad (not the hand origin)
        # sits there; the hand looks at the centre.
        palm = d / np.sqrt(np.sum((d / radii) ** 2))
        origin = palm + d * cfg.palm_offset_m
        for roll in np.deg2rad(cfg.rolls_deg):
            quat = look_at_quaternion(-d, roll)
            # Centre the object between fingers and thumb: move the hand by -offset along its
            # own x axis (the fingers' side), so its approach axis is at hand x = +offset.
            o = origin - Rotation.from_quat(quat).as_matrix()[:, 0] * cfg.center_offset_m
            if o[2] + ext[2] / 2 >= cfg.min_wrist_height_m:
                poses.append(np.concatenate([o, quat]))
                preshapes.append(cfg.preshape)
                ids.append(pid)
            pid += 1  # ids stay stable when filtering changes
    return GridPoses(
        pose_ids=np.asarray(ids, dtype=np.int64),
        poses=np.asarray(poses, dtype=np.float64).reshape(-1, 7),
        preshapes=np.asarray(preshapes, dtype=np.float64),
    )


# Grid settings for small and irregular objects (measured, docs/objects.md "Small objects"):
# the palm 4.5 cm beyond the bounding ellipsoid instead of 6, the approach axis between
# fingers and thumb, and wrist rolls that keep every finger off the table (roll 0 points the
# thumb at the table on the 50 deg ring: 100 % of those grasps of low objects felt the table).
SMALL_OBJECT_GRID: dict[str, object] = {
    "margin_m": 0.045,
    "rolls_deg": [90.0, 270.0],
    "center_offset_m": 0.015,
}


def small_object_overrides() -> list[str]:
    """`--set` overrides that select `SMALL_OBJECT_GRID`."""
    return [f"grid.{k}={v}" for k, v in SMALL_OBJECT_GRID.items()]


def pose_content_id(pose: np.ndarray) -> int:
    """A stable 56-bit id of a pose (rounded to 0.1 mm and 1e-5 per quaternion component), so
    a shared grid's ids do not depend on which objects contributed the pose."""
    pose = np.asarray(pose, dtype=np.float64)
    q = pose[3:] if pose[6] >= 0 else -pose[3:]  # q and -q are one rotation: one id
    key = np.round(np.concatenate([pose[:3] * 1e4, q * 1e5]))
    digest = hashlib.blake2b(key.astype(np.int64).tobytes(), digest_size=7).digest()
    return int.from_bytes(digest, "little")


def shared_grid(extents: Mapping[str, np.ndarray], cfg: GridConfig) -> GridPoses:
    """The union of the grids of every object in `extents` (name -> bounding-box sizes).

    At test time the object is unknown, so the planner chooses among the poses of every
    object's grid; grasping each object at all of them gives every class data at every pose it
    can be asked about. Ids come from the pose itself (`pose_content_id`): adding an object
    keeps the ids of the poses already collected, and equal poses appear once."""
    parts = [training_grid(extents[name], cfg) for name in sorted(extents)]
    poses = np.concatenate([g.poses for g in parts]).reshape(-1, 7)
    preshapes = np.concatenate([g.preshapes for g in parts])
    ids = np.array([pose_content_id(p) for p in poses], dtype=np.int64)
    _, first = np.unique(ids, return_index=True)
    keep = np.sort(first)
    return GridPoses(pose_ids=ids[keep], poses=poses[keep], preshapes=preshapes[keep])


def object_grids(extents: Mapping[str, np.ndarray], cfg: GridConfig) -> dict[str, GridPoses]:
    """The grid each object is collected at, following `cfg.layout`."""
    if cfg.layout == "shared":
        grid = shared_grid(extents, cfg)
        return {name: grid for name in extents}
    if cfg.layout != "per_object":
        raise ValueError(f"grid.layout must be shared or per_object, got {cfg.layout!r}")
    return {name: training_grid(ext, cfg) for name, ext in extents.items()}
