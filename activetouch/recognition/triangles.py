"""Triangle parameters from the contact points of one grasp (Zhang et al., IROS 2016/2017).

Every 3-subset of a grasp's n contacts is a triangle. Its sides are sorted l0 >= l1 >= l2 and
its angles a0 >= a1 >= a2 (a0 is opposite l0, a1 opposite l1, a2 opposite l2). A triangle is
described by three of these six numbers (the *parameterisation*, default "l0,l1,a0"); because
they are relative measures the result does not depend on the pose of the hand or the object, nor
on the order of the contacts (only the row order of the result does).

Degenerate triangles are dropped: a side shorter than ``min_side_m`` (two contacts at the same
place; a zero side always) or an angle smaller than ``min_angle_deg`` (three contacts on a line).
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
    """Column indices into FEATURE_NAMES for e.g. "l0,l1,a0"; ConfigError unless 3 distinct."""
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


@lru_cache(maxsize=64)
def _side_table(n: int) -> np.ndarray:
    """(3, n choose 3) flat indices into an n x n distance matrix: for each triangle (i, j, k)
    the sides jk, ik, ij (cached, read-only)."""
    idx = subset_table(n)
    i, j, k = idx[:, 0], idx[:, 1], idx[:, 2]
    table = np.ascontiguousarray(np.stack([j * n + k, i * n + k, i * n + j]))
    table.flags.writeable = False
    return table


# Build the tables for every contact count a ReFlex grasp can have once, at import.
for _n in range(MAX_PRECOMPUTED_CONTACTS + 1):
    subset_table(_n)
    _side_table(_n)


def _sort3_desc_rows(a: np.ndarray, out: np.ndarray) -> None:
    """Sort the 3 rows of a (3, m) descending column by column into out (3, m); a is clobbered.

    A sorting network of elementwise max/min: exact, and written into preallocated rows because
    allocating many temporaries costs more than the arithmetic at these sizes.
    """
    np.maximum(a[0], a[1], out=out[0])  # larger of the first two
    np.minimum(a[0], a[1], out=a[0])  # smaller of the first two
    np.minimum(out[0], a[2], out=out[1])
    np.maximum(out[0], a[2], out=out[0])  # largest of all
    np.minimum(a[0], out[1], out=out[2])  # smallest of all
    np.maximum(a[0], out[1], out=out[1])  # middle


def feature_rows(
    xyz: np.ndarray, min_side_m: float = 1e-4, min_angle_deg: float = 1.0
) -> np.ndarray:
    """(6, m) rows l0, l1, l2, a0, a1, a2 (metres, radians) of the non-degenerate triangles."""
    pts = _validated_points(xyz)
    n = len(pts)
    if n < 3:
        return np.zeros((6, 0), dtype=np.float64)
    # All pairwise distances once (n x n), then look the three sides of each triangle up.
    diff = pts[:, None, :] - pts[None, :, :]
    dist = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff)).ravel()
    sides = dist.take(_side_table(n))
    out = np.empty((6, sides.shape[1]), dtype=np.float64)
    _sort3_desc_rows(sides, out[:3])
    # A zero side (coincident contacts) is always degenerate, whatever the threshold.
    ok = (out[2] >= min_side_m) & (out[2] > 0.0)
    if not ok.all():
        out = out[:, ok]
    sq = out[:3] * out[:3]
    tmp = np.empty((3, out.shape[1]), dtype=np.float64)
    den = np.empty(out.shape[1], dtype=np.float64)
    # Law of cosines, angle r opposite side r:
    # (sum of the other squares - own square) / (2 * product of the other sides).
    for r, (p, q) in enumerate(((1, 2), (0, 2), (0, 1))):
        np.add(sq[p], sq[q], out=tmp[r])
        tmp[r] -= sq[r]
        np.multiply(out[p], out[q], out=den)
        den *= 2.0
        tmp[r] /= den
    # Clip: rounding can leave |cos| slightly above 1 for flat triangles.
    np.clip(tmp, -1.0, 1.0, out=tmp)
    np.arccos(tmp, out=tmp)
    # Larger side <=> larger angle, so sorting keeps a_i opposite l_i; it only fixes rounding
    # in isosceles triangles where the law of cosines can swap equal angles by an ulp.
    _sort3_desc_rows(tmp, out[3:])
    ok = out[5] >= np.deg2rad(min_angle_deg)
    return out if ok.all() else out[:, ok]


def triangle_features(
    xyz: np.ndarray, min_side_m: float = 1e-4, min_angle_deg: float = 1.0
) -> np.ndarray:
    """(m, 6) table l0, l1, l2, a0, a1, a2 (metres, radians) of the non-degenerate triangles."""
    return np.ascontiguousarray(feature_rows(xyz, min_side_m, min_angle_deg).T)


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
    rows = feature_rows(xyz, min_side_m=min_side_m, min_angle_deg=min_angle_deg)
    return np.ascontiguousarray(rows[list(cols)].T)
