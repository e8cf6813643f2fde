"""Building the observation model (observation_model.py) from training grasps.

How `build_observation_model` fills the tables:
- Discretisation is the authors' ``trunc(v / cell) * cell`` (values are rounded to 9 decimals of
  a cell first, so 0.12 / 0.06 counts as 2, not 1.999...). Quaternions are sign-canonicalised
  (w >= 0) before they are discretised.
- Poses: training poses of all classes, deduplicated by their discretised (translation,
  quaternion) key; the first pose met with a key represents it. Pose ids follow first occurrence.
- Edges: every ordered pair p != q of pooled poses, CSR by p with q ascending; the action of an
  edge is the discretised pose of q in p's frame. Action ids index the distinct discretised
  relative poses (ascending key order); `action_delta` holds the discretised values and
  `action_cost` the mean movement cost of the exact relative poses of the edges in the action.
- Absolute actions (observation.action_frame = "absolute", not the paper): the action of an
  edge p -> q is q's own discretised pose (A = P); class y's tallies come from pairs (i, j) of
  its grasps at different poses where j is y's grasp in q's cell, else y's grasp nearest to q
  within absolute_near_m / absolute_near_deg (the objects' grids differ in radius). The move's
  cost then depends on p as well, so `edge_cost` holds the exact c_m of each edge.
- Cells: a dictionary of the discretised triangle triples met in training; `cell_key[c]` is the
  integer triple ``trunc(v / triangle_cell)`` of cell c (rows sorted). Unseen triples -> -1.
- Tallies of class y from every ordered pair (i, j) of its grasps at different pooled poses,
  action a = the action of the edge (pose of i, pose of j):
  * "triangle" (the paper): for every triangle of i in cell c and every triangle t' of j,
    count[(y, a, c) -> (cell of t', bin of t')] += 1. Outcomes are the distinct (cell, bin) pairs.
  * "grasp": outcomes are the distinct (grasp j, cell c') pairs of all classes; an outcome adds
    all of j's triangle bins and leaves cell c' behind. count[(y, a, c) -> (j, c')] +=
    n_i(c) * n_j(c'), the numbers of i's triangles in c and of j's in c'.
  Grasps without triangles are never outcomes (there is nothing to add to the histogram).
- Marginal rows p(z' | a, y): every pair (i, j) (also i without triangles) adds n_j(o) to
  outcome o, i.e. the conditioning on i's cells is dropped.
Rows are normalised and stored as cumulative probabilities (outcomes ascending within a row).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

import numpy as np
import scipy.sparse as sp

from activetouch.config import ObservationConfig
from activetouch.errors import ConfigError, DataError
from activetouch.planning.observation_model import (
    ACTION_FRAMES,
    GRANULARITIES,
    ObservationModel,
    canonical_quat,
    cell_keys,
    edge_index_dtype,
    empty_i64,
    encode_rows,
    movement_cost,
    pose_keys,
    relative_pose,
)
from activetouch.recognition.histogram import HistogramSpec


def pose_spread(poses: np.ndarray, translation_cell: float, quaternion_cell: float) -> np.ndarray:
    """How far (m) each training pose (n, 7), in class order, lies from the pose its pooled
    pose is executed at: the first pose met with the same discretised key, as
    `build_observation_model` pools them. Cells wider than the spread of the objects' grid
    radii send the hand to one object's grid pose for all of them (docs/benchmark.md)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
    if not len(poses):
        return np.zeros(0)
    _, first, inv = encode_rows(pose_keys(poses, translation_cell, quaternion_cell))
    return np.linalg.norm(poses[:, :3] - poses[first[inv.reshape(-1)], :3], axis=1)


# The translation cells `cells_for_library` chooses among, coarsest first (metres).
LIBRARY_CELLS_M = (0.06, 0.04, 0.03, 0.02, 0.015, 0.01)


