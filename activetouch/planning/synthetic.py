"""A synthetic observation model and classifier kernel with the shape of the real ones.

Used by the planner's tests and benchmark, where training a model from simulated grasps would
take minutes. The construction follows the paper's training stage (Alg. 1) on made-up data:

- Each class owns a grid of nominal wrist poses on a sphere of its own radius around the
  object centre, palm facing the centre; the planner sees all grids pooled (P poses), and
  every pose reaches every other pose (P - 1 edges each: with P = 1064 the paper's 1063
  actions per node).
- An action is the relative pose between two poses (translation in the first pose's frame,
  quaternion), discretised with the authors' cells (0.06 m, 0.05 per quaternion component);
  its movement cost is half the translation length over the longest one plus half the
  rotation angle over pi.
- Each pose has one training grasp: a few contacts, so 1 to C(n, 3) triangles, each falling in
  a histogram bin drawn from its class's bin distribution. A bin's conditioning cell is a fixed
  coarse grouping of bins (cells are coarser than bins, as with the authors' 0.08 cells).
- Tallies come only from pairs of poses of the *same* class, as in training: the row
  (y, a, z) counts the outcomes of grasp j for every pair (i, j) of class y with action a
  whose grasp i left cell z. So most (y, a, z) a planner meets at test time have no row (the
  marginal (y, a) fallback is exercised), some have no marginal row either, and a row holds
  only a few outcomes.
- Classifier: a one-vs-rest linear kernel whose weights are the centred class bin
  distributions, with Platt sigmoids that make a full class histogram confidently classified.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
from dataclasses import dataclass

import numpy as np

from activetouch.planning.observation_builder import concat_csr_rows, rank_edge_codes
from activetouch.planning.observation_model import (
    GRANULARITIES,
    ObservationModel,
    edge_index_dtype,
)
from activetouch.poses import look_at_axes, quat_conj, quat_mul, quat_rotate
from activetouch.recognition.kernels import KIND_LINEAR_OVR, ClassifierKernel

TRANSLATION_CELL_M = 0.06
QUATERNION_CELL = 0.05


@dataclass(frozen=True)
class SyntheticProblem:
    model: ObservationModel
    kernel: ClassifierKernel
    pose_class: np.ndarray  # (P,) class whose grid each pose belongs to
    class_bin_p: np.ndarray  # (K, n_bins) bin distribution of each class's triangles
    grasp_ptr: np.ndarray  # (P + 1,) CSR over poses into grasp_bin
    grasp_bin: np.ndarray  # bins of each pose's training grasp triangles
    cell_of_bin: np.ndarray  # (n_bins,) conditioning cell of a triangle in each bin

    def observe(self, pose: int) -> tuple[np.ndarray, np.ndarray]:
        """The training grasp at `pose` as a real observation: (histogram counts it adds,
        cells it leaves behind)."""
        m = self.model
        bins = self.grasp_bin[self.grasp_ptr[pose] : self.grasp_ptr[pose + 1]]
        counts = np.bincount(bins, minlength=m.n_bins).astype(np.float64)
        if m.granularity == "grasp":
            return counts, m.out_cell[pose : pose + 1].copy()
        return counts, np.unique(self.cell_of_bin[bins])


def _look_at_quaternions(direction: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(N, 4) x y z w of frames whose +z is `direction` (N, 3), rolled about it by `roll`."""
    x, y, z = look_at_axes(direction)
    cr, sr = np.cos(roll)[:, None], np.sin(roll)[:, None]
    x, y = cr * x + sr * y, -sr * x + cr * y
    R = np.stack([x, y, z], axis=2)  # columns are the frame axes
    return _matrix_to_quat(R)


def _ring_directions(step_deg: float) -> np.ndarray:
    """Unit vectors in horizontal rings every `step_deg` of elevation from 0, azimuths about
    `step_deg` apart, plus straight up (the authors' grid layout)."""
    dirs = [np.array([0.0, 0.0, 1.0])]
    for el in np.deg2rad(np.arange(0.0, 90.0 - 1e-9, step_deg)):
        n_az = max(1, round(360.0 * np.cos(el) / step_deg))
        az = np.arange(n_az) * (2 * np.pi / n_az)
        dirs.extend(
            np.stack(
                [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full(n_az, np.sin(el))], 1
            )
        )
    return np.array(dirs)


def _matrix_to_quat(R: np.ndarray) -> np.ndarray:
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()


