"""Histogram distances, each in [0, 1] for non-negative histograms.

- inner product: ``1 - |h1 . h2| / (||h1|| ||h2||)`` (the best in the source paper); it ignores
  the histograms' scale, so raw counts and normalised histograms give the same value.
- intersection: ``1 - sum(min(h1n, h2n))`` on L1-normalised histograms.
- l2: Euclidean distance of the L1-normalised histograms (in [0, sqrt(2)]).

A zero histogram (no triangles) is at distance 1 from everything under inner product and
intersection, itself included: it carries no evidence of similarity. Under l2 it is the origin.

The ``*_many`` versions compare one histogram h (D,) with the rows of H (N, D) and return (N,).
"""

from __future__ import annotations

import numpy as np

from activetouch.recognition.histogram import l1_normalise, l1_normalise_rows


def _pair(h1: np.ndarray, h2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(h1, dtype=np.float64).reshape(-1)
    b = np.asarray(h2, dtype=np.float64).reshape(-1)
    if a.shape != b.shape:
        raise ValueError(f"histograms differ in length: {a.shape[0]} and {b.shape[0]}")
    return a, b


def _one_many(h: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(h, dtype=np.float64).reshape(-1)
    B = np.asarray(H, dtype=np.float64)
    if B.ndim != 2 or B.shape[1] != a.shape[0]:
        raise ValueError(f"expected H of shape (N, {a.shape[0]}), got {B.shape}")
    return a, B


def inner_product_distance(h1: np.ndarray, h2: np.ndarray) -> float:
    a, b = _pair(h1, h2)
    # Scale-free, so normalise first: squares of tiny counts would underflow.
    a, b = l1_normalise(a), l1_normalise(b)
    denom = float(np.linalg.norm(a) * np.linalg.norm(b))
    if denom == 0.0:
        return 1.0
    return float(1.0 - min(1.0, abs(float(a @ b)) / denom))


def intersection_distance(h1: np.ndarray, h2: np.ndarray) -> float:
    a, b = _pair(h1, h2)
    # Clamped: the normalised sums can exceed 1 by rounding.
    return float(max(0.0, 1.0 - np.minimum(l1_normalise(a), l1_normalise(b)).sum()))


def l2_distance(h1: np.ndarray, h2: np.ndarray) -> float:
    a, b = _pair(h1, h2)
    return float(np.linalg.norm(l1_normalise(a) - l1_normalise(b)))


def inner_product_distance_many(h: np.ndarray, H: np.ndarray) -> np.ndarray:
    a, B = _one_many(h, H)
    a, B = l1_normalise(a), l1_normalise_rows(B)
    denom = np.linalg.norm(a) * np.linalg.norm(B, axis=1)
    num = np.abs(B @ a)
    sim = np.divide(num, denom, out=np.zeros_like(num), where=denom > 0)
    return 1.0 - np.minimum(sim, 1.0)


def intersection_distance_many(h: np.ndarray, H: np.ndarray) -> np.ndarray:
    a, B = _one_many(h, H)
    sim = np.minimum(l1_normalise(a)[None, :], l1_normalise_rows(B)).sum(axis=1)
    return np.maximum(1.0 - sim, 0.0)


def l2_distance_many(h: np.ndarray, H: np.ndarray) -> np.ndarray:
    a, B = _one_many(h, H)
    return np.linalg.norm(l1_normalise_rows(B) - l1_normalise(a)[None, :], axis=1)


DISTANCES_MANY = {
    "inner": inner_product_distance_many,
    "intersection": intersection_distance_many,
    "l2": l2_distance_many,
}


def pairwise_distances(H1: np.ndarray, H2: np.ndarray, metric: str = "inner") -> np.ndarray:
    """(N1, N2) distances between the rows of H1 and H2 (loops over the shorter side, so memory
    stays O(N * D) even for intersection)."""
    if metric not in DISTANCES_MANY:
        raise ValueError(f"unknown metric {metric!r}; choose from {sorted(DISTANCES_MANY)}")
    A = np.asarray(H1, dtype=np.float64)
    B = np.asarray(H2, dtype=np.float64)
    if A.ndim != 2 or B.ndim != 2 or A.shape[1] != B.shape[1]:
        raise ValueError(f"expected (N1, D) and (N2, D) arrays, got {A.shape} and {B.shape}")
    fn = DISTANCES_MANY[metric]
    if len(B) <= len(A):
        out = np.empty((len(B), len(A)))
        for j in range(len(B)):
            out[j] = fn(B[j], A)
        return out.T.copy()
    out = np.empty((len(A), len(B)))
    for i in range(len(A)):
        out[i] = fn(A[i], B)
    return out
