"""The class belief p(y | h) of a simulated history, as the compiled search keeps it.

Two beliefs share one argument layout (the kernel tuple), so the search code is the same:
- the classifier's posterior on the simulated histogram (Eq. 1's p): `kernel_tuple`; for
  kernels linear in h the scores are kept incrementally per added triangle;
- Bayes' rule over grasp likelihoods (`recognition.belief = grasp_likelihood`):
  `bayes_kernel_tuple`, where an observation adds its training grasp's log-likelihoods.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from activetouch.recognition.kernels import (
    KIND_LINEAR_OVR,
    KIND_NN_INTERSECTION,
    Z_CLIP,
    ClassifierKernel,
    kernel_proba,
    normalise_or_uniform,
    softmin_into,
)

# Planning on the grasp-likelihood belief (recognition.belief = grasp_likelihood): p(y | ...)
# is Bayes' rule over the grasps, not a classifier. Its kernel tuple keeps kernel_tuple's
# layout so the compiled code is shared: slot 2 holds the root's log-belief (K,), slot 8 the
# log-likelihood table (O, K) of every outcome's training grasp, and the scores S hold the
# simulated log-belief (an outcome adds its grasp's row; slot 3 maps outcomes to grasps).
KIND_BAYES = 3


@dataclass(frozen=True)
class BeliefTable:
    """What planning on the grasp-likelihood belief needs from the trained model."""

    log_lik: np.ndarray  # (G, K) log p(training grasp g | y), at g's own pose
    outcome_grasp: np.ndarray  # (O,) the training grasp of each observation-model outcome


@njit(cache=True)
def proba_full(kern: tuple, hist: np.ndarray) -> np.ndarray:
    return kernel_proba(
        kern[0], kern[1], kern[2], kern[3], kern[4], kern[5], kern[6], kern[7], hist
    )


# Incremental classifier state: for kernels whose scores are linear in h (KIND_LINEAR_OVR and
# KIND_NN_INNER) a simulation keeps S = [W h (M values), sum(h), ||h||^2] and updates it per
# added triangle in O(M) instead of re-evaluating W h in O(M D) for every p(y | h_t) it needs.
# proba_scores is kernel_proba's maths on that state (tested equal to 1e-9); other kinds
# fall back to kernel_proba on the histogram.


@njit(cache=True)
def scores_init(kern: tuple, hist: np.ndarray, S: np.ndarray) -> None:
    W = kern[1]
    M, D = W.shape
    if kern[0] == KIND_BAYES:
        for m in range(M):
            S[m] = kern[2][m]
        S[M] = 0.0
        S[M + 1] = 0.0
        return
    total = 0.0
    sq = 0.0
    for i in range(D):
        total += hist[i]
        sq += hist[i] * hist[i]
    for m in range(M):
        s = 0.0
        for i in range(D):
            s += W[m, i] * hist[i]
        S[m] = s
    S[M] = total
    S[M + 1] = sq


@njit(cache=True)
def scores_add(
    kern: tuple, out_ptr: np.ndarray, out_bin: np.ndarray, o: int, hist: np.ndarray, S: np.ndarray
) -> None:
    """Add outcome `o`'s triangles to the histogram (and to S when the kernel is linear)."""
    WT = kern[8]
    M = WT.shape[1]
    if kern[0] == KIND_BAYES:  # Bayes' rule: the likelihoods of the outcome's grasp
        g = kern[3][o]
        for m in range(M):
            S[m] += WT[g, m]
    linear = kern[0] != KIND_NN_INTERSECTION and kern[0] != KIND_BAYES and kern[9]
    for k in range(out_ptr[o], out_ptr[o + 1]):
        j = out_bin[k]
        if linear:
            for m in range(M):
                S[m] += WT[j, m]
            S[M] += 1.0
            S[M + 1] += 2.0 * hist[j] + 1.0
        hist[j] += 1.0


