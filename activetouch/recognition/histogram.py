"""3-D histogram of triangle parameters, the object descriptor (default 10 x 10 x 10 = 1000 bins).

Edges are ``linspace(lo[d], hi[d], bins + 1)`` per dimension d, with the ranges taken from all
training triangles and stored with the model. A value outside [lo, hi] is counted in the nearest
edge bin (test-time triangles can fall outside the training ranges); how many triangles were
clipped is reported on request. Bin i of dimension d is the half-open interval
[edge_i, edge_{i+1}), except that the last bin also holds hi. The flat index of bin
(i0, i1, i2) is ``(i0 * bins + i1) * bins + i2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, overload

import numpy as np

from activetouch.errors import DataError

SPEC_FORMAT = "activetouch.histogram_spec/1"


def _triangles(triangles: np.ndarray) -> np.ndarray:
    t = np.asarray(triangles, dtype=np.float64)
    if t.ndim == 1 and t.size == 0:
        t = t.reshape(0, 3)
    if t.ndim != 2 or t.shape[1] != 3:
        raise DataError(f"triangles must be an (m, 3) array, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise DataError("triangle parameters contain NaN or infinite values")
    return t


@dataclass(frozen=True, eq=False)
class HistogramSpec:
    """Bin layout of the triangle histogram: per-dimension range [lo, hi] and bins per dimension."""

    lo: np.ndarray  # (3,) float64
    hi: np.ndarray  # (3,) float64
    bins: int = 10

    def __post_init__(self) -> None:
        lo = np.array(self.lo, dtype=np.float64).reshape(-1)
        hi = np.array(self.hi, dtype=np.float64).reshape(-1)
        if lo.shape != (3,) or hi.shape != (3,):
            raise DataError(f"histogram ranges need 3 values each, got {lo.shape} and {hi.shape}")
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise DataError("histogram ranges must be finite")
        if not (hi > lo).all():
            raise DataError(f"histogram ranges need hi > lo in every dimension: lo={lo}, hi={hi}")
        if isinstance(self.bins, bool) or int(self.bins) != self.bins or int(self.bins) < 1:
            raise DataError(f"histogram bins must be a positive integer, got {self.bins!r}")
        lo.flags.writeable = False
        hi.flags.writeable = False
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "bins", int(self.bins))
        edges = np.stack([np.linspace(lo[d], hi[d], self.bins + 1) for d in range(3)])
        edges.flags.writeable = False
        object.__setattr__(self, "_edges", edges)
        object.__setattr__(self, "_edge_offset", np.arange(3, dtype=np.int64) * (self.bins + 1))
        object.__setattr__(self, "_strides", np.array([self.bins**2, self.bins, 1], dtype=np.int64))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, HistogramSpec):
            return NotImplemented
        return (
            self.bins == other.bins
            and np.array_equal(self.lo, other.lo)
            and np.array_equal(self.hi, other.hi)
        )

    def __hash__(self) -> int:
        return hash((self.lo.tobytes(), self.hi.tobytes(), self.bins))

    @classmethod
    def fit(cls, triangles: np.ndarray, bins: int = 10) -> HistogramSpec:
        """Ranges = min and max of the training triangles per dimension.

        A dimension where every triangle has the same value is widened slightly around it so
        the bins have a positive width.
        """
        t = _triangles(triangles)
        if len(t) == 0:
            raise DataError("cannot fit histogram ranges: no training triangles")
        lo = t.min(axis=0)
        hi = t.max(axis=0)
        flat = hi - lo <= 1e-12 * np.maximum(1.0, np.abs(lo))
        pad = np.maximum(1e-6 * np.abs(lo), 1e-9)
        lo = np.where(flat, lo - pad, lo)
        hi = np.where(flat, hi + pad, hi)
        return cls(lo=lo, hi=hi, bins=bins)

    @property
    def n_bins(self) -> int:
        return self.bins**3

    @property
    def edges(self) -> np.ndarray:
        """(3, bins + 1) bin edges."""
        return self._edges  # type: ignore[attr-defined]

    @property
    def centres(self) -> np.ndarray:
        """(3, bins) bin centres."""
        e = self.edges
        return 0.5 * (e[:, 1:] + e[:, :-1])

    @overload
    def bin_index(
        self, triangles: np.ndarray, return_clipped: Literal[False] = ...
    ) -> np.ndarray: ...

    @overload
    def bin_index(
        self, triangles: np.ndarray, return_clipped: Literal[True]
    ) -> tuple[np.ndarray, int]: ...

    def bin_index(
        self, triangles: np.ndarray, return_clipped: bool = False
    ) -> np.ndarray | tuple[np.ndarray, int]:
        """(m,) int64 flat bin of each triangle; with return_clipped also how many triangles had a
        value outside [lo, hi] (counted in the edge bin)."""
        t = _triangles(triangles)
        b = self.bins
        # Arithmetic bin guess, then a one-step correction against the linspace edges themselves,
        # so a value equal to an edge lands where numpy.histogramdd puts it (faster than
        # searchsorted per column).
        f = (t - self.lo) * (b / (self.hi - self.lo))
        np.clip(f, 0.0, b - 1.0, out=f)
        i = f.astype(np.int64)
        pos = i + self._edge_offset  # flat index into edges.ravel() of each lower edge
        edges = self.edges.ravel()
        i -= (t < edges.take(pos)) & (i > 0)
        pos = i + self._edge_offset + 1
        i += (t >= edges.take(pos)) & (i < b - 1)
        flat = i @ self._strides
        if return_clipped:
            outside = ((t < self.lo) | (t > self.hi)).any(axis=1)
            return flat, int(outside.sum())
        return flat

    def counts(self, triangles: np.ndarray) -> np.ndarray:
        """(n_bins,) float64 raw counts."""
        return np.bincount(self.bin_index(triangles), minlength=self.n_bins).astype(np.float64)

    def counts_with_clipped(self, triangles: np.ndarray) -> tuple[np.ndarray, int]:
        """Raw counts and the number of triangles clipped into an edge bin."""
        idx, clipped = self.bin_index(triangles, return_clipped=True)
        return np.bincount(idx, minlength=self.n_bins).astype(np.float64), clipped

    def histogram(self, triangles: np.ndarray) -> np.ndarray:
        """(n_bins,) L1-normalised histogram; all zeros when there are no triangles."""
        return l1_normalise(self.counts(triangles))

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": SPEC_FORMAT,
            "lo": [float(v) for v in self.lo],
            "hi": [float(v) for v in self.hi],
            "bins": self.bins,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> HistogramSpec:
        if not isinstance(d, dict):
            raise DataError(f"histogram spec must be a mapping, got {type(d).__name__}")
        fmt = d.get("format", SPEC_FORMAT)
        if fmt != SPEC_FORMAT:
            raise DataError(f"histogram spec has format {fmt!r}, expected {SPEC_FORMAT!r}")
        missing = [k for k in ("lo", "hi", "bins") if k not in d]
        if missing:
            raise DataError(f"histogram spec lacks {', '.join(missing)}")
        try:
            lo = np.asarray(d["lo"], dtype=np.float64)
            hi = np.asarray(d["hi"], dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise DataError(f"histogram spec ranges are not numbers: {e}") from None
        return cls(lo=lo, hi=hi, bins=d["bins"])


def l1_normalise(h: np.ndarray) -> np.ndarray:
    """h / sum(h) for a 1-D histogram; an all-zero histogram stays all zeros."""
    h = np.asarray(h, dtype=np.float64)
    total = h.sum()
    return h / total if total > 0 else np.zeros_like(h)


def l1_normalise_rows(H: np.ndarray) -> np.ndarray:
    """Row-wise L1 normalisation of (N, D) histograms; all-zero rows stay zero."""
    H = np.asarray(H, dtype=np.float64)
    totals = H.sum(axis=1, keepdims=True)
    return np.divide(H, totals, out=np.zeros_like(H), where=totals > 0)
