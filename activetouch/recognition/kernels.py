"""Compiled prediction of the fitted classifiers: their array form and its p(y | h).

`ClassifierKernel` is what `classifiers` fits and saves; ``kernel_proba`` (numba) evaluates
it, here rather than in `classifiers` so that the planner's compiled code can call it without
importing the fitting side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

KIND_LINEAR_OVR = 0
KIND_NN_INNER = 1
KIND_NN_INTERSECTION = 2

# exp(500) is finite in float64; clipping the sigmoid argument avoids overflow warnings and
# changes probabilities only below 1e-200.
Z_CLIP = 500.0


@dataclass(frozen=True)
class ClassifierKernel:
    """Array form of a fitted classifier, for compiled code.

    kind 0 (KIND_LINEAR_OVR): rows are per-class weight vectors; h1 = h / sum(h),
        s_m = W_m . h1 + b_m, q_m = 1 / (1 + exp(platt_a_m s_m + platt_b_m)),
        p(y) ∝ sum of q_m over rows m with row_class[m] == y.
    kind 1 (KIND_NN_INNER): rows are templates scaled to unit L2 norm;
        d_m = 1 - min(1, |W_m . h| / ||h||_2).
    kind 2 (KIND_NN_INTERSECTION): rows are L1-normalised templates;
        d_m = 1 - sum_i min(W_mi, h_i / sum(h)).
    kinds 1, 2: p(y) ∝ exp(-d_min(y) / temperature), d_min(y) the smallest d_m of class y.
    Every kind: p sums to 1; an all-zero h gives 1 / n_classes each.
    The kind 0 and kind 1 scores W h are linear in h, so a caller adding triangles one at a time
    can update them (and sum(h), ||h||^2) incrementally.
    """

    kind: int
    W: np.ndarray  # (M, D) float64
    b: np.ndarray  # (M,) float64
    row_class: np.ndarray  # (M,) int64
    platt_a: np.ndarray  # (M,) float64
    platt_b: np.ndarray  # (M,) float64
    temperature: float
    n_classes: int

    def proba(self, h: np.ndarray) -> np.ndarray:
        return kernel_proba(
            self.kind,
            self.W,
            self.b,
            self.row_class,
            self.platt_a,
            self.platt_b,
            self.temperature,
            self.n_classes,
            np.ascontiguousarray(h, dtype=np.float64),
        )


@njit(cache=True)
def softmin_into(dmin: np.ndarray, temperature: float, out: np.ndarray) -> None:
    """out[k] = exp(-(dmin[k] - min(dmin)) / temperature): NN distances to probabilities."""
    best = np.inf
    for k in range(dmin.shape[0]):
        if dmin[k] < best:
            best = dmin[k]
    for k in range(dmin.shape[0]):
        out[k] = np.exp(-(dmin[k] - best) / temperature)


@njit(cache=True)
def normalise_or_uniform(out: np.ndarray) -> np.ndarray:
    """`out` scaled to sum to 1 in place; uniform when it sums to zero."""
    total = 0.0
    for k in range(out.shape[0]):
        total += out[k]
    for k in range(out.shape[0]):
        out[k] = out[k] / total if total > 0.0 else 1.0 / out.shape[0]
    return out


# "reassoc" lets LLVM vectorise the dot-product loops (a different summation order changes the
# result by rounding only); no other fast-math flag, so inf and NaN keep their meaning.
@njit(cache=True, fastmath={"reassoc"})
def kernel_proba(
    kind: int,
    W: np.ndarray,
    b: np.ndarray,
    row_class: np.ndarray,
    platt_a: np.ndarray,
    platt_b: np.ndarray,
    temperature: float,
    n_classes: int,
    h: np.ndarray,
) -> np.ndarray:
    """p(y | h) (n_classes,) of a ClassifierKernel's arrays; see ClassifierKernel for the maths."""
    M, D = W.shape
    out = np.zeros(n_classes)
    total = 0.0
    sq = 0.0
    for i in range(D):
        total += h[i]
        sq += h[i] * h[i]
    if total <= 0.0:
        for k in range(n_classes):
            out[k] = 1.0 / n_classes
        return out
    if kind == 0:
        inv = 1.0 / total
        for m in range(M):
            s = 0.0
            for i in range(D):
                s += W[m, i] * h[i]
            z = platt_a[m] * (s * inv + b[m]) + platt_b[m]
            z = min(max(z, -Z_CLIP), Z_CLIP)
            out[row_class[m]] += 1.0 / (1.0 + np.exp(z))
    else:
        dmin = np.full(n_classes, np.inf)
        if kind == 1:
            norm = np.sqrt(sq)
            if not (0.0 < sq < np.inf):
                # Squares of tiny (or huge) counts under/overflow: measure h / sum(h) instead.
                sq = 0.0
                for i in range(D):
                    sq += (h[i] / total) ** 2
                norm = total * np.sqrt(sq)
            for m in range(M):
                s = 0.0
                for i in range(D):
                    s += W[m, i] * h[i]
                d = 1.0 - min(1.0, abs(s) / norm)
                if d < dmin[row_class[m]]:
                    dmin[row_class[m]] = d
        else:
            inv = 1.0 / total
            for m in range(M):
                s = 0.0
                for i in range(D):
                    s += min(W[m, i], h[i] * inv)
                d = 1.0 - s
                if d < dmin[row_class[m]]:
                    dmin[row_class[m]] = d
        softmin_into(dmin, temperature, out)
    return normalise_or_uniform(out)