@njit(cache=True)
def proba_scores(kern: tuple, hist: np.ndarray, S: np.ndarray) -> np.ndarray:
    kind = kern[0]
    if kind == KIND_BAYES:
        return softmax(S[: kern[7]])
    if kind == KIND_NN_INTERSECTION or not kern[9]:
        return proba_full(kern, hist)
    b, row_class, platt_a, platt_b, temperature, n_classes = (
        kern[2],
        kern[3],
        kern[4],
        kern[5],
        kern[6],
        kern[7],
    )
    M = S.shape[0] - 2
    total = S[M]
    out = np.zeros(n_classes)
    if total <= 0.0:
        for k in range(n_classes):
            out[k] = 1.0 / n_classes
        return out
    if kind == KIND_LINEAR_OVR:
        inv = 1.0 / total
        for m in range(M):
            z = platt_a[m] * (S[m] * inv + b[m]) + platt_b[m]
            z = min(max(z, -Z_CLIP), Z_CLIP)
            out[row_class[m]] += 1.0 / (1.0 + np.exp(z))
    else:
        if not 0.0 < S[M + 1] < np.inf:  # squares under/overflowed: kernel_proba rescales
            return proba_full(kern, hist)
        dmin = np.full(n_classes, np.inf)
        norm = np.sqrt(S[M + 1])
        for m in range(M):
            d = 1.0 - min(1.0, abs(S[m]) / norm)
            if d < dmin[row_class[m]]:
                dmin[row_class[m]] = d
        softmin_into(dmin, temperature, out)
    return normalise_or_uniform(out)


@njit(cache=True)
def softmax(log_b: np.ndarray) -> np.ndarray:
    out = np.empty(log_b.shape[0])
    top = np.max(log_b)
    for k in range(log_b.shape[0]):
        out[k] = np.exp(log_b[k] - top)
    return out / out.sum()


@njit(cache=True)
def pmax(p: np.ndarray) -> float:
    best = 0.0
    for y in range(p.shape[0]):
        if p[y] > best:
            best = p[y]
    return best


@njit(cache=True)
def norm_entropy(p: np.ndarray) -> float:
    """H(p) / log K in [0, 1] (K classes; 0 for one class)."""
    k = p.shape[0]
    if k < 2:
        return 0.0
    h = 0.0
    for y in range(k):
        if p[y] > 0.0:
            h -= p[y] * np.log(p[y])
    return h / np.log(k)


def kernel_tuple(kernel: ClassifierKernel, incremental: bool = True) -> tuple:
    """The classifier kernel as the argument tuple the compiled code takes. `incremental`
    False makes every p(y | h) a full `kernel_proba` call (for measuring what it saves)."""
    f64 = np.float64
    return (
        np.int64(kernel.kind),
        np.ascontiguousarray(kernel.W, dtype=f64),
        np.ascontiguousarray(kernel.b, dtype=f64),
        np.ascontiguousarray(kernel.row_class, dtype=np.int64),
        np.ascontiguousarray(kernel.platt_a, dtype=f64),
        np.ascontiguousarray(kernel.platt_b, dtype=f64),
        f64(kernel.temperature),
        np.int64(kernel.n_classes),
        np.ascontiguousarray(np.asarray(kernel.W, dtype=f64).T),  # columns per bin, contiguous
        np.bool_(incremental),
    )


def bayes_kernel_tuple(belief: BeliefTable) -> tuple:
    """The kernel tuple of planning on the grasp-likelihood belief (`KIND_BAYES`); the root's
    log-belief goes in slot 2 per search."""
    f64 = np.float64
    K = belief.log_lik.shape[1]
    return (
        np.int64(KIND_BAYES),
        np.zeros((K, 0)),
        np.zeros(K),
        np.ascontiguousarray(belief.outcome_grasp, dtype=np.int64),
        np.zeros(K),
        np.zeros(K),
        f64(1.0),
        np.int64(K),
        np.ascontiguousarray(belief.log_lik, dtype=f64),
        np.bool_(True),
    )