def _rows(keys: np.ndarray, outs: np.ndarray, n_out: int) -> tuple[np.ndarray, ...]:
    """Tally entries (key, outcome), one per observation, into sorted CSR rows with
    cumulative probabilities."""
    uniq_code, counts = np.unique(keys * n_out + outs, return_counts=True)  # by key, outcome
    uk, uo = uniq_code // n_out, uniq_code % n_out
    rk, start = np.unique(uk, return_index=True)
    ptr = np.append(start, len(uk)).astype(np.int64)
    w = counts.astype(np.float64)
    row_of = np.repeat(np.arange(len(rk)), np.diff(ptr))
    totals = np.bincount(row_of, weights=w)
    cum = np.cumsum(w)
    before = np.concatenate([[0.0], cum[ptr[1:-1] - 1]])
    cum = (cum - before[row_of]) / totals[row_of]
    cum[ptr[1:] - 1] = 1.0  # exact row ends despite rounding
    return rk.astype(np.int64), ptr, uo.astype(np.int64), cum


# Action keys: the 7 integer cells of a relative pose, each offset into [0, 256), in base 256
# (56 bits). Translation cells reach +-70 with 100 classes (spheres up to 2.1 m apart), which
# a base of 128 let carry into the next cell, merging different moves into one action.
_KEY_BASE, _KEY_OFFSET = 256, 128


def _action_keys(xyz: np.ndarray, quat: np.ndarray, src: np.ndarray, tgt: np.ndarray) -> np.ndarray:
    """The action key of each edge src -> tgt: its discretised relative pose's 7 cells."""
    inv = quat_conj(quat[src])
    t_rel = quat_rotate(inv, xyz[tgt] - xyz[src])
    q_rel = quat_mul(inv, quat[tgt])
    q_rel *= np.where(q_rel[:, 3:4] < 0, -1.0, 1.0)  # q and -q are one rotation
    key = np.zeros(len(src), dtype=np.int64)
    for v, cell in ((t_rel, TRANSLATION_CELL_M), (q_rel, QUATERNION_CELL)):
        for col in np.trunc(v / cell).astype(np.int64).T:
            key = key * _KEY_BASE + (col + _KEY_OFFSET)
    return key


def _return_freed_memory() -> None:
    """Give freed scratch memory back to the OS. glibc keeps freed arrays of a few MB in its
    heap (the per-class tally parts, about 200 MB at 5000 poses x 100 classes), which would
    count in the process's memory for the rest of its life; elsewhere this does nothing."""

    with contextlib.suppress(OSError, AttributeError, TypeError):
        ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim(0)


def _decode_action_keys(keys: np.ndarray) -> np.ndarray:
    """(A, 7) discretised translation and quaternion of each action key (a column at a time:
    A is 3.5 M at 5000 poses)."""
    out = np.empty((len(keys), 7), dtype=np.float64)
    k = keys.copy()
    for col in range(6, -1, -1):
        out[:, col] = k % _KEY_BASE - _KEY_OFFSET
        out[:, col] *= TRANSLATION_CELL_M if col < 3 else QUATERNION_CELL
        k //= _KEY_BASE
    return out


def _action_lengths(
    action_delta: np.ndarray, chunk: int = 1 << 18
) -> tuple[np.ndarray, np.ndarray]:
    """(translation length, rotation angle) of each action, a slice at a time (the (A, 4)
    temporaries of a single pass are 100 MB each at 5000 poses)."""
    t_len = np.empty(len(action_delta))
    angle = np.empty(len(action_delta))
    for lo in range(0, len(action_delta), chunk):
        d = action_delta[lo : lo + chunk]
        t_len[lo : lo + chunk] = np.linalg.norm(d[:, :3], axis=1)
        qn = d[:, 3:] / np.maximum(np.linalg.norm(d[:, 3:], axis=1), 1e-12)[:, None]
        angle[lo : lo + chunk] = 2.0 * np.arccos(np.clip(np.abs(qn[:, 3]), 0.0, 1.0))
    return t_len, angle