def cells_for_library(poses: np.ndarray, cfg: ObservationConfig) -> float:
    """The translation cell to pool `poses` (n, 7, every class's training poses) by: with
    `cfg.cells_from = "library"` the coarsest of `LIBRARY_CELLS_M` no coarser than
    `cfg.translation_cell_m` whose pooled poses send the hand at most `cfg.max_pose_shift_m`
    from a pose a class was trained at (the finest if none does); else the setting."""
    if cfg.cells_from == "setting":
        return float(cfg.translation_cell_m)
    if cfg.cells_from != "library":
        raise ConfigError(f"observation.cells_from: {cfg.cells_from!r} is not library or setting")
    if not cfg.max_pose_shift_m > 0:
        raise ConfigError(f"observation.max_pose_shift_m must be > 0, got {cfg.max_pose_shift_m}")
    start = float(cfg.translation_cell_m)
    cells = [start] + [c for c in LIBRARY_CELLS_M if c < start - 1e-12]
    for c in cells:
        d = pose_spread(poses, c, cfg.quaternion_cell)
        if not len(d) or d.max() <= cfg.max_pose_shift_m:
            return c
    return cells[-1]


def _cumulative_rows(m: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ptr, outcome ids, cumulative probabilities) of a CSR count matrix without empty rows."""
    m.sum_duplicates()
    m.sort_indices()
    ptr = m.indptr.astype(np.int64)
    data = m.data.astype(np.float64)
    lens = np.diff(ptr)
    cs = np.cumsum(data)
    start = np.concatenate([[0.0], cs])[ptr[:-1]]
    total = np.concatenate([[0.0], cs])[ptr[1:]] - start
    cum = (cs - np.repeat(start, lens)) / np.repeat(total, lens)
    cum[ptr[1:] - 1] = 1.0  # exact row ends, whatever the rounding
    return ptr, m.indices.astype(np.int64), cum


# --- builder ----------------------------------------------------------------------------------


def build_observation_model(
    objects: Sequence[tuple[str, np.ndarray, Sequence[np.ndarray]]],
    spec: HistogramSpec,
    cfg: ObservationConfig,
) -> ObservationModel:
    """The observation model of training data: per object (name, poses (G, 7), triangles of each
    grasp [(m_g, 3)]). See the module docstring for what each table holds."""
    if cfg.granularity not in GRANULARITIES:
        raise ConfigError(
            f"observation.granularity {cfg.granularity!r}: choose one of {', '.join(GRANULARITIES)}"
        )
    if cfg.action_frame not in ACTION_FRAMES:
        raise ConfigError(
            f"observation.action_frame {cfg.action_frame!r}: choose one of "
            f"{', '.join(ACTION_FRAMES)}"
        )
    if cfg.action_frame == "absolute" and not (
        cfg.absolute_near_m >= 0 and cfg.absolute_near_deg >= 0
    ):
        raise ConfigError(
            "observation.absolute_near_m and absolute_near_deg must be >= 0, got "
            f"{cfg.absolute_near_m} and {cfg.absolute_near_deg}"
        )
    tcell, qcell, ccell = cfg.translation_cell_m, cfg.quaternion_cell, cfg.triangle_cell
    for name, v in (
        ("translation_cell_m", tcell),
        ("quaternion_cell", qcell),
        ("triangle_cell", ccell),
    ):
        if not v > 0:
            raise ConfigError(f"observation.{name} must be positive, got {v}")
    if not objects:
        raise DataError("cannot build an observation model without objects")
    names = tuple(str(o[0]) for o in objects)
    if len(set(names)) != len(names):
        raise DataError(f"duplicate object names in {names}")
    K = len(objects)

    # Grasps of all classes, concatenated in object order.
    pose_blocks, tri_blocks, tri_count, grasp_class = [], [], [], []
    for y, (name, poses, tris) in enumerate(objects):
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
        if len(tris) != len(poses):
            raise DataError(f"object {name}: {len(poses)} poses but {len(tris)} triangle tables")
        if not np.all(np.isfinite(poses)):
            raise DataError(f"object {name}: poses hold NaN or infinite values")
        pose_blocks.append(poses)
        for t in tris:
            t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
            tri_blocks.append(t)
            tri_count.append(len(t))
        grasp_class.append(np.full(len(poses), y, dtype=np.int64))
    all_poses = np.concatenate(pose_blocks)
    g_class = np.concatenate(grasp_class)
    n_grasps = len(all_poses)
    tri_ptr = np.zeros(n_grasps + 1, dtype=np.int64)
    np.cumsum(np.asarray(tri_count, dtype=np.int64), out=tri_ptr[1:])
    tris = np.concatenate([*tri_blocks, np.zeros((0, 3))])
    tri_grasp = np.repeat(np.arange(n_grasps, dtype=np.int64), np.diff(tri_ptr))

    # Poses: dedupe by discretised key, ids in order of first occurrence.
    _, first, inv = encode_rows(pose_keys(all_poses, tcell, qcell))
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    grasp_pose = rank[inv] if n_grasps else empty_i64()
    rep = all_poses[first[order]]
    pose_xyz = rep[:, :3].copy()
    pose_quat = canonical_quat(rep[:, 3:]) if len(rep) else np.zeros((0, 4))
    P = len(rep)

    # Edges p -> q (q != p, ascending) and their discretised actions.
    pooled = np.concatenate([pose_xyz, pose_quat], axis=1)
    absolute = cfg.action_frame == "absolute"
    pose_action = empty_i64()
    if absolute:
        # The action of p -> q is q's own cell: pooled poses have distinct cells, so A = P.
        akeys, _, pose_action = encode_rows(pose_keys(pooled, tcell, qcell))
        edges = _all_pairs_edges(pooled, tcell, qcell, absolute_keys=(akeys, pose_action))
    else:
        edges = _all_pairs_edges(pooled, tcell, qcell)
    edge_action, dst, akeys, action_cost, edge_cost, max_t = edges
    A = len(akeys)
    action_delta = np.concatenate(
        [akeys[:, :3].astype(np.float64) * tcell, akeys[:, 3:].astype(np.float64) * qcell], axis=1
    )
    edge_ptr = np.arange(P + 1, dtype=np.int64) * max(P - 1, 0)

    # Cells and bins of every training triangle.
    cell_key, _, tri_cell = encode_rows(cell_keys(tris, ccell))
    C = len(cell_key)
    tri_bin = spec.bin_index(tris) if len(tris) else empty_i64()
    nb = spec.n_bins

    # Outcomes: one id per triangle, so both granularities share the tally code below.
    out_grasp = empty_i64()
    if cfg.granularity == "triangle":
        ucode, tri_out = np.unique(tri_cell * nb + tri_bin, return_inverse=True)
        out_cell = (ucode // nb).astype(np.int64)
        out_ptr = np.arange(len(ucode) + 1, dtype=np.int64)
        out_bin = (ucode % nb).astype(np.int64)
    else:
        ucode, tri_out = np.unique(tri_grasp * max(C, 1) + tri_cell, return_inverse=True)
        out_cell = (ucode % max(C, 1)).astype(np.int64)
        og = (ucode // max(C, 1)).astype(np.int64)  # grasp of each outcome
        out_grasp = og
        lens = np.diff(tri_ptr)[og]
        out_ptr = np.zeros(len(ucode) + 1, dtype=np.int64)
        np.cumsum(lens, out=out_ptr[1:])
        gather = np.repeat(tri_ptr[og] - out_ptr[:-1], lens) + np.arange(out_ptr[-1])
        out_bin = tri_bin[gather].astype(np.int64)
    tri_out = tri_out.reshape(-1).astype(np.int64)
    n_out = len(out_cell)

    ones = np.ones(len(tris))
    cmat = sp.csr_matrix((ones, (tri_grasp, tri_cell)), shape=(n_grasps, max(C, 1)))
    omat = sp.csr_matrix((ones, (tri_grasp, tri_out)), shape=(n_grasps, max(n_out, 1)))
    cmat.sum_duplicates()
    omat.sum_duplicates()

    t_keys, t_ptrs, t_outs, t_cums = [], [], [], []
    m_keys, m_ptrs, m_outs, m_cums = [], [], [], []
    for y in range(K):
        g = np.flatnonzero(g_class == y)
        if len(g) < 2 or P < 2:
            continue
        if absolute:
            ii, jj, act = _absolute_pairs(
                g,
                grasp_pose,
                all_poses,
                pooled,
                pose_action,
                cfg.absolute_near_m,
                np.deg2rad(cfg.absolute_near_deg),
            )
        else:
            ii = np.repeat(g, len(g))
            jj = np.tile(g, len(g))
            pi, pj = grasp_pose[ii], grasp_pose[jj]
            ok = pi != pj
            ii, jj, pi, pj = ii[ok], jj[ok], pi[ok], pj[ok]
            act = edge_action[pi * (P - 1) + pj - (pj > pi)].astype(np.int64)
        if len(ii) == 0:
            continue
        n_pairs = len(ii)
        right = omat[jj]  # (pairs, O): outcomes of the second grasp of each pair

        # Conditioned rows (a, c): left[(a, c), k] = n_i(c) for pair k.
        ci = cmat[ii]
        plen = np.diff(ci.indptr)
        rowkey = np.repeat(act, plen) * C + ci.indices
        urow, rinv = np.unique(rowkey, return_inverse=True)
        left = sp.csr_matrix(
            (ci.data, (rinv.reshape(-1), np.repeat(np.arange(n_pairs), plen))),
            shape=(len(urow), n_pairs),
        )
        ptr, outs, cum = _cumulative_rows(sp.csr_matrix(left @ right))
        keep = np.diff(ptr) > 0
        if not keep.all():  # rows whose pairs had no outcome at all
            ptr, outs, cum, urow = _drop_empty(ptr, outs, cum, urow, keep)
        t_keys.append(y * A * C + urow)
        t_ptrs.append(ptr)
        t_outs.append(outs)
        t_cums.append(cum)

        # Marginal rows (a): every pair counts once, whatever i's cells.
        uact, ainv = np.unique(act, return_inverse=True)
        lm = sp.csr_matrix(
            (np.ones(n_pairs), (ainv.reshape(-1), np.arange(n_pairs))), shape=(len(uact), n_pairs)
        )
        ptr, outs, cum = _cumulative_rows(sp.csr_matrix(lm @ right))
        keep = np.diff(ptr) > 0
        if not keep.all():
            ptr, outs, cum, uact = _drop_empty(ptr, outs, cum, uact, keep)
        m_keys.append(y * A + uact)
        m_ptrs.append(ptr)
        m_outs.append(outs)
        m_cums.append(cum)

    tally_key, tally_ptr, tally_out, tally_cum = concat_csr_rows(t_keys, t_ptrs, t_outs, t_cums)
    marg_key, marg_ptr, marg_out, marg_cum = concat_csr_rows(m_keys, m_ptrs, m_outs, m_cums)
    return ObservationModel(
        granularity=cfg.granularity,
        class_names=names,
        n_bins=nb,
        n_cells=C,
        pose_xyz=pose_xyz,
        pose_quat=pose_quat,
        action_delta=action_delta,
        action_cost=action_cost,
        edge_ptr=edge_ptr,
        edge_action=edge_action,
        edge_target=dst,
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
        cell_key=cell_key,
        translation_cell=float(tcell),
        quaternion_cell=float(qcell),
        triangle_cell=float(ccell),
        max_translation=max_t,
        edge_cost=np.asarray(edge_cost, dtype=np.float64),
        action_frame=cfg.action_frame,
        out_grasp=out_grasp,
    )


def _absolute_pairs(
    g: np.ndarray,
    grasp_pose: np.ndarray,
    all_poses: np.ndarray,
    pooled: np.ndarray,
    pose_action: np.ndarray,
    near_m: float,
    near_rad: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tally pairs (i, j, action) of one class's grasps `g` for absolute actions.

    For every pooled pose q the class answers with its grasps at q's cell, else with those at
    the pooled pose of its grasp nearest to q (translation) among the grasps within `near_m`
    and `near_rad`; j is such a grasp, the action is q's, and i runs over the class's grasps
    at other poses than j (the conditioning observation came from somewhere else)."""
    P = len(pooled)
    diff = all_poses[g][None, :, :3] - pooled[:, None, :3]
    dist = np.linalg.norm(diff, axis=-1)  # (P, n_g)
    dots = np.abs(canonical_quat(all_poses[g][:, 3:]) @ pooled[:, 3:].T).T
    angle = 2.0 * np.arccos(np.clip(dots, 0.0, 1.0))
    ok = (dist <= near_m) & (angle <= near_rad)
    score = np.where(ok, dist, np.inf)
    own = grasp_pose[g][None, :] == np.arange(P)[:, None]
    score[own] = -1.0  # a grasp in q's own cell always answers for q
    best = np.argmin(score, axis=1)
    has = np.isfinite(score[np.arange(P), best])
    q = np.flatnonzero(has)
    answer_pose = grasp_pose[g][best[q]]  # pooled pose whose grasps answer for q
    # (q, j) for every grasp j of the class at the answering pose.
    match = grasp_pose[g][None, :] == answer_pose[:, None]  # (len(q), n_g)
    qq, jk = np.nonzero(match)
    q_of, j_of = q[qq], g[jk]
    # Cross with every grasp i of the class at another pose than j.
    n_g = len(g)
    ii = np.tile(g, len(j_of))
    jj = np.repeat(j_of, n_g)
    aa = np.repeat(pose_action[q_of], n_g)
    keep = grasp_pose[ii] != grasp_pose[jj]
    return ii[keep], jj[keep], aa[keep].astype(np.int64)


