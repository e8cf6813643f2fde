"""Triangle parameters from the contact points of one grasp (Zhang et al., IROS 2016/2017).

Every 3-subset of a grasp's n contacts is a triangle. Its sides are sorted l0 >= l1 >= l2 and
its angles a0 >= a1 >= a2 (a0 is opposite l0, a1 opposite l1, a2 opposite l2). A triangle is
described by three of these six numbers (the *parameterisation*, default "l0,l1,a0"); because
they are relative measures the result does not depend on the pose of the hand or the object, nor
on the order of the contacts (only the row order of the result does).

Degenerate triangles are dropped: a side shorter than ``min_side_m`` (two contacts at the same
place) or an angle smaller than ``min_angle_deg`` (three contacts on a line).
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

from activetouch.errors import ConfigError, DataError

# Column order of the full feature table computed for every triangle.
FEATURE_NAMES: tuple[str, ...] = ("l0", "l1", "l2", "a0", "a1", "a2")

# Named parameterisations; any 3 distinct names from FEATURE_NAMES, comma separated, are accepted.
PARAMETERISATIONS: tuple[str, ...] = (
    "l0,l1,a0",
    "l0,l1,l2",
    "a0,a1,l0",
    "l0,l1,a1",
    "l1,l2,a0",
    "l0,a0,a1",
)

# Contacts of a ReFlex hand: 3 fingers x 9 sensors + 11 palm sensors.
MAX_PRECOMPUTED_CONTACTS = 38


def parse_parameterisation(parameterisation: str) -> tuple[int, int, int]:
    """Column indices into FEATURE_NAMES for e.g. "l0,l1,a0"; ConfigError if not 3 distinct names."""
    names = [s.strip() for s in str(parameterisation).split(",")]
    if len(names) != 3 or len(set(names)) != 3 or not all(n in FEATURE_NAMES for n in names):
        raise ConfigError(
            f"triangle parameterisation {parameterisation!r} is invalid: give 3 distinct names "
            f"out of {', '.join(FEATURE_NAMES)} separated by commas (e.g. 'l0,l1,a0')"
        )
    i, j, k = (FEATURE_NAMES.index(n) for n in names)
    return i, j, k


@lru_cache(maxsize=64)
def subset_table(n: int) -> np.ndarray:
    """All 3-subsets of range(n) as an (n choose 3, 3) int64 table (cached, read-only)."""
    if n < 3:
        table = np.zeros((0, 3), dtype=np.int64)
    else:
        table = np.array(list(itertools.combinations(range(n), 3)), dtype=np.int64)
    table.flags.writeable = False
    return table


# Build the tables for every contact count a ReFlex grasp can have once, at import.
for _n in range(MAX_PRECOMPUTED_CONTACTS + 1):
    subset_table(_n)


def _validated_points(xyz: np.ndarray) -> np.ndarray:
    pts = np.asarray(xyz, dtype=np.float64)
    if pts.ndim == 1 and pts.size == 0:
        pts = pts.reshape(0, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DataError(f"contact points must be an (n, 3) array, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        bad = int((~np.isfinite(pts)).any(axis=1).sum())
        raise DataError(f"contact points contain NaN or infinite coordinates ({bad} of {len(pts)})")
    return pts


def triangle_features(
    xyz: np.ndarray, min_side_m: float = 1e-4, min_angle_deg: float = 1.0
) -> np.ndarray:
    """(m, 6) table l0, l1, l2, a0, a1, a2 (metres, radians) of the non-degenerate triangles."""
    pts = _validated_points(xyz)
    idx = subset_table(len(pts))
    if len(idx) == 0:
        return np.zeros((0, 6), dtype=np.float64)
    p = pts[idx]  # (m, 3 vertices, 3)
    # Side i is opposite vertex i; only the sorted lengths matter afterwards.
    sides = np.empty((len(idx), 3), dtype=np.float64)
    sides[:, 0] = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
    sides[:, 1] = np.linalg.norm(p[:, 0] - p[:, 2], axis=1)
    sides[:, 2] = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
    sides = -np.sort(-sides, axis=1)
    keep = sides[:, 2] >= min_side_m
    sides = sides[keep]
    l0, l1, l2 = sides[:, 0], sides[:, 1], sides[:, 2]
    sq0, sq1, sq2 = l0 * l0, l1 * l1, l2 * l2
    # Law of cosines; clip because rounding can leave |cos| slightly above 1 for flat triangles.
    a0 = np.arccos(np.clip((sq1 + sq2 - sq0) / (2.0 * l1 * l2), -1.0, 1.0))
    a1 = np.arccos(np.clip((sq0 + sq2 - sq1) / (2.0 * l0 * l2), -1.0, 1.0))
    a2 = np.arccos(np.clip((sq0 + sq1 - sq2) / (2.0 * l0 * l1), -1.0, 1.0))
    angles = np.stack([a0, a1, a2], axis=1)
    # Larger side <=> larger angle, so sorting keeps a_i opposite l_i; it only fixes rounding
    # in isosceles triangles where the law of cosines can swap equal angles by an ulp.
    angles = -np.sort(-angles, axis=1)
    keep = angles[:, 2] >= np.deg2rad(min_angle_deg)
    return np.concatenate([sides[keep], angles[keep]], axis=1)


def triangle_params(
    xyz: np.ndarray,
    parameterisation: str = "l0,l1,a0",
    min_side_m: float = 1e-4,
    min_angle_deg: float = 1.0,
) -> np.ndarray:
    """Parameters of every non-degenerate triangle of a grasp's contacts.

    xyz: (n, 3) contact positions (metres). Returns (m, 3) float64 with m <= n choose 3, columns
    in the order the parameterisation names them; fewer than 3 contacts give shape (0, 3).
    Raises DataError for NaN/inf or a wrong shape, ConfigError for an unknown parameterisation.
    """
    cols = parse_parameterisation(parameterisation)
    feats = triangle_features(xyz, min_side_m=min_side_m, min_angle_deg=min_angle_deg)
    return np.ascontiguousarray(feats[:, cols])
