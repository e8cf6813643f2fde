"""The paper's observation model p(z' | z, a, y), as flat arrays the planner can run on.

Vocabulary (Zhang et al. 2017, Sec. III-IV):
- *pose*: a nominal absolute wrist pose in the object frame; training poses of all classes are
  pooled (the object pose is known at test time, so every class's grid is superimposed).
- *action* a: the relative wrist pose between two poses, discretised with the authors' cells.
- *cell*: the discretised triangle (or, at grasp level, a grasp's representative cell) that an
  observation leaves behind and that the next transition is conditioned on (the paper's z).
- *outcome*: what one simulated observation adds to the histogram: one triangle's bin at
  triangle granularity, every triangle bin of a training grasp at grasp granularity.

Every table is a flat numpy array (CSR where ragged), so the tree search can run compiled.

The builder (`observation_builder.build_observation_model`) says how it fills them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from activetouch.errors import ConfigError, DataError
from activetouch.poses import quat_conj, quat_mul, quat_rotate

GRANULARITIES = ("triangle", "grasp")
ACTION_FRAMES = ("relative", "absolute")

_I64 = np.int64
# Edge arrays (E = P (P - 1) entries, 25 M at 5000 poses) are 4-byte when their values fit.
_INT32_ARRAYS = frozenset({"edge_action", "edge_target"})


def empty_i64(*shape: int) -> np.ndarray:
    return np.zeros(shape or (0,), dtype=np.int64)


def edge_index_dtype(n_edges: int, n_values: int) -> type:
    """int32 for edge arrays whose count and values fit in it, else int64."""
    return np.int32 if max(n_edges, n_values) < 2**31 - 1 else np.int64


@dataclass(frozen=True)
class ObservationModel:
    granularity: str  # "triangle" | "grasp"
    class_names: tuple[str, ...]
    n_bins: int  # histogram length (bins ** 3)
    n_cells: int  # number of conditioning cells C
    # Poses (P): pooled nominal wrist poses in the object frame.
    pose_xyz: np.ndarray  # (P, 3) float64
    pose_quat: np.ndarray  # (P, 4) float64, x y z w
    # Actions (A): discretised relative poses and their movement cost c_m(a) in [0, 1].
    action_delta: np.ndarray  # (A, 7) float64: translation, quaternion (x y z w)
    action_cost: np.ndarray  # (A,) float64
    # Transitions from each pose (CSR over poses): action taken and pose reached.
    edge_ptr: np.ndarray  # (P + 1,) int64
    edge_action: np.ndarray  # (E,) int32 (int64 in models saved before, or beyond 2^31)
    edge_target: np.ndarray  # (E,) int32 (idem)
    # Outcomes (O): the cell each leaves behind and the histogram bins it adds (CSR).
    out_cell: np.ndarray  # (O,) int64
    out_ptr: np.ndarray  # (O + 1,) int64
    out_bin: np.ndarray  # (X,) int64, a bin repeated once per triangle that falls in it
    # Tallies keyed by (class y, action a, cell z): code = (y * A + a) * C + z, sorted ascending.
    tally_key: np.ndarray  # (R,) int64
    tally_ptr: np.ndarray  # (R + 1,) int64
    tally_out: np.ndarray  # (S,) int64 outcome ids
    tally_cum: np.ndarray  # (S,) float64 cumulative probability within each row (row ends at 1)
    # Fallback when the current cell never met action a for class y: p(z' | a, y),
    # keyed by code = y * A + a, sorted ascending.
    marg_key: np.ndarray  # (R2,) int64
    marg_ptr: np.ndarray  # (R2 + 1,) int64
    marg_out: np.ndarray  # (S2,) int64
    marg_cum: np.ndarray  # (S2,) float64
    # --- additions (defaults keep hand-built models valid) ---
    # Cell dictionary: integer triple trunc(v / triangle_cell) of each cell, rows sorted.
    cell_key: np.ndarray = field(default_factory=lambda: empty_i64(0, 3))  # (C, 3) int64
    translation_cell: float = 0.06  # m
    quaternion_cell: float = 0.05
    triangle_cell: float = 0.08
    max_translation: float = 0.0  # m, the largest edge translation: c_m's normaliser
    # Movement cost c_m of each edge (E,), what the search adds per step, when it is not the
    # action's: with absolute actions the cost is that of the move p -> q, which the action
    # (q alone) does not fix. Empty: c_m(edge) = action_cost[edge_action] (the paper's c_m(a)
    # with relative actions), which is not stored per edge (200 MB at 5000 poses).
    edge_cost: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (E,) or (0,) float64
    action_frame: str = "relative"  # "relative" (the paper) | "absolute", see the builder
    # Grasp granularity: the training grasp of each outcome (O,), indexing the training grasps
    # in class order, each class's in dataset order (what the grasp likelihood holds, for
    # planning on its belief). Empty for triangle outcomes and models saved before.
    out_grasp: np.ndarray = field(default_factory=empty_i64)

    @property
    def n_classes(self) -> int:
        return len(self.class_names)

    @property
    def n_poses(self) -> int:
        return len(self.pose_xyz)

    @property
    def n_actions(self) -> int:
        return len(self.action_cost)

    @property
    def n_outcomes(self) -> int:
        return len(self.out_cell)

    def edge_costs(self) -> np.ndarray:
        """(E,) float64 c_m of every edge: `edge_cost` if stored, else its action's cost."""
        if len(self.edge_cost):
            return self.edge_cost
        return np.asarray(self.action_cost, dtype=np.float64)[self.edge_action]

    @cached_property
    def rows_by_action(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The tally and marginal rows re-keyed so that one action's classes sit together:
        (tally codes (a C + z) K + y ascending, their rows, marginal codes a K + y ascending,
        their rows). Eq. 4 asks every class for (a, z) at once: with these it is one binary
        search and a short scan instead of K searches (cached; not saved with the model)."""
        K, A, C = self.n_classes, self.n_actions, self.n_cells
        return (*_rekey_by_class(self.tally_key, A * C, K), *_rekey_by_class(self.marg_key, A, K))

    # --- queries ------------------------------------------------------------------------------

    def actions_from(self, pose: int) -> tuple[np.ndarray, np.ndarray]:
        """(action ids, target pose ids) of the edges leaving pooled pose `pose`."""
        if not 0 <= pose < self.n_poses:
            raise IndexError(f"pose {pose} out of range [0, {self.n_poses})")
        lo, hi = self.edge_ptr[pose], self.edge_ptr[pose + 1]
        return self.edge_action[lo:hi], self.edge_target[lo:hi]

    def cells_of(self, triangles: np.ndarray) -> np.ndarray:
        """(m,) int64 cell id of each triangle (m, 3); -1 for a cell never seen in training."""
        t = np.asarray(triangles, dtype=np.float64).reshape(-1, 3)
        keys = cell_keys(t, self.triangle_cell)
        return _lookup_rows(self.cell_key, keys)

    def pose_index_of(self, pose: np.ndarray) -> int:
        """The pooled pose nearest to `pose` (7,), nearest meaning the cheapest move c_m."""
        if self.n_poses == 0:
            raise IndexError("the observation model has no poses")
        p = np.asarray(pose, dtype=np.float64).reshape(7)
        pooled = np.concatenate([self.pose_xyz, self.pose_quat], axis=1)
        delta = relative_pose(p, pooled)
        scale = self.max_translation if self.max_translation > 0 else 1.0
        return int(np.argmin(movement_cost(delta, scale, clip=False)))

    # --- storage ------------------------------------------------------------------------------

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array field, for an ``.npz`` (no pickle)."""
        return {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if isinstance(getattr(self, f.name), np.ndarray)
        }

    def scalars(self) -> dict[str, Any]:
        """Every non-array field, JSON-able."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, np.ndarray):
                out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def from_parts(cls, scalars: dict[str, Any], arrays: dict[str, np.ndarray]) -> ObservationModel:
        """Inverse of `scalars()` / `arrays()`; DataError when something is missing or wrong."""
        names = [f.name for f in dataclasses.fields(cls)]
        kw: dict[str, Any] = {}
        for name in names:
            if name in arrays:
                kw[name] = np.asarray(arrays[name])
            elif name in scalars:
                kw[name] = scalars[name]
        missing = [
            f.name
            for f in dataclasses.fields(cls)
            if f.name not in kw
            and f.default is dataclasses.MISSING
            and f.default_factory is dataclasses.MISSING
        ]
        if missing:
            raise DataError(f"observation model lacks {', '.join(missing)}")
        kw["class_names"] = tuple(str(c) for c in kw["class_names"])
        model = cls(**kw)
        model.validate()
        return model

    def validate(self) -> None:
        """Check dtypes and that every index and CSR pointer is consistent; DataError if not."""
        P, A, C, K = self.n_poses, self.n_actions, self.n_cells, self.n_classes
        n_out = self.n_outcomes

        def fail(msg: str) -> None:
            raise DataError(f"observation model is inconsistent: {msg}")

        if self.granularity not in GRANULARITIES:
            fail(f"granularity {self.granularity!r}")
        if self.action_frame not in ACTION_FRAMES:
            fail(f"action_frame {self.action_frame!r}")
        shapes = {
            "pose_xyz": (P, 3),
            "pose_quat": (P, 4),
            "action_delta": (A, 7),
            "edge_ptr": (P + 1,),
            "out_ptr": (n_out + 1,),
            "tally_ptr": (len(self.tally_key) + 1,),
            "marg_ptr": (len(self.marg_key) + 1,),
            "cell_key": (C, 3),
        }
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                fail(f"{name} has shape {getattr(self, name).shape}, expected {shape}")
        for name, arr in self.arrays().items():
            want = np.float64 if name in _FLOAT_ARRAYS else np.int64
            if arr.dtype != want and not (name in _INT32_ARRAYS and arr.dtype == np.int32):
                fail(f"{name} has dtype {arr.dtype}, expected {np.dtype(want)}")
        for ptr, data, what in (
            ("edge_ptr", ("edge_action", "edge_target"), "edges"),
            ("out_ptr", ("out_bin",), "outcome bins"),
            ("tally_ptr", ("tally_out", "tally_cum"), "tallies"),
            ("marg_ptr", ("marg_out", "marg_cum"), "marginal tallies"),
        ):
            p = getattr(self, ptr)
            n = len(getattr(self, data[0]))
            if p[0] != 0 or p[-1] != n or np.any(np.diff(p) < 0):
                fail(f"{ptr} is not a CSR index into {n} {what}")
            if any(len(getattr(self, d)) != n for d in data):
                fail(f"{', '.join(data)} differ in length")
        checks = [
            ("edge_action", A),
            ("edge_target", P),
            ("out_cell", C),
            ("out_bin", self.n_bins),
            ("tally_out", n_out),
            ("marg_out", n_out),
        ]
        for name, bound in checks:
            a = getattr(self, name)
            if len(a) and (a.min() < 0 or a.max() >= bound):
                fail(f"{name} holds ids outside [0, {bound})")
        for ptr, cum in (("tally_ptr", "tally_cum"), ("marg_ptr", "marg_cum")):
            p, c = getattr(self, ptr), getattr(self, cum)
            ends = p[1:][np.diff(p) > 0] - 1
            if np.any(np.diff(p) == 0) or np.any((c < 0) | (c > 1)) or np.any(c[ends] != 1.0):
                fail(f"{cum} is not a cumulative distribution per row")
        for key, bound in (("tally_key", K * A * C), ("marg_key", K * A)):
            k = getattr(self, key)
            if len(k) and (np.any(np.diff(k) <= 0) or k[0] < 0 or k[-1] >= bound):
                fail(f"{key} is not strictly ascending within [0, {bound})")
        if len(self.out_grasp) not in (0, n_out) or (
            len(self.out_grasp) and self.out_grasp.min() < 0
        ):
            fail(f"out_grasp has {len(self.out_grasp)} grasp ids for {n_out} outcomes")
        if len(self.edge_cost) not in (0, len(self.edge_action)):
            fail(f"edge_cost has {len(self.edge_cost)} costs for {len(self.edge_action)} edges")
        if not np.all((self.edge_cost >= 0) & (self.edge_cost <= 1)):
            fail("edge_cost holds movement costs outside [0, 1]")


_FLOAT_ARRAYS = frozenset(
    {"pose_xyz", "pose_quat", "action_delta", "action_cost", "tally_cum", "marg_cum", "edge_cost"}
)


def _rekey_by_class(key: np.ndarray, n_inner: int, K: int) -> tuple[np.ndarray, np.ndarray]:
    """Codes y * n_inner + r re-keyed as r * K + y, ascending, with the row of each."""
    key = np.asarray(key, dtype=np.int64)
    code = (key % max(n_inner, 1)) * K + key // max(n_inner, 1)
    order = np.argsort(code, kind="stable")
    return code[order], order.astype(np.int64)


# --- pure pose math ---------------------------------------------------------------------------


def canonical_quat(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) x y z w with the sign fixed: w > 0, or for w = 0 the first
    nonzero of x, y, z positive (q and -q are the same rotation)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    order = q[..., [3, 0, 1, 2]]
    big = np.abs(order) > 1e-12
    first = np.argmax(big, axis=-1)
    lead = np.take_along_axis(order, first[..., None], axis=-1)
    return np.where(lead < 0, -q, q)


def relative_pose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose of b in a's frame, (..., 7) x y z qx qy qz qw; broadcasts; quaternion canonical."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    qa = a[..., 3:] / np.linalg.norm(a[..., 3:], axis=-1, keepdims=True)
    qa_inv = quat_conj(qa)
    t = quat_rotate(qa_inv, b[..., :3] - a[..., :3])
    q = canonical_quat(quat_mul(qa_inv, b[..., 3:]))
    return np.concatenate([t, q], axis=-1)


def cell_keys(values: np.ndarray, cell: float) -> np.ndarray:
    """Integer cell index trunc(v / cell) (int64), robust to float noise at cell boundaries."""
    if not cell > 0:
        raise ConfigError(f"discretisation cell must be positive, got {cell}")
    return np.trunc(np.round(np.asarray(values, dtype=np.float64) / cell, 9)).astype(np.int64)


def discretise(values: np.ndarray, cell: float) -> np.ndarray:
    """The authors' discretisation trunc(v / cell) * cell."""
    return cell_keys(values, cell).astype(np.float64) * cell


def rotation_angle(quat: np.ndarray) -> np.ndarray:
    """Rotation angle in [0, pi] of quaternions (..., 4) (need not be unit)."""
    q = np.asarray(quat, dtype=np.float64)
    w = np.abs(q[..., 3]) / np.linalg.norm(q, axis=-1)
    return 2.0 * np.arccos(np.clip(w, 0.0, 1.0))


def travel_edge_cost(model: ObservationModel, seconds: np.ndarray) -> np.ndarray:
    """(E,) c_m of the model's edges from a (P, P) matrix of move durations between its poses
    (seconds, NaN: a move that cannot be made): each edge's duration over the longest finite
    one, so c_m stays in [0, 1] as in Eq. 1; an impossible move costs 1."""
    t = np.asarray(seconds, dtype=np.float64)
    if t.shape != (model.n_poses, model.n_poses):
        raise ValueError(f"travel times must be ({model.n_poses}, {model.n_poses}), got {t.shape}")
    src = np.repeat(np.arange(model.n_poses), np.diff(model.edge_ptr))
    edge_t = t[src, model.edge_target]
    finite = np.isfinite(edge_t)
    longest = float(edge_t[finite].max()) if finite.any() else 0.0
    cost = np.ones(len(edge_t))
    if longest > 0:
        cost[finite] = edge_t[finite] / longest
    return cost


def movement_cost(delta: np.ndarray, max_translation: float, clip: bool = True) -> np.ndarray:
    """c_m(a) in [0, 1]: 0.5 * |t| / max_translation + 0.5 * angle / pi for deltas (A, 7).

    Translation and rotation are each normalised to [0, 1] and weighted equally (paper Sec. IV).
    A translation beyond `max_translation` counts as 1 unless clip=False."""
    d = np.asarray(delta, dtype=np.float64)
    trans = np.linalg.norm(d[..., :3], axis=-1)
    tnorm = trans / max_translation if max_translation > 0 else np.zeros_like(trans)
    if clip:
        tnorm = np.minimum(tnorm, 1.0)
    return 0.5 * tnorm + 0.5 * rotation_angle(d[..., 3:]) / np.pi


# --- encoding helpers -------------------------------------------------------------------------


def encode_rows(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct rows of an (n, k) int64 array: (unique rows sorted, first index, inverse)."""
    keys = np.asarray(keys, dtype=np.int64)
    n, k = keys.shape
    if n == 0:
        return keys.reshape(0, k), empty_i64(), empty_i64()
    lo = keys.min(axis=0)
    span = keys.max(axis=0) - lo + 1
    if np.sum(np.log2(span.astype(np.float64))) < 62:
        # Mixed-radix code: one int64 per row, so np.unique stays one fast 1-D sort.
        code = np.zeros(n, dtype=np.int64)
        for d in range(k):
            code = code * span[d] + (keys[:, d] - lo[d])
        _, first, inverse = np.unique(code, return_index=True, return_inverse=True)
    else:
        _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return keys[first], first.astype(np.int64), inverse.reshape(-1).astype(np.int64)


def _lookup_rows(table: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Index of each row of `keys` in the lexicographically sorted unique rows `table`, or -1."""
    out = np.full(len(keys), -1, dtype=np.int64)
    if len(table) == 0 or len(keys) == 0:
        return out
    lo = table.min(axis=0)
    span = table.max(axis=0) - lo + 1
    inside = np.all((keys >= lo) & (keys < lo + span), axis=1)
    # Within the table's ranges a mixed-radix code preserves lexicographic order.
    code_t = np.zeros(len(table), dtype=np.int64)
    code_k = np.zeros(int(inside.sum()), dtype=np.int64)
    ki = keys[inside]
    for d in range(table.shape[1]):
        code_t = code_t * span[d] + (table[:, d] - lo[d])
        code_k = code_k * span[d] + (ki[:, d] - lo[d])
    pos = np.searchsorted(code_t, code_k)
    pos_c = np.minimum(pos, len(code_t) - 1)
    found = code_t[pos_c] == code_k
    res = np.where(found, pos_c, -1)
    out[np.flatnonzero(inside)] = res
    return out


def pose_keys(poses: np.ndarray, tcell: float, qcell: float) -> np.ndarray:
    return np.concatenate(
        [cell_keys(poses[:, :3], tcell), cell_keys(canonical_quat(poses[:, 3:]), qcell)], axis=1
    )


# --- sampling (reference numpy implementation of Eq. 4) ---------------------------------------


def _find(keys: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Row of each code in the sorted `keys`, -1 where absent."""
    if len(keys) == 0:
        return np.full(len(codes), -1, dtype=np.int64)
    pos = np.minimum(np.searchsorted(keys, codes), len(keys) - 1)
    return np.where(keys[pos] == codes, pos, -1).astype(np.int64)


def class_rows(model: ObservationModel, cell: int, action: int) -> tuple[str, np.ndarray]:
    """Which table answers (cell, action) and each class's row in it (-1: no data).

    ("tally", rows) when some class has a row for (y, action, cell); else ("marg", rows) from
    the (y, action) marginal rows; ("none", all -1) when no class has data for the action."""
    if not 0 <= action < model.n_actions:
        raise IndexError(f"action {action} out of range [0, {model.n_actions})")
    y = np.arange(model.n_classes, dtype=np.int64)
    A, C = model.n_actions, model.n_cells
    if 0 <= cell < C:
        rows = _find(model.tally_key, (y * A + action) * C + cell)
        if np.any(rows >= 0):
            return "tally", rows
    rows = _find(model.marg_key, y * A + action)
    return ("marg" if np.any(rows >= 0) else "none"), rows


def _class_weights(p_y: np.ndarray, rows: np.ndarray, n_classes: int) -> np.ndarray:
    p = np.asarray(p_y, dtype=np.float64).reshape(-1)
    if p.shape != (n_classes,) or np.any(p < 0) or not np.all(np.isfinite(p)):
        raise ValueError(f"p_y must be {n_classes} non-negative probabilities, got {p}")
    w = np.where(rows >= 0, p, 0.0)
    if w.sum() <= 0:  # the classifier rules out every class with data: treat those alike
        w = (rows >= 0).astype(np.float64)
    return w / w.sum()


def sample_outcome(
    model: ObservationModel,
    cell: int,
    action: int,
    p_y: np.ndarray,
    rng: np.random.Generator,
) -> int:
    """Draw z' ~ sum_y p(z' | z=cell, a=action, y) p(y) (Eq. 4); -1 when nothing is known.

    Classes without a row for (y, action, cell) are left out and p(y) renormalised over the
    rest; when no class has one, the (y, action) marginal rows are used the same way."""
    table, rows = class_rows(model, cell, action)
    if table == "none":
        return -1
    w = _class_weights(p_y, rows, model.n_classes)
    y = min(int(np.searchsorted(np.cumsum(w), rng.random() * w.sum(), side="right")), len(w) - 1)
    while w[y] <= 0:  # only reachable through rounding at the top end
        y -= 1
    ptr, out, cum = (
        (model.tally_ptr, model.tally_out, model.tally_cum)
        if table == "tally"
        else (model.marg_ptr, model.marg_out, model.marg_cum)
    )
    lo, hi = ptr[rows[y]], ptr[rows[y] + 1]
    k = min(int(np.searchsorted(cum[lo:hi], rng.random(), side="right")), hi - lo - 1)
    return int(out[lo + k])


def outcome_probabilities_per_class(
    model: ObservationModel, cell: int, action: int, p_y: np.ndarray
) -> np.ndarray:
    """(O,) probabilities of each outcome under the per-class back-off reading of Eq. 4
    (planner.eq4_sampling = "per_class"): class y, drawn from the full `p_y`, answers from its
    (action, cell) row, else its (action) row, else with nothing; the mass of "nothing" is
    1 - sum of the result."""
    if not 0 <= action < model.n_actions:
        raise IndexError(f"action {action} out of range [0, {model.n_actions})")
    p = np.asarray(p_y, dtype=np.float64).reshape(-1)
    if p.shape != (model.n_classes,) or np.any(p < 0) or not np.all(np.isfinite(p)):
        raise ValueError(f"p_y must be {model.n_classes} non-negative probabilities, got {p}")
    p = p / p.sum()
    y = np.arange(model.n_classes, dtype=np.int64)
    A, C = model.n_actions, model.n_cells
    tally = _find(model.tally_key, (y * A + action) * C + cell) if 0 <= cell < C else -(y + 1)
    marg = _find(model.marg_key, y * A + action)
    probs = np.zeros(model.n_outcomes)
    for k in range(model.n_classes):
        if tally[k] >= 0:
            ptr, out, cum, r = model.tally_ptr, model.tally_out, model.tally_cum, tally[k]
        elif marg[k] >= 0:
            ptr, out, cum, r = model.marg_ptr, model.marg_out, model.marg_cum, marg[k]
        else:
            continue
        lo, hi = ptr[r], ptr[r + 1]
        np.add.at(probs, out[lo:hi], p[k] * np.diff(np.concatenate([[0.0], cum[lo:hi]])))
    return probs


def outcome_probabilities(
    model: ObservationModel, cell: int, action: int, p_y: np.ndarray
) -> np.ndarray:
    """(O,) exact probabilities of each outcome under `sample_outcome` (zeros if no data)."""
    probs = np.zeros(model.n_outcomes)
    table, rows = class_rows(model, cell, action)
    if table == "none":
        return probs
    w = _class_weights(p_y, rows, model.n_classes)
    ptr, out, cum = (
        (model.tally_ptr, model.tally_out, model.tally_cum)
        if table == "tally"
        else (model.marg_ptr, model.marg_out, model.marg_cum)
    )
    for y in np.flatnonzero(w > 0):
        lo, hi = ptr[rows[y]], ptr[rows[y] + 1]
        pmf = np.diff(np.concatenate([[0.0], cum[lo:hi]]))
        np.add.at(probs, out[lo:hi], w[y] * pmf)
    return probs
