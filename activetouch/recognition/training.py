"""Training samples for the classifier p(y | h).

At test time the histogram holds the triangles of only the few grasps made so far, so the
classifier is trained on *partial* histograms (random subsets of each object's training grasps)
as well as on the full histogram of each object.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from activetouch.errors import ConfigError, DataError
from activetouch.recognition.histogram import HistogramSpec, l1_normalise_rows
from activetouch.recognition.triangles import triangle_params


def grasp_triangles(
    contacts: Sequence[np.ndarray],
    parameterisation: str = "l0,l1,a0",
    min_side_m: float = 1e-4,
    min_angle_deg: float = 1.0,
) -> list[np.ndarray]:
    """Triangle parameters (m_g, 3) of each grasp, given each grasp's (n_g, 3) contact points."""
    return [
        triangle_params(c, parameterisation, min_side_m=min_side_m, min_angle_deg=min_angle_deg)
        for c in contacts
    ]


def grasp_counts(triangles: Sequence[np.ndarray], spec: HistogramSpec) -> np.ndarray:
    """(G, n_bins) raw histogram counts, one row per grasp."""
    out = np.zeros((len(triangles), spec.n_bins), dtype=np.float64)
    for g, t in enumerate(triangles):
        if len(t):
            out[g] = spec.counts(t)
    return out


def partial_histograms(
    triangles_per_grasp: Sequence[Sequence[np.ndarray]],
    spec: HistogramSpec,
    n_samples: int,
    min_grasps: int,
    max_grasps: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Partial and full L1-normalised histograms of every object, with their class labels.

    triangles_per_grasp[y][g] is the (m, 3) triangle table of grasp g of object y. For each
    object: ``n_samples`` histograms, each of k grasps drawn without replacement with k uniform in
    [min_grasps, min(max_grasps, G)], then the histogram of all its grasps. Samples with no
    triangle at all (grasps with < 3 contacts) carry no information and are left out.
    Returns H (N, n_bins) float64 and y (N,) int64, objects in order.
    """
    if n_samples < 0:
        raise ConfigError(f"partial-histogram samples must be >= 0, got {n_samples}")
    if min_grasps < 1 or max_grasps < min_grasps:
        raise ConfigError(
            f"partial-histogram grasp range [{min_grasps}, {max_grasps}] is invalid: "
            "need 1 <= min_grasps <= max_grasps"
        )
    blocks: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    for y, grasps in enumerate(triangles_per_grasp):
        G = len(grasps)
        if G == 0:
            raise DataError(f"object {y} has no training grasps")
        C = grasp_counts(grasps, spec)
        hi = min(max_grasps, G)
        lo = min(min_grasps, hi)
        k = rng.integers(lo, hi + 1, size=n_samples)
        # Selection matrix: row s picks k[s] grasps; the rank of a uniform key draws a
        # without-replacement subset for every row at once.
        ranks = np.argsort(np.argsort(rng.random((n_samples, G)), axis=1), axis=1)
        S = (ranks < k[:, None]).astype(np.float64)
        counts = np.vstack([S @ C, C.sum(axis=0, keepdims=True)])
        counts = counts[counts.sum(axis=1) > 0]
        blocks.append(l1_normalise_rows(counts))
        labels.append(np.full(len(counts), y, dtype=np.int64))
    if not blocks:
        raise DataError("no objects to train on")
    return np.vstack(blocks), np.concatenate(labels)
