"""Classifiers p(y | h) on triangle histograms, evaluated with numpy (and numba for the planner).

Inputs are any non-negative histograms of length D (raw counts or normalised): each classifier
normalises as it needs. An all-zero histogram (no triangles yet) gives the uniform distribution.
All-zero training rows carry no evidence and are ignored when fitting.

LinearSVMClassifier ("svm", the source paper's classifier)
    scikit-learn's LinearSVC, one-vs-rest, fitted on L1-normalised histograms h1 = h / sum(h).
    Each class k gets a Platt sigmoid fitted on *held-out* decision values (stratified k-fold,
    Platt's smoothed targets), then the final SVM is fitted on all rows. At prediction time:
        s_k = W_k . h1 + b_k,   q_k = 1 / (1 + exp(a_k s_k + c_k)),   p_k = q_k / sum_j q_j.
    With two classes LinearSVC learns one vector w; it becomes the rows -w (class 0) and +w
    (class 1), each with its own sigmoid, so the formula above holds for every K.

NearestNeighbourClassifier ("nn_inner", "nn_intersection")
    One template per class: the mean of its L1-normalised training histograms. The distance to
    a class is d_y = distance(h, template_y) (inner product: 1 - |h . t| / (|h| |t|); intersection:
    1 - sum(min(h1, t1))), and distances become probabilities through a softmax
        p(y | h) ∝ exp(-d_y / temperature).
    The temperature is the one (on a log grid from 1e-3 to 10) that maximises the log-likelihood
    of the training labels, with each row's distances measured to templates built without the
    row's fold (5-fold), so it is not fitted to distances the templates have memorised.

Both reduce to a ClassifierKernel (flat arrays, in `kernels`) that ``kernels.kernel_proba``, a
numba function, evaluates exactly as ``proba`` does; the planner calls it from compiled code.
"""

from __future__ import annotations

import math
import warnings
from typing import Any, ClassVar

import numpy as np

from activetouch.errors import ConfigError, DataError
from activetouch.recognition.histogram import l1_normalise_rows
from activetouch.recognition.kernels import (
    KIND_LINEAR_OVR,
    KIND_NN_INNER,
    KIND_NN_INTERSECTION,
    Z_CLIP,
    ClassifierKernel,
)

CLASSIFIER_NAMES: tuple[str, ...] = ("svm", "nn_inner", "nn_intersection")
ARRAYS_FORMAT_VERSION = 1


# ---------------------------------------------------------------------------------------------
# Shared helpers