def edge_blocks(P: int, chunk_edges: int) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:
    """The all-pairs edges p -> q (q != p, ascending; CSR by p) in blocks of source poses of
    about `chunk_edges` edges each: (first edge id, end edge id, sources, targets)."""
    for b in np.array_split(np.arange(P), max(1, P * (P - 1) // chunk_edges)):
        src = np.repeat(b, P - 1)
        off = np.tile(np.arange(P - 1), len(b))
        yield int(b[0]) * (P - 1), (int(b[-1]) + 1) * (P - 1), src, off + (off >= src)


def rank_edge_codes(
    P: int,
    code_of: Callable[[np.ndarray, np.ndarray], np.ndarray],
    chunk_edges: int,
    dtype: type,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(edge_action, edge_target, distinct codes ascending) of the all-pairs edges of P >= 2
    poses, where an edge's action is the rank of its int64 code `code_of(sources, targets)`
    among all edges' distinct codes. A block at a time (`edge_blocks`): each block's edges get
    block-local ids, then mapped to the global ranks, so no pass holds every edge's code."""
    E = P * (P - 1)
    edge_action = np.empty(E, dtype=dtype)
    edge_target = np.empty(E, dtype=dtype)
    local: list[tuple[int, int, np.ndarray]] = []
    for a, z, src, dst in edge_blocks(P, chunk_edges):
        u, inv = np.unique(code_of(src, dst), return_inverse=True)
        edge_action[a:z], edge_target[a:z] = inv, dst
        local.append((a, z, u))
    every = np.sort(np.concatenate([u for *_, u in local]))
    uniq = every[np.concatenate([[True], every[1:] != every[:-1]])]
    del every
    for a, z, u in local:
        edge_action[a:z] = np.searchsorted(uniq, u).astype(dtype)[edge_action[a:z]]
    return edge_action, edge_target, uniq


def _all_pairs_edges(
    pooled: np.ndarray,
    tcell: float,
    qcell: float,
    absolute_keys: tuple[np.ndarray, np.ndarray] | None = None,
    chunk_edges: int = 1_000_000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Every ordered pair p -> q of pooled poses (q ascending, p skipped): (edge_action,
    edge_target, action keys (A, 7), action_cost, edge_cost, longest translation).

    Built a block of source poses at a time (`edge_blocks`), so no pass holds every pair's
    relative pose (E x 7 doubles: 1.4 GB at 5000 poses). Relative actions are the pairs'
    discretised keys, ranked as `encode_rows` ranks them (lexicographically); `absolute_keys`
    (pooled poses' keys, each pose's action) makes the action of p -> q q's own. A cost is
    accumulated in edge order, as one `bincount` over all edges would, so the model is the same
    to the bit whatever the block size. `edge_cost` (the exact move's c_m) only for absolute
    actions."""
    P = len(pooled)
    E = P * (P - 1)
    dtype = edge_index_dtype(E, E)
    if P < 2:
        keys = absolute_keys[0] if absolute_keys is not None else empty_i64(0, 7)
        none = empty_i64().astype(dtype)
        return none, none, keys, np.zeros(len(keys)), np.zeros(0), 0.0

    def rel(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
        return relative_pose(pooled[src], pooled[dst])

    # Pass 1: the longest translation (c_m's normaliser) and each key column's range.
    max_t = 0.0
    lo = np.full(7, np.iinfo(np.int64).max)
    hi = np.full(7, np.iinfo(np.int64).min)
    for _, _, src, dst in edge_blocks(P, chunk_edges):
        d = rel(src, dst)
        max_t = max(max_t, float(np.linalg.norm(d[:, :3], axis=1).max()))
        if absolute_keys is None:
            k = pose_keys(d, tcell, qcell)
            lo, hi = np.minimum(lo, k.min(axis=0)), np.maximum(hi, k.max(axis=0))
    # Pass 2: each edge's action id and target.
    span = np.maximum(hi - lo + 1, 1)
    if absolute_keys is not None:
        akeys, pose_action = absolute_keys
        edge_action = np.empty(E, dtype=dtype)
        edge_target = np.empty(E, dtype=dtype)
        for a, z, _, dst in edge_blocks(P, chunk_edges):
            edge_action[a:z], edge_target[a:z] = pose_action[dst], dst
    elif np.sum(np.log2(span.astype(np.float64))) >= 62:  # keys too wide for one int64 code
        blocks = list(edge_blocks(P, chunk_edges))
        akeys, _, ids = encode_rows(
            np.concatenate([pose_keys(rel(src, dst), tcell, qcell) for *_, src, dst in blocks])
        )
        edge_action = ids.astype(dtype)
        edge_target = np.concatenate([dst for *_, dst in blocks]).astype(dtype)
    else:
        # A mixed-radix code over the global ranges keeps the rows' lexicographic order.
        def code_of(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
            code = np.zeros(len(src), dtype=np.int64)
            for k, l0, sp in zip(pose_keys(rel(src, dst), tcell, qcell).T, lo, span, strict=True):
                code = code * sp + (k - l0)
            return code

        edge_action, edge_target, uniq = rank_edge_codes(P, code_of, chunk_edges, dtype)
        akeys = np.empty((len(uniq), 7), dtype=np.int64)
        rest = uniq.copy()
        for col in range(6, -1, -1):
            akeys[:, col] = rest % span[col] + lo[col]
            rest //= span[col]
    # Pass 3: costs, accumulated in edge order.
    A = len(akeys)
    sums = np.zeros(A)
    edge_cost = np.empty(E) if absolute_keys is not None else np.zeros(0)
    for a, z, src, dst in edge_blocks(P, chunk_edges):
        cost = movement_cost(rel(src, dst), max_t)
        np.add.at(sums, edge_action[a:z], cost)
        if absolute_keys is not None:
            edge_cost[a:z] = cost
    n_in = np.bincount(edge_action, minlength=A)
    return edge_action, edge_target, akeys, sums / np.maximum(n_in, 1), edge_cost, max_t


def _drop_empty(
    ptr: np.ndarray, outs: np.ndarray, cum: np.ndarray, keys: np.ndarray, keep: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    lens = np.diff(ptr)[keep]
    new_ptr = np.zeros(len(lens) + 1, dtype=np.int64)
    np.cumsum(lens, out=new_ptr[1:])
    return new_ptr, outs, cum, keys[keep]  # empty rows own no entries, so data stays as is


def concat_csr_rows(
    keys: Sequence[np.ndarray],
    ptrs: Sequence[np.ndarray],
    outs: Sequence[np.ndarray],
    cums: Sequence[np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One CSR row table (keys, ptr, outcomes, cumulative probabilities) from several."""
    if not keys:
        return empty_i64(), np.zeros(1, dtype=np.int64), empty_i64(), np.zeros(0)
    shifts = np.cumsum([0] + [p[-1] for p in ptrs[:-1]])
    ptr = np.concatenate([[0]] + [p[1:] + s for p, s in zip(ptrs, shifts, strict=True)])
    return (
        np.concatenate(keys).astype(np.int64),
        ptr.astype(np.int64),
        np.concatenate(outs).astype(np.int64),
        np.concatenate(cums).astype(np.float64),
    )