def synthetic_problem(
    n_poses: int = 1064,
    n_classes: int = 7,
    n_cells: int = 64,
    *,
    rng: np.random.Generator,
    bins: int = 10,
    granularity: str = "triangle",
    contacts: tuple[int, int] = (3, 5),
    bins_per_class: int = 150,
    shared_fraction: float = 0.85,
    confidence: float = 10.0,
) -> SyntheticProblem:
    """Observation model + matching kernel (see the module docstring).

    `contacts`: inclusive range of contacts per training grasp. `bins_per_class`: support of a
    class's bin distribution. `shared_fraction`: weight of a bin distribution common to all
    classes (makes classes confusable). `confidence`: slope of the Platt sigmoids."""
    if granularity not in GRANULARITIES:
        raise ValueError(f"granularity must be one of {GRANULARITIES}, got {granularity!r}")
    if n_poses < 2 or n_classes < 2 or n_cells < 1:
        raise ValueError("need at least 2 poses, 2 classes and 1 cell")
    n_bins = bins**3
    K, P = n_classes, n_poses

    # Class bin distributions: own support plus a shared component.
    shared = rng.dirichlet(np.ones(bins_per_class))
    shared_bins = rng.choice(n_bins, bins_per_class, replace=False)
    q = np.zeros((K, n_bins))
    for y in range(K):
        own = rng.choice(n_bins, bins_per_class, replace=False)
        q[y, own] += (1.0 - shared_fraction) * rng.dirichlet(np.ones(bins_per_class))
        q[y, shared_bins] += shared_fraction * shared
    cell_of_bin = (np.arange(n_bins) * n_cells) // n_bins

    # Poses: class y's grid of rings on a sphere of radius 0.12 + 0.02 y (upper hemisphere),
    # two wrist rolls, a random subset of it when the grid holds more poses than wanted.
    pose_class = np.arange(P) % K
    xyz = np.empty((P, 3))
    quat = np.empty((P, 4))
    for y in range(K):
        ids = np.flatnonzero(pose_class == y)
        step = 25.0
        while 2 * len(_ring_directions(step)) < len(ids):
            step *= 0.9
        dirs = np.repeat(_ring_directions(step), 2, axis=0)
        rolls = np.tile([0.0, np.pi / 2], len(dirs) // 2)
        pick = np.sort(rng.choice(len(dirs), len(ids), replace=False))
        radius = 0.12 + 0.02 * y
        xyz[ids] = dirs[pick] * radius
        quat[ids] = _look_at_quaternions(-dirs[pick], rolls[pick])

    # Edges: every ordered pair of distinct poses; actions = discretised relative poses.
    # A block of source poses at a time (`rank_edge_codes`): every pair's relative pose at once
    # would take 25 M x 7 doubles at 5000 poses.
    edge_action, tgt, keys = rank_edge_codes(
        P,
        lambda src, dst: _action_keys(xyz, quat, src, dst),
        250_000,
        edge_index_dtype(P * (P - 1), P * (P - 1)),
    )
    A = len(keys)
    action_delta = _decode_action_keys(keys)
    del keys
    t_len, angle = _action_lengths(action_delta)
    action_cost = 0.5 * (t_len / max(t_len.max(), 1e-12)) + 0.5 * (angle / np.pi)
    edge_ptr = np.arange(P + 1, dtype=np.int64) * (P - 1)

    # One training grasp per pose: C(n, 3) triangles with bins from its class.
    n_contacts = rng.integers(contacts[0], contacts[1] + 1, P)
    n_tri = n_contacts * (n_contacts - 1) * (n_contacts - 2) // 6
    grasp_ptr = np.concatenate([[0], np.cumsum(n_tri)]).astype(np.int64)
    grasp_bin = np.concatenate(
        [rng.choice(n_bins, n_tri[i], p=q[pose_class[i]]) for i in range(P)]
    ).astype(np.int64)
    grasp_of_tri = np.repeat(np.arange(P), n_tri)

    if granularity == "triangle":
        # An outcome is one triangle's bin; its cell is the bin's cell.
        out_cell = cell_of_bin.astype(np.int64)
        out_ptr = np.arange(n_bins + 1, dtype=np.int64)
        out_bin = np.arange(n_bins, dtype=np.int64)
        # Cells grasp i leaves behind; outcomes grasp j produces (one per triangle).
        g_cells = [
            np.unique(cell_of_bin[grasp_bin[grasp_ptr[i] : grasp_ptr[i + 1]]]) for i in range(P)
        ]
        g_outs = [grasp_bin[grasp_ptr[j] : grasp_ptr[j + 1]] for j in range(P)]
    else:
        # An outcome is a whole grasp; its cell is the cell of its most frequent bin.
        out_ptr = grasp_ptr
        out_bin = grasp_bin
        rep = np.array(
            [
                np.bincount(cell_of_bin[grasp_bin[grasp_ptr[i] : grasp_ptr[i + 1]]]).argmax()
                for i in range(P)
            ]
        )
        out_cell = rep.astype(np.int64)
        g_cells = [rep[i : i + 1] for i in range(P)]
        g_outs = [np.array([j]) for j in range(P)]
    del grasp_of_tri

    # Tallies from same-class pairs only, aggregated per class (keys lead with the class, so
    # concatenating the classes' sorted rows keeps them sorted).
    n_out = len(out_cell)
    tally_parts: list[tuple[np.ndarray, ...]] = []
    marg_parts: list[tuple[np.ndarray, ...]] = []
    for y in range(K):
        members = np.flatnonzero(pose_class == y)
        t_keys: list[np.ndarray] = []
        t_outs: list[np.ndarray] = []
        m_keys: list[np.ndarray] = []
        m_outs: list[np.ndarray] = []
        for i in members:
            js = members[members != i]
            e = edge_ptr[i] + np.where(js < i, js, js - 1)
            acts = edge_action[e].astype(np.int64)  # int32 edges: codes below need int64
            outs = [g_outs[j] for j in js]
            lens = np.array([len(o) for o in outs])
            flat_out = np.concatenate(outs)
            flat_act = np.repeat(acts, lens)
            m_keys.append(y * A + flat_act)
            m_outs.append(flat_out)
            for z in g_cells[i]:
                t_keys.append((y * A + flat_act) * n_cells + z)
                t_outs.append(flat_out)
        tally_parts.append(_rows(np.concatenate(t_keys), np.concatenate(t_outs), n_out))
        marg_parts.append(_rows(np.concatenate(m_keys), np.concatenate(m_outs), n_out))
    tally_key, tally_ptr, tally_out, tally_cum = concat_csr_rows(*zip(*tally_parts, strict=True))
    marg_key, marg_ptr, marg_out, marg_cum = concat_csr_rows(*zip(*marg_parts, strict=True))
    del tally_parts, marg_parts
    _return_freed_memory()

    model = ObservationModel(
        granularity=granularity,
        class_names=tuple(f"class{y}" for y in range(K)),
        n_bins=n_bins,
        n_cells=n_cells,
        pose_xyz=xyz,
        pose_quat=quat,
        action_delta=action_delta,
        action_cost=action_cost,
        edge_ptr=edge_ptr,
        edge_action=edge_action,
        edge_target=tgt,
        out_cell=out_cell,
        out_ptr=out_ptr,
        out_bin=out_bin,
        tally_key=tally_key,
        tally_ptr=tally_ptr,
        tally_out=tally_out,
        tally_cum=tally_cum,
        marg_key=marg_key,
        marg_ptr=marg_ptr,
        marg_out=marg_out,
        marg_cum=marg_cum,
        # Cell c stands for the made-up triangle cell triple (c, 0, 0).
        cell_key=np.stack(
            [np.arange(n_cells), np.zeros(n_cells, int), np.zeros(n_cells, int)], axis=1
        ).astype(np.int64),
        translation_cell=TRANSLATION_CELL_M,
        quaternion_cell=QUATERNION_CELL,
        max_translation=float(t_len.max()),
    )
    return SyntheticProblem(
        model=model,
        kernel=synthetic_kernel(q, confidence=confidence),
        pose_class=pose_class,
        class_bin_p=q,
        grasp_ptr=grasp_ptr,
        grasp_bin=grasp_bin,
        cell_of_bin=cell_of_bin.astype(np.int64),
    )


def synthetic_kernel(class_bin_p: np.ndarray, confidence: float = 10.0) -> ClassifierKernel:
    """One-vs-rest linear kernel: score_y = (q_y - qbar) . (h1 - qbar) / ||q_y - qbar||^2, so
    the class's own distribution scores 1 and the mean distribution 0; Platt sigmoids of slope
    `confidence` centred at score 0.5."""
    q = np.asarray(class_bin_p, dtype=np.float64)
    K = q.shape[0]
    qbar = q.mean(axis=0)
    W = q - qbar
    W /= np.maximum((W * W).sum(axis=1, keepdims=True), 1e-12)
    return ClassifierKernel(
        kind=KIND_LINEAR_OVR,
        W=np.ascontiguousarray(W),
        b=-(W @ qbar),
        row_class=np.arange(K, dtype=np.int64),
        platt_a=np.full(K, -confidence),
        platt_b=np.full(K, 0.5 * confidence),
        temperature=1.0,
        n_classes=K,
    )


def synthetic_observation_model(
    n_poses: int = 1064,
    n_classes: int = 7,
    n_cells: int = 64,
    *,
    rng: np.random.Generator,
    **kw: object,
) -> ObservationModel:
    """Just the observation model of `synthetic_problem` (same arguments)."""
    return synthetic_problem(n_poses, n_classes, n_cells, rng=rng, **kw).model  # type: ignore[arg-type]