def _training_rows(H: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Validated float64 histograms (zero rows removed), int64 labels, number of classes."""
    H = np.asarray(H, dtype=np.float64)
    y = np.asarray(y)
    if H.ndim != 2 or y.ndim != 1 or len(H) != len(y):
        raise DataError(f"training data must be H (N, D) and y (N,), got {H.shape} and {y.shape}")
    if H.shape[1] == 0 or len(H) == 0:
        raise DataError(f"training data is empty: H has shape {H.shape}")
    if not np.issubdtype(y.dtype, np.integer):
        raise DataError(f"class labels must be integers, got dtype {y.dtype}")
    if not np.isfinite(H).all() or (H < 0).any():
        raise DataError("training histograms must be finite and non-negative")
    y = y.astype(np.int64)
    if y.min() < 0:
        raise DataError(f"class labels must be >= 0, got {y.min()}")
    n_classes = int(y.max()) + 1
    keep = H.sum(axis=1) > 0
    H, y = H[keep], y[keep]
    present = np.bincount(y, minlength=n_classes)
    if n_classes < 2:
        raise DataError("a classifier needs training histograms of at least 2 classes")
    missing = np.flatnonzero(present == 0)
    if len(missing):
        raise DataError(
            f"classes {missing.tolist()} have no non-empty training histogram "
            f"(labels must be 0..{n_classes - 1}, each with at least one grasp with triangles)"
        )
    return H, y, n_classes


def _as_histogram(h: np.ndarray, D: int) -> np.ndarray:
    h = np.asarray(h, dtype=np.float64)
    if h.shape != (D,):
        raise ValueError(f"expected a histogram of shape ({D},), got {h.shape}")
    return h


def _as_histograms(H: np.ndarray, D: int) -> np.ndarray:
    H = np.asarray(H, dtype=np.float64)
    if H.ndim != 2 or H.shape[1] != D:
        raise ValueError(f"expected histograms of shape (N, {D}), got {H.shape}")
    return H


def _normalise_probs(P: np.ndarray) -> np.ndarray:
    """Row-normalise non-negative scores; rows summing to 0 become uniform."""
    s = P.sum(axis=-1, keepdims=True)
    K = P.shape[-1]
    return np.divide(P, s, out=np.full_like(P, 1.0 / K), where=s > 0)


def _sigmoid_neg(z: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(z)), overflow-free."""
    return 1.0 / (1.0 + np.exp(np.clip(z, -Z_CLIP, Z_CLIP)))


def fit_platt(scores: np.ndarray, positive: np.ndarray) -> tuple[float, float]:
    """Platt's sigmoid p = 1 / (1 + exp(a s + c)) fitted to decision values by maximum likelihood,
    with Platt's smoothed targets (N+ + 1) / (N+ + 2) and 1 / (N- + 2). Returns (a, c)."""
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.optimize import minimize

    f = np.asarray(scores, dtype=np.float64)
    pos = np.asarray(positive, dtype=bool)
    n_pos = int(pos.sum())
    n_neg = len(pos) - n_pos
    t = np.where(pos, (n_pos + 1.0) / (n_pos + 2.0), 1.0 / (n_neg + 2.0))

    def loss(params: np.ndarray) -> tuple[float, np.ndarray]:
        z = params[0] * f + params[1]
        # -log p = log(1 + e^z), -log(1 - p) = log(1 + e^-z)
        value = float(np.sum(t * np.logaddexp(0.0, z) + (1.0 - t) * np.logaddexp(0.0, -z)))
        g = t - _sigmoid_neg(z)  # d value / dz
        return value, np.array([float(g @ f), float(g.sum())])

    x0 = np.array([0.0, np.log((n_neg + 1.0) / (n_pos + 1.0))])
    res = minimize(loss, x0, jac=True, method="L-BFGS-B")
    return float(res.x[0]), float(res.x[1])


def _stratified_folds(y: np.ndarray, n_folds: int, seed: int) -> np.ndarray:
    """Fold id per row, each class spread evenly over the folds."""
    rng = np.random.default_rng(seed)
    fold = np.empty(len(y), dtype=np.int64)
    for k in np.unique(y):
        rows = np.flatnonzero(y == k)
        fold[rng.permutation(rows)] = np.arange(len(rows)) % n_folds
    return fold


def _str_array(d: dict[str, np.ndarray], key: str) -> str:
    return str(np.asarray(d[key]).reshape(()).item())


def _check_keys(d: dict[str, Any], keys: tuple[str, ...], what: str) -> None:
    missing = [k for k in keys if k not in d]
    if missing:
        raise DataError(f"{what} arrays lack {', '.join(missing)}")


# ---------------------------------------------------------------------------------------------
# Classifiers


class _KernelClassifier:
    """Shared parts: the fitted state is exactly a ClassifierKernel."""

    name: ClassVar[str] = ""
    _kernel: ClassifierKernel | None = None

    @property
    def fitted(self) -> bool:
        return self._kernel is not None

    def kernel(self) -> ClassifierKernel:
        if self._kernel is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted")
        return self._kernel

    @property
    def n_classes(self) -> int:
        return self.kernel().n_classes

    @property
    def n_features(self) -> int:
        return int(self.kernel().W.shape[1])

    def _set_kernel(self, k: ClassifierKernel) -> None:
        # Row-per-class layouts (the usual case) take a faster numpy path than the general one.
        self._kernel = k
        self._one_row_per_class = len(k.row_class) == k.n_classes and np.array_equal(
            k.row_class, np.arange(k.n_classes)
        )
        # A row of ones under W: one matrix-vector product gives the scores and sum(h).
        self._W_sum = np.ascontiguousarray(np.vstack([k.W, np.ones((1, k.W.shape[1]))]))
        # a * (s / total + b) + c == (a / total) * s + (a * b + c)
        self._platt_offset = k.platt_a * k.b + k.platt_b
        self._uniform = np.full(k.n_classes, 1.0 / k.n_classes)

    def _per_class(self, v: np.ndarray, reduce: str) -> np.ndarray:
        """Combine per-row values (..., M) into per-class values (..., K)."""
        k = self.kernel()
        if self._one_row_per_class:
            return v
        out_shape = (*v.shape[:-1], k.n_classes)
        if reduce == "sum":
            out = np.zeros(out_shape)
            for m, c in enumerate(k.row_class):
                out[..., c] += v[..., m]
        else:
            out = np.full(out_shape, np.inf)
            for m, c in enumerate(k.row_class):
                out[..., c] = np.minimum(out[..., c], v[..., m])
        return out

    def _kernel_arrays(self) -> dict[str, np.ndarray]:
        k = self.kernel()
        return {
            "format_version": np.array(ARRAYS_FORMAT_VERSION, dtype=np.int64),
            "classifier": np.array(self.name),
            "kind": np.array(k.kind, dtype=np.int64),
            "W": k.W,
            "b": k.b,
            "row_class": k.row_class,
            "platt_a": k.platt_a,
            "platt_b": k.platt_b,
            "temperature": np.array(k.temperature, dtype=np.float64),
            "n_classes": np.array(k.n_classes, dtype=np.int64),
        }

    @staticmethod
    def _kernel_from_arrays(d: dict[str, np.ndarray], expect_name: str) -> ClassifierKernel:
        keys = ("format_version", "classifier", "kind", "W", "b", "row_class", "platt_a")
        _check_keys(d, (*keys, "platt_b", "temperature", "n_classes"), "classifier")
        version = int(np.asarray(d["format_version"]).reshape(()))
        if version != ARRAYS_FORMAT_VERSION:
            raise DataError(
                f"classifier arrays have format version {version}, expected {ARRAYS_FORMAT_VERSION}"
            )
        name = _str_array(d, "classifier")
        if name != expect_name:
            raise DataError(f"classifier arrays are for {name!r}, not {expect_name!r}")
        W = np.ascontiguousarray(d["W"], dtype=np.float64)
        if W.ndim != 2 or W.shape[0] == 0 or W.shape[1] == 0:
            raise DataError(f"classifier weight matrix has shape {W.shape}, expected (M, D)")
        M = W.shape[0]
        vecs = {}
        for key, dtype in (
            ("b", np.float64),
            ("row_class", np.int64),
            ("platt_a", np.float64),
            ("platt_b", np.float64),
        ):
            v = np.ascontiguousarray(d[key], dtype=dtype)
            if v.shape != (M,):
                raise DataError(f"classifier array {key} has shape {v.shape}, expected ({M},)")
            vecs[key] = v
        n_classes = int(np.asarray(d["n_classes"]).reshape(()))
        temperature = float(np.asarray(d["temperature"]).reshape(()))
        rc = vecs["row_class"]
        if n_classes < 1 or rc.min() < 0 or rc.max() >= n_classes:
            raise DataError(f"classifier row classes {rc.tolist()} do not fit {n_classes} classes")
        if not all(np.isfinite(a).all() for a in (W, *vecs.values())) or not temperature > 0:
            raise DataError("classifier arrays hold NaN/inf or a non-positive temperature")
        return ClassifierKernel(
            kind=int(np.asarray(d["kind"]).reshape(())),
            W=W,
            b=vecs["b"],
            row_class=rc,
            platt_a=vecs["platt_a"],
            platt_b=vecs["platt_b"],
            temperature=temperature,
            n_classes=n_classes,
        )


class LinearSVMClassifier(_KernelClassifier):
    """One-vs-rest linear SVM with per-class Platt calibration (see the module docstring)."""

    name: ClassVar[str] = "svm"

    def __init__(
        self,
        C: float = 1.0,
        calibration_folds: int = 3,
        max_iter: int = 5000,
        random_state: int = 0,
    ) -> None:
        if not C > 0:
            raise ConfigError(f"SVM regularisation C must be > 0, got {C}")
        if calibration_folds < 2:
            raise ConfigError(f"calibration_folds must be >= 2, got {calibration_folds}")
        self.C = float(C)
        self.calibration_folds = int(calibration_folds)
        self.max_iter = int(max_iter)
        self.random_state = int(random_state)
        self._kernel = None

    def _fit_svm(self, H1: np.ndarray, y: np.ndarray, n_classes: int) -> tuple[np.ndarray, ...]:
        """(W (K, D), b (K,)) of a LinearSVC on L1-normalised rows; binary expanded to 2 rows."""
        # deferred: scikit-learn takes 1.5 s to import; only fitting needs it
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.svm import LinearSVC

        svm = LinearSVC(C=self.C, max_iter=self.max_iter, random_state=self.random_state)
        with warnings.catch_warnings():
            # A not-quite-converged hinge solution is still a usable separator; the Platt
            # sigmoids are fitted to whatever scores it gives.
            warnings.simplefilter("ignore", ConvergenceWarning)
            svm.fit(H1, y)
        W = np.asarray(svm.coef_, dtype=np.float64)
        b = np.asarray(svm.intercept_, dtype=np.float64).reshape(-1)
        classes = np.asarray(svm.classes_)
        if len(classes) == 2:
            # Binary LinearSVC: one vector, positive scores mean classes[1].
            W = np.vstack([-W[0], W[0]])
            b = np.array([-b[0], b[0]])
        Wf = np.zeros((n_classes, H1.shape[1]))
        bf = np.zeros(n_classes)
        # Classes absent from a calibration fold keep a zero row (score 0 for them there).
        Wf[classes] = W
        bf[classes] = b
        return Wf, bf

    def fit(self, H: np.ndarray, y: np.ndarray) -> LinearSVMClassifier:
        H, y, K = _training_rows(H, y)
        H1 = l1_normalise_rows(H)
        n_folds = min(self.calibration_folds, int(np.bincount(y, minlength=K).min()))
        scores = np.empty((len(y), K))
        if n_folds >= 2:
            fold = _stratified_folds(y, n_folds, self.random_state)
            for f in range(n_folds):
                test = fold == f
                W, b = self._fit_svm(H1[~test], y[~test], K)
                scores[test] = H1[test] @ W.T + b
        else:
            # Some class has a single row: no held-out scores possible, calibrate in-sample.
            W, b = self._fit_svm(H1, y, K)
            scores = H1 @ W.T + b
        platt = np.array([fit_platt(scores[:, k], y == k) for k in range(K)])
        W, b = self._fit_svm(H1, y, K)
        self._set_kernel(
            ClassifierKernel(
                kind=KIND_LINEAR_OVR,
                W=np.ascontiguousarray(W),
                b=b,
                row_class=np.arange(K, dtype=np.int64),
                platt_a=np.ascontiguousarray(platt[:, 0]),
                platt_b=np.ascontiguousarray(platt[:, 1]),
                temperature=1.0,
                n_classes=K,
            )
        )
        return self

    def decision_function(self, H: np.ndarray) -> np.ndarray:
        """(N, M) raw SVM scores W h1 + b."""
        k = self.kernel()
        H1 = l1_normalise_rows(_as_histograms(H, k.W.shape[1]))
        return H1 @ k.W.T + k.b

    def proba(self, h: np.ndarray) -> np.ndarray:
        k = self.kernel()
        h = _as_histogram(h, k.W.shape[1])
        st = self._W_sum.dot(h)
        total = st[-1]
        if not total > 0:
            return self._uniform.copy()
        # Scores of the normalised histogram first: a/total overflows for a subnormal total.
        z = k.platt_a * (st[:-1] / total) + self._platt_offset
        q = self._per_class(1.0 / (1.0 + np.exp(np.minimum(z, Z_CLIP))), "sum")
        qs = q.sum()
        return q / qs if qs > 0 else self._uniform.copy()

    def proba_many(self, H: np.ndarray) -> np.ndarray:
        k = self.kernel()
        H = _as_histograms(H, k.W.shape[1])
        totals = H.sum(axis=1)
        s = (H @ k.W.T) / np.where(totals > 0, totals, 1.0)[:, None] + k.b
        q = self._per_class(_sigmoid_neg(k.platt_a * s + k.platt_b), "sum")
        q[totals <= 0] = 0.0
        return _normalise_probs(q)

    def to_arrays(self) -> dict[str, np.ndarray]:
        d = self._kernel_arrays()
        d["C"] = np.array(self.C)
        d["calibration_folds"] = np.array(self.calibration_folds, dtype=np.int64)
        d["max_iter"] = np.array(self.max_iter, dtype=np.int64)
        d["random_state"] = np.array(self.random_state, dtype=np.int64)
        return d

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> LinearSVMClassifier:
        k = cls._kernel_from_arrays(d, cls.name)
        if k.kind != KIND_LINEAR_OVR:
            raise DataError(f"SVM arrays have kernel kind {k.kind}, expected {KIND_LINEAR_OVR}")
        _check_keys(d, ("C", "calibration_folds", "max_iter", "random_state"), "SVM")
        obj = cls(
            C=float(np.asarray(d["C"]).reshape(())),
            calibration_folds=int(np.asarray(d["calibration_folds"]).reshape(())),
            max_iter=int(np.asarray(d["max_iter"]).reshape(())),
            random_state=int(np.asarray(d["random_state"]).reshape(())),
        )
        obj._set_kernel(k)
        return obj


NN_METRICS: dict[str, int] = {"inner": KIND_NN_INNER, "intersection": KIND_NN_INTERSECTION}


class NearestNeighbourClassifier(_KernelClassifier):
    """Nearest class template under inner-product or intersection distance, softmax over
    -distance / temperature (see the module docstring)."""

    TEMPERATURE_GRID: ClassVar[np.ndarray] = np.logspace(-3, 1, 161)

    def __init__(self, metric: str = "inner", temperature_folds: int = 5, random_state: int = 0):
        if metric not in NN_METRICS:
            raise ConfigError(
                f"unknown nearest-neighbour metric {metric!r}; choose from {sorted(NN_METRICS)}"
            )
        self.metric = metric
        self.temperature_folds = int(temperature_folds)
        self.random_state = int(random_state)
        self._kernel = None

    @property
    def name(self) -> str:  # type: ignore[override]
        return f"nn_{self.metric}"

    @property
    def kind(self) -> int:
        return NN_METRICS[self.metric]

    def _template_rows(self, H1: np.ndarray, y: np.ndarray, K: int) -> np.ndarray:
        """Per-class mean of L1-normalised rows, stored as the kernel wants its rows."""
        T = np.vstack([H1[y == c].mean(axis=0) for c in range(K)])
        if self.kind == KIND_NN_INNER:
            return T / np.linalg.norm(T, axis=1, keepdims=True)
        return l1_normalise_rows(T)

    def _distances(self, rows: np.ndarray, H: np.ndarray) -> np.ndarray:
        """(N, M) distances of histograms H (raw or normalised) to kernel rows."""
        totals = H.sum(axis=1)
        ok = totals > 0
        if self.kind == KIND_NN_INNER:
            safe = np.where(ok, totals, 1.0)[:, None]
            # Norm of h / sum(h), times sum(h): squares of tiny counts cannot underflow.
            norms = np.linalg.norm(H / safe, axis=1) * safe[:, 0]
            sim = np.abs(H @ rows.T) / np.where(ok, norms, 1.0)[:, None]
            return 1.0 - np.minimum(sim, 1.0)
        H1 = H / np.where(ok, totals, 1.0)[:, None]
        out = np.empty((len(H), len(rows)))
        for m in range(len(rows)):
            out[:, m] = 1.0 - np.minimum(H1, rows[m]).sum(axis=1)
        return out

    @staticmethod
    def _softmax(dmin: np.ndarray, temperature: float) -> np.ndarray:
        z = -(dmin - dmin.min(axis=-1, keepdims=True)) / temperature
        e = np.exp(z)
        return e / e.sum(axis=-1, keepdims=True)

    def _fit_temperature(self, H1: np.ndarray, y: np.ndarray, K: int) -> float:
        n_folds = min(self.temperature_folds, int(np.bincount(y, minlength=K).min()))
        if n_folds >= 2:
            fold = _stratified_folds(y, n_folds, self.random_state)
            D = np.empty((len(y), K))
            for f in range(n_folds):
                test = fold == f
                D[test] = self._distances(self._template_rows(H1[~test], y[~test], K), H1[test])
        else:
            D = self._distances(self._template_rows(H1, y, K), H1)
        D = D - D.min(axis=1, keepdims=True)
        d_true = D[np.arange(len(y)), y]
        best_t, best_ll = 1.0, -np.inf
        for t in self.TEMPERATURE_GRID:
            ll = float(np.sum(-d_true / t - np.log(np.exp(-D / t).sum(axis=1))))
            if ll > best_ll:
                best_t, best_ll = float(t), ll
        return best_t

    def fit(self, H: np.ndarray, y: np.ndarray) -> NearestNeighbourClassifier:
        H, y, K = _training_rows(H, y)
        H1 = l1_normalise_rows(H)
        temperature = self._fit_temperature(H1, y, K)
        rows = self._template_rows(H1, y, K)
        self._set_kernel(
            ClassifierKernel(
                kind=self.kind,
                W=np.ascontiguousarray(rows),
                b=np.zeros(K),
                row_class=np.arange(K, dtype=np.int64),
                platt_a=np.zeros(K),
                platt_b=np.zeros(K),
                temperature=temperature,
                n_classes=K,
            )
        )
        return self

    def templates(self) -> np.ndarray:
        """(M, D) class templates as L1-normalised histograms."""
        return l1_normalise_rows(self.kernel().W)

    def distances(self, h: np.ndarray) -> np.ndarray:
        """(K,) distance from h to the nearest template of each class."""
        k = self.kernel()
        h = _as_histogram(h, k.W.shape[1])
        return self._per_class(self._distances(k.W, h[None, :])[0], "min")

    def proba(self, h: np.ndarray) -> np.ndarray:
        k = self.kernel()
        h = _as_histogram(h, k.W.shape[1])
        if k.kind == KIND_NN_INNER:
            sq = h.dot(h)
            if 0.0 < sq < math.inf:
                norm = math.sqrt(sq)
            else:
                total = h.sum()
                if not total > 0:
                    return self._uniform.copy()
                # Squares of tiny (or huge) counts under/overflow: measure h / sum(h) instead.
                h1 = h / total
                norm = total * math.sqrt(h1.dot(h1))
            d = 1.0 - np.minimum(np.abs(k.W.dot(h)) * (1.0 / norm), 1.0)
        else:
            total = h.sum()
            if not total > 0:
                return self._uniform.copy()
            nz = (h > 0).nonzero()[0]
            if 4 * len(nz) < len(h):
                # Test-time histograms are sparse: min(w, 0) = 0 adds nothing outside h's support.
                m = np.minimum(k.W.take(nz, axis=1), h[nz] * (1.0 / total))
                d = 1.0 - m.dot(np.ones(len(nz)))
            else:
                d = 1.0 - np.minimum(k.W, h * (1.0 / total)).sum(axis=1)
        d = self._per_class(d, "min")
        e = np.exp((d.min() - d) * (1.0 / k.temperature))
        return e / e.sum()

    def proba_many(self, H: np.ndarray) -> np.ndarray:
        k = self.kernel()
        H = _as_histograms(H, k.W.shape[1])
        P = self._softmax(self._per_class(self._distances(k.W, H), "min"), k.temperature)
        P[H.sum(axis=1) <= 0] = 1.0 / k.n_classes
        return P

    def to_arrays(self) -> dict[str, np.ndarray]:
        d = self._kernel_arrays()
        d["metric"] = np.array(self.metric)
        d["temperature_folds"] = np.array(self.temperature_folds, dtype=np.int64)
        d["random_state"] = np.array(self.random_state, dtype=np.int64)
        return d

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> NearestNeighbourClassifier:
        _check_keys(d, ("metric", "temperature_folds", "random_state"), "nearest-neighbour")
        metric = _str_array(d, "metric")
        if metric not in NN_METRICS:
            raise DataError(f"nearest-neighbour arrays name an unknown metric {metric!r}")
        obj = cls(
            metric=metric,
            temperature_folds=int(np.asarray(d["temperature_folds"]).reshape(())),
            random_state=int(np.asarray(d["random_state"]).reshape(())),
        )
        k = cls._kernel_from_arrays(d, obj.name)
        if k.kind != obj.kind:
            raise DataError(f"{obj.name} arrays have kernel kind {k.kind}, expected {obj.kind}")
        obj._set_kernel(k)
        return obj


Classifier = LinearSVMClassifier | NearestNeighbourClassifier


def make_classifier(name: str, **kw: Any) -> Classifier:
    """A new, unfitted classifier by its configuration name: svm | nn_inner | nn_intersection."""
    if name == "svm":
        return LinearSVMClassifier(**kw)
    if name in ("nn_inner", "nn_intersection"):
        return NearestNeighbourClassifier(metric=name[3:], **kw)
    raise ConfigError(f"unknown classifier {name!r}; choose from {', '.join(CLASSIFIER_NAMES)}")


def classifier_from_arrays(d: dict[str, np.ndarray]) -> Classifier:
    """Rebuild whichever classifier ``to_arrays`` saved (dispatches on its stored name)."""
    _check_keys(d, ("classifier",), "classifier")
    name = _str_array(d, "classifier")
    if name == "svm":
        return LinearSVMClassifier.from_arrays(d)
    if name in ("nn_inner", "nn_intersection"):
        return NearestNeighbourClassifier.from_arrays(d)
    raise DataError(f"classifier arrays name an unknown classifier {name!r}")
