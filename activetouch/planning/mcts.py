"""Monte Carlo tree search over wrist poses (Zhang et al. IROS 2017, Sec. IV, Algs. 2-4).

One tree search (Alg. 3 run `simulations` times from a fresh root, then Alg. 2's path pick):

- **Selection** (Eq. 3): at a node, an action edge never followed from it is taken first
  (uniformly among them); once every edge has been followed, UCT
  ``argmax_a Q_a + c sqrt(2 ln N / N_a)`` with ``Q_a = 1 - C_a`` the running-mean reward and
  ``N = sum_a N_a``.
- **Next observation** (Eq. 4): ``z' ~ sum_y p(z' | z, a, y) p(y | h_t)``: a class is drawn
  from ``p(y | h_t)`` restricted to the classes that have a tally row for (y, a, z); with none,
  the classes with a marginal row for (y, a); with none of those either the step observes
  nothing (the histogram is unchanged and the next step has no conditioning cell). Then an
  outcome is drawn from that row and its bins are added to the simulated histogram. Option
  ``planner.belief_temperature`` tau draws the class from p(y | h_t)^(1/tau) instead (1: Eq. 4).
- **Expansion**: one new node per simulation at most; the tree policy stops there.
- **Rollout**: uniformly random unvisited edges down to depth T (a temporary path, not stored).
- **Cost** (Eq. 1): ``C = lam / T * sum_t c_m(a_t) + (1 - lam) * (1 - max_y p(y | h_T))`` with
  ``p`` the classifier kernel on the simulated histogram counts; reward ``r = 1 - C``.
  ``c_m`` is the model's ``edge_cost`` of the step's edge: the paper's c_m(a) of its action for
  relative actions, the cost of the move itself for absolute ones. Option ``anytime``
  (`planner.objective`) replaces ``1 - max_y p(y | h_T)`` by its mean over ``h_1 .. h_T``.
  Option ``info_gain`` replaces it by the mean over ``h_1 .. h_T`` of the normalised entropy
  ``H(p(y | h_t)) / log K``: a constant (the root's entropy) minus the information the path
  gains per step, so the running-mean backup over Eq. 4's sampled observations makes Q the
  expected entropy reduction of p(y | h) per step (the paper's future work), shifted.
  Confidence (max p) only counts the top class; entropy also rewards ruling out the runners-up,
  which is what separates look-alikes.
- **Backup**: every edge on the stored path gets ``N_a += 1, Q_a += (r - Q_a) / N_a``. Like the
  paper ("C_{t_a} is C_T(pi)"), every depth stores the whole path's reward, so the value of
  an edge deep in the tree estimates the cost of the full root-to-leaf path.
- **No pose twice**: an edge whose target pose was already executed (the root is given
  them) or lies earlier on the simulated path is never taken.
- **Path extraction**: from the root follow the highest-Q edge (ties: more visits), then its
  most visited outcome child, until a leaf or depth T.

Node identity. An edge is a transition of the model (action a, target pose), so a child is
keyed by (edge, outcome cell): the paper's nodes are observations under an action edge and
observations are stochastic, so one edge can have several children, one per cell the
sampled observation left behind (cell -1: nothing observed). A node therefore fixes its pose,
its cell and its ancestry (hence the set of poses it may not revisit), but not the exact
histogram: outcomes with equal cells share a node, and each simulation keeps its own
histogram by adding its sampled outcomes along the path (and removing them afterwards).

Layout. The tree is a structure of preallocated arrays sized from the simulation budget:
at most one node and one edge record are created per simulation (an edge record is created
only when an untried edge is taken, whose child then cannot exist yet). Edge records of a node
form a singly linked list (``rec_next``), as do the children of an edge record
(``rec_child`` / ``node_sibling``), so memory grows with simulations, not with the ~1000
edges per pose. The simulation loop is one numba function (``cache=True``); its random draws
come from numba's own generator, seeded inside the compiled code with a value drawn from the
caller's ``numpy.random.Generator`` — equal generator states give equal trees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from activetouch.errors import PlanningError, PlanningInterruptedError
from activetouch.planning.observation_model import ObservationModel
from activetouch.planning.simulated_belief import (
    BeliefTable,
    bayes_kernel_tuple,
    kernel_tuple,
    norm_entropy,
    pmax,
    proba_scores,
    scores_add,
    scores_init,
)
from activetouch.recognition.kernels import ClassifierKernel

# Draws before a uniform pick among the remaining edges falls back to a full scan.
_REJECTION_TRIES = 32

# The recognition term of Eq. 1 (`planner.objective`), as the compiled loop takes it.
OBJECTIVE_CODES = {"final": 0, "anytime": 1, "info_gain": 2}
_FINAL, _ANYTIME, _INFO_GAIN = 0, 1, 2


class ModelArrays(NamedTuple):
    """The observation model as the compiled code reads it, by field name (numba lays a
    NamedTuple out like a plain tuple, so names cost nothing at run time). `model_arrays`
    builds it."""

    edge_ptr: np.ndarray  # (P + 1,) int64: pose p's edges are edge_ptr[p] .. edge_ptr[p + 1]
    edge_action: np.ndarray  # (E,) int32 (int64 for a model too large for int32)
    edge_target: np.ndarray  # (E,) likewise
    edge_cost: np.ndarray  # (E,) float64 c_m per edge; empty: the action's (`action_cost`)
    out_cell: np.ndarray  # (O,) int64 conditioning cell each outcome leaves
    out_ptr: np.ndarray  # (O + 1,) int64 into out_bin
    out_bin: np.ndarray  # int64 histogram bin of each outcome's triangles
    # Eq. 4 looks rows up by (action, cell, class) and (action, class): the model's keys
    # re-keyed so (`rows_by_action`), ascending int64, with the row each points to.
    tally_key: np.ndarray
    tally_row: np.ndarray
    tally_ptr: np.ndarray
    tally_out: np.ndarray
    tally_cum: np.ndarray
    marg_key: np.ndarray
    marg_row: np.ndarray
    marg_ptr: np.ndarray
    marg_out: np.ndarray
    marg_cum: np.ndarray
    n_cells: np.int64
    action_cost: np.ndarray  # (A,) float64


# --------------------------------------------------------------------------------------------
# Compiled pieces
# --------------------------------------------------------------------------------------------


@njit(cache=True)
def seed_numba(seed: int) -> None:
    """Seed numba's generator (separate from numpy's global one); for tests of the pieces."""
    np.random.seed(seed)


@njit(cache=True)
def _lower_bound(keys: np.ndarray, key: int) -> int:
    """First index whose key is >= `key` (keys ascending)."""
    lo = 0
    hi = keys.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _find_key(keys: np.ndarray, key: int) -> int:
    """Index of `key` in the ascending array `keys`, or -1."""
    lo = _lower_bound(keys, key)
    if lo < keys.shape[0] and keys[lo] == key:
        return lo
    return -1


@njit(cache=True)
def _draw_in_row(ptr: np.ndarray, out: np.ndarray, cum: np.ndarray, row: int) -> int:
    """An outcome from one tally row: the first entry whose cumulative probability exceeds u."""
    s = ptr[row]
    e = ptr[row + 1]
    u = np.random.random()
    lo = s
    hi = e - 1  # the last entry catches u at (or rounding above) the row's end
    while lo < hi:
        mid = (lo + hi) >> 1
        if cum[mid] > u:
            hi = mid
        else:
            lo = mid + 1
    return out[lo]


@njit(cache=True)
def _class_span(keys: np.ndarray, base: int, n_classes: int) -> tuple:
    """[lo, hi) of the entries coded base + y (y < n_classes) in keys re-keyed by class
    (`ObservationModel.rows_by_action`): the classes that have a row, in class order."""
    lo = _lower_bound(keys, base)
    hi = lo
    end = base + n_classes
    while hi < keys.shape[0] and keys[hi] < end:
        hi += 1
    return lo, hi


@njit(cache=True)
def _tempered(p: np.ndarray, inv_temp: float) -> np.ndarray:
    """p^inv_temp normalised (p itself when inv_temp is 1): with a belief temperature above 1
    Eq. 4 imagines the runners-up's observations more often than p(y|h) says, so a path
    that would test the leading class against them is not scored as learning nothing."""
    if inv_temp == 1.0:
        return p
    q = np.empty_like(p)
    total = 0.0
    for k in range(p.shape[0]):
        q[k] = p[k] ** inv_temp
        total += q[k]
    if total <= 0.0:
        return p
    for k in range(p.shape[0]):
        q[k] /= total
    return q


@njit(cache=True)
def _sample_outcome(
    m: ModelArrays,
    kern: tuple,
    action: int,
    cell: int,
    hist: np.ndarray,
    S: np.ndarray,
    counters: np.ndarray,
    per_class: bool,
    inv_temp: float = 1.0,
) -> int:
    """Eq. 4: an outcome id for taking `action` from conditioning `cell` (-1: none), or -1.

    `per_class` False: y is drawn among the classes that have data for (a, cell) (else for a
    alone), renormalising p(y|h) over them. True: y is drawn from the full p(y|h); that class
    answers from its (a, cell) row, else its (a) row, else with nothing observed — so a class
    without data cannot make another class's observation look certain.
    `inv_temp`: 1 / planner.belief_temperature; below 1 the class is drawn from a flattened
    p(y|h)^inv_temp (see `_tempered`)."""
    tkey, tally_ptr, tally_out, tally_cum = m.tally_key, m.tally_ptr, m.tally_out, m.tally_cum
    mkey, marg_ptr, marg_out, marg_cum = m.marg_key, m.marg_ptr, m.marg_out, m.marg_cum
    n_cells = m.n_cells
    trow, mrow = m.tally_row, m.marg_row
    n_classes = kern[7]
    if per_class:
        p = _tempered(proba_scores(kern, hist, S), inv_temp)
        u = np.random.random()
        acc = 0.0
        y = n_classes - 1
        for k in range(n_classes):
            acc += p[k]
            if u < acc:
                y = k
                break
        if 0 <= cell < n_cells:
            i = _find_key(tkey, (action * n_cells + cell) * n_classes + y)
            if i >= 0:
                counters[0] += 1
                return _draw_in_row(tally_ptr, tally_out, tally_cum, trow[i])
        i = _find_key(mkey, action * n_classes + y)
        if i >= 0:
            counters[1] += 1
            return _draw_in_row(marg_ptr, marg_out, marg_cum, mrow[i])
        counters[2] += 1
        return -1
    lo = 0
    hi = 0
    use_marg = False
    base = 0
    if 0 <= cell < n_cells:
        base = (action * n_cells + cell) * n_classes
        lo, hi = _class_span(tkey, base, n_classes)
    if hi == lo:
        use_marg = True
        base = action * n_classes
        lo, hi = _class_span(mkey, base, n_classes)
    found = hi - lo
    if found == 0:
        counters[2] += 1
        return -1
    counters[1 if use_marg else 0] += 1
    keys = mkey if use_marg else tkey
    sel = lo
    if found > 1:
        # p(y | h_t) only matters when several classes could have produced the observation.
        p = _tempered(proba_scores(kern, hist, S), inv_temp)
        total = 0.0
        for i in range(lo, hi):
            total += p[keys[i] - base]
        if total > 0.0:
            u = np.random.random() * total
            acc = 0.0
            for i in range(lo, hi):
                acc += p[keys[i] - base]
                sel = i
                if u < acc:
                    break
        else:  # every candidate class has zero probability: treat them alike
            sel = lo + np.random.randint(0, found)
    if use_marg:
        return _draw_in_row(marg_ptr, marg_out, marg_cum, mrow[sel])
    return _draw_in_row(tally_ptr, tally_out, tally_cum, trow[sel])


@njit(cache=True)
def _observe(
    m: ModelArrays,
    kern: tuple,
    action: int,
    cell: int,
    hist: np.ndarray,
    S: np.ndarray,
    counters: np.ndarray,
    per_class: bool,
    inv_temp: float,
) -> tuple:
    """One simulated observation (Eq. 4) added to the histogram and its scores; returns the
    outcome (-1: nothing observed) and the cell it leaves (-1 then too)."""
    o = _sample_outcome(m, kern, action, cell, hist, S, counters, per_class, inv_temp)
    if o < 0:
        return o, -1
    scores_add(kern, m.out_ptr, m.out_bin, o, hist, S)
    return o, m.out_cell[o]


@njit(cache=True)
def _add_outcome(out_ptr: np.ndarray, out_bin: np.ndarray, o: int, hist: np.ndarray, sign: float):
    for i in range(out_ptr[o], out_ptr[o + 1]):
        hist[out_bin[i]] += sign


@njit(cache=True)
def _random_edge(edge_ptr: np.ndarray, edge_target: np.ndarray, pose: int, used: np.ndarray) -> int:
    """A uniformly random edge out of `pose` whose target is not used, or -1."""
    base = edge_ptr[pose]
    deg = edge_ptr[pose + 1] - base
    if deg == 0:
        return -1
    for _ in range(_REJECTION_TRIES):
        e = base + np.random.randint(0, deg)
        if not used[edge_target[e]]:
            return e
    n_ok = 0
    for e in range(base, base + deg):
        if not used[edge_target[e]]:
            n_ok += 1
    if n_ok == 0:
        return -1
    k = np.random.randint(0, n_ok)
    for e in range(base, base + deg):
        if not used[edge_target[e]]:
            if k == 0:
                return e
            k -= 1
    return -1


@njit(cache=True)
def _select(
    node: int,
    edge_ptr: np.ndarray,
    edge_target: np.ndarray,
    used: np.ndarray,
    c: float,
    nodes: tuple,
    recs: tuple,
    n_recs: np.ndarray,
    mark: np.ndarray,
) -> int:
    """Edge record to follow from `node` (created if the edge is new), or -1 if none is left."""
    node_pose, _nd, _nc, _nin, _nsib, node_first, node_sel, _nvis, node_full = nodes
    rec_node, rec_edge, rec_n, rec_q, rec_next, rec_child = recs
    pose = node_pose[node]
    base = edge_ptr[pose]
    deg = edge_ptr[pose + 1] - base
    if deg == 0:
        node_full[node] = True
    if not node_full[node]:
        # Unvisited edges first: mark the tried ones, draw uniformly among the others.
        r = node_first[node]
        while r >= 0:
            mark[rec_edge[r] - base] = True
            r = rec_next[r]
        pick = -1
        for _ in range(_REJECTION_TRIES):
            j = np.random.randint(0, deg)
            if not mark[j] and not used[edge_target[base + j]]:
                pick = j
                break
        if pick < 0:
            n_ok = 0
            for j in range(deg):
                if not mark[j] and not used[edge_target[base + j]]:
                    n_ok += 1
            if n_ok > 0:
                k = np.random.randint(0, n_ok)
                for j in range(deg):
                    if not mark[j] and not used[edge_target[base + j]]:
                        if k == 0:
                            pick = j
                            break
                        k -= 1
        r = node_first[node]
        while r >= 0:
            mark[rec_edge[r] - base] = False
            r = rec_next[r]
        if pick >= 0:
            nr = n_recs[0]
            n_recs[0] = nr + 1
            rec_node[nr] = node
            rec_edge[nr] = base + pick
            rec_n[nr] = 0
            rec_q[nr] = 0.0
            rec_child[nr] = -1
            rec_next[nr] = node_first[node]
            node_first[node] = nr
            return nr
        node_full[node] = True
    # UCT (Eq. 3) over the edges already followed.
    best = -1
    best_v = -np.inf
    log_n = np.log(max(node_sel[node], 1))
    r = node_first[node]
    while r >= 0:
        v = rec_q[r] + c * np.sqrt(2.0 * log_n / rec_n[r])
        if v > best_v:
            best_v = v
            best = r
        r = rec_next[r]
    return best


@njit(cache=True)
def _edge_cost(edge_cost: np.ndarray, action_cost: np.ndarray, a: int, e: int) -> float:
    """c_m of edge e (action a): per edge when given, else the action's (not stored per edge)."""
    if edge_cost.shape[0] > 0:
        return edge_cost[e]
    return action_cost[a]


@njit(cache=True)
def _unsure(kern: tuple, hist: np.ndarray, S: np.ndarray, objective: int) -> float:
    """The per-step recognition term: 1 - max p(y | h), or H(p(y | h)) / log K."""
    p = proba_scores(kern, hist, S)
    if objective == _INFO_GAIN:
        return norm_entropy(p)
    return 1.0 - pmax(p)


@njit(cache=True)
def _step_unsure(
    kern: tuple, hist: np.ndarray, S: np.ndarray, o: int, last: float, objective: int
) -> float:
    """The recognition term after a step; a step that observed nothing leaves it as it was."""
    if o < 0:
        return last
    return _unsure(kern, hist, S, objective)


# nogil: a long search must not freeze the daemon's other threads (e-stop, status, signals).
@njit(cache=True, nogil=True)
def _run_simulations(
    m: ModelArrays,
    kern: tuple,
    root_pose: int,
    used: np.ndarray,
    hist: np.ndarray,
    root_cells: np.ndarray,
    horizon: int,
    n_sims: int,
    c: float,
    lam: float,
    per_class: bool,
    objective: int,
    inv_temp: float,
    seed: int,
    nodes: tuple,
    recs: tuple,
    mark: np.ndarray,
    counters: np.ndarray,
    stop: np.ndarray,
) -> tuple:
    """Run the simulations; returns (nodes used, edge records used, simulations run). `used`
    and `hist` are modified during a simulation and restored after it. Another thread may
    set `stop[0]` (the search runs without the GIL): the search ends after the simulation
    it is in. `objective`: `OBJECTIVE_CODES` (final, anytime, info_gain)."""
    edge_ptr, edge_action, edge_target = m.edge_ptr, m.edge_action, m.edge_target
    edge_cost, action_cost = m.edge_cost, m.action_cost
    out_ptr, out_bin = m.out_ptr, m.out_bin
    (
        node_pose,
        node_depth,
        node_cell,
        node_in,
        node_sibling,
        node_first,
        node_sel,
        node_vis,
        node_full,
    ) = nodes
    rec_node, rec_edge, rec_n, rec_q, _rec_next, rec_child = recs
    np.random.seed(seed)
    M = kern[1].shape[0]
    S0 = np.empty(M + 2)
    scores_init(kern, hist, S0)
    S = S0.copy()
    per_step = objective != _FINAL  # anytime and info_gain average a term over the path
    unsure0 = _unsure(kern, hist, S0, objective) if per_step else 0.0
    path_recs = np.empty(horizon, dtype=np.int64)
    path_pose = np.empty(horizon, dtype=np.int64)
    path_out = np.empty(horizon, dtype=np.int64)
    n_recs = np.zeros(1, dtype=np.int64)

    node_pose[0] = root_pose
    node_depth[0] = 0
    node_cell[0] = -1
    node_in[0] = -1
    node_sibling[0] = -1
    node_first[0] = -1
    node_sel[0] = 0
    node_vis[0] = 0
    node_full[0] = False
    n_nodes = 1

    done = 0
    for _sim in range(n_sims):
        if stop[0] != 0:
            break
        done += 1
        node = 0
        node_vis[0] += 1
        depth = 0
        n_tree = 0
        pose = root_pose
        cell = (
            root_cells[np.random.randint(0, root_cells.shape[0])] if root_cells.shape[0] > 0 else -1
        )
        move = 0.0
        last = unsure0  # per-step objectives: the recognition term after each step, summed
        unsure = 0.0
        # Tree policy (Alg. 4) until a node is created, depth T, or no edge is left.
        while depth < horizon:
            rec = _select(node, edge_ptr, edge_target, used, c, nodes, recs, n_recs, mark)
            if rec < 0:
                break
            e = rec_edge[rec]
            a = edge_action[e]
            move += _edge_cost(edge_cost, action_cost, a, e)
            o, cell = _observe(m, kern, a, cell, hist, S, counters, per_class, inv_temp)
            if per_step:
                last = _step_unsure(kern, hist, S, o, last, objective)
                unsure += last
            pose = edge_target[e]
            used[pose] = True
            path_pose[depth] = pose
            path_out[depth] = o
            path_recs[n_tree] = rec
            n_tree += 1
            depth += 1
            child = rec_child[rec]
            while child >= 0 and node_cell[child] != cell:
                child = node_sibling[child]
            if child < 0:
                child = n_nodes
                n_nodes += 1
                node_pose[child] = pose
                node_depth[child] = depth
                node_cell[child] = cell
                node_in[child] = rec
                node_sibling[child] = rec_child[rec]
                rec_child[rec] = child
                node_first[child] = -1
                node_sel[child] = 0
                node_vis[child] = 1
                node_full[child] = False
                node = child
                break
            node = child
            node_vis[child] += 1
        # Rollout: random unvisited poses down to depth T.
        while depth < horizon:
            e = _random_edge(edge_ptr, edge_target, pose, used)
            if e < 0:
                break
            a = edge_action[e]
            move += _edge_cost(edge_cost, action_cost, a, e)
            o, cell = _observe(m, kern, a, cell, hist, S, counters, per_class, inv_temp)
            if per_step:
                last = _step_unsure(kern, hist, S, o, last, objective)
                unsure += last
            pose = edge_target[e]
            used[pose] = True
            path_pose[depth] = pose
            path_out[depth] = o
            depth += 1
        if per_step:
            # Steps the path could not take (no pose left) keep the last value.
            unsure += (horizon - depth) * last
            reward = 1.0 - (lam * move + (1.0 - lam) * unsure) / horizon
        else:
            # Eq. 1 on the simulated histogram h_T.
            top = pmax(proba_scores(kern, hist, S))
            reward = 1.0 - (lam / horizon * move + (1.0 - lam) * (1.0 - top))
        # Backup: running mean of the whole path's reward at every stored edge.
        for i in range(n_tree):
            rec = path_recs[i]
            rec_n[rec] += 1
            rec_q[rec] += (reward - rec_q[rec]) / rec_n[rec]
            node_sel[rec_node[rec]] += 1
        # Undo this simulation's poses and observations.
        for i in range(depth):
            used[path_pose[i]] = False
            if path_out[i] >= 0:
                _add_outcome(out_ptr, out_bin, path_out[i], hist, -1.0)
        S[:] = S0
    return n_nodes, n_recs[0], done


@njit(cache=True, nogil=True)
def _extract_path(horizon: int, nodes: tuple, recs: tuple, out_recs: np.ndarray) -> int:
    """Max-reward root-to-leaf path: edge records into `out_recs`; returns its length."""
    _np, _nd, _nc, _ni, node_sibling, node_first, _ns, node_vis, _nf = nodes
    _rn, _re, rec_n, rec_q, rec_next, rec_child = recs
    node = 0
    k = 0
    while k < horizon:
        best = -1
        r = node_first[node]
        while r >= 0:
            if rec_n[r] > 0 and (
                best < 0
                or rec_q[r] > rec_q[best]
                or (rec_q[r] == rec_q[best] and rec_n[r] > rec_n[best])
            ):
                best = r
            r = rec_next[r]
        if best < 0:
            break
        out_recs[k] = best
        k += 1
        child = rec_child[best]
        nxt = child
        while child >= 0:
            if node_vis[child] > node_vis[nxt]:
                nxt = child
            child = node_sibling[child]
        if nxt < 0:
            break
        node = nxt
    return k


# --------------------------------------------------------------------------------------------
# Python side
# --------------------------------------------------------------------------------------------


@dataclass
class Tree:
    """Structure-of-arrays storage for one search; `capacity` simulations fit."""

    capacity: int
    max_degree: int
    # Nodes (capacity + 1): pose, depth, cell (-1 none), incoming edge record, next sibling
    # under the same edge record, first outgoing edge record, selections made from the node
    # (N in Eq. 3), visits, and whether every edge has been tried.
    node_pose: np.ndarray
    node_depth: np.ndarray
    node_cell: np.ndarray
    node_in: np.ndarray
    node_sibling: np.ndarray
    node_first: np.ndarray
    node_sel: np.ndarray
    node_vis: np.ndarray
    node_full: np.ndarray
    # Edge records (capacity): owning node, model edge id, N_a, Q_a, next record of the same
    # node, first child node.
    rec_node: np.ndarray
    rec_edge: np.ndarray
    rec_n: np.ndarray
    rec_q: np.ndarray
    rec_next: np.ndarray
    rec_child: np.ndarray
    mark: np.ndarray  # (max_degree,) scratch: tried edges of the node being expanded

    @classmethod
    def allocate(cls, capacity: int, max_degree: int) -> Tree:
        n = capacity + 1
        i64 = np.int64
        return cls(
            capacity=capacity,
            max_degree=max_degree,
            node_pose=np.empty(n, i64),
            node_depth=np.empty(n, i64),
            node_cell=np.empty(n, i64),
            node_in=np.empty(n, i64),
            node_sibling=np.empty(n, i64),
            node_first=np.empty(n, i64),
            node_sel=np.empty(n, i64),
            node_vis=np.empty(n, i64),
            node_full=np.empty(n, np.bool_),
            rec_node=np.empty(capacity, i64),
            rec_edge=np.empty(capacity, i64),
            rec_n=np.empty(capacity, i64),
            rec_q=np.empty(capacity, np.float64),
            rec_next=np.empty(capacity, i64),
            rec_child=np.empty(capacity, i64),
            mark=np.zeros(max(max_degree, 1), np.bool_),
        )

    def node_arrays(self) -> tuple:
        return (
            self.node_pose,
            self.node_depth,
            self.node_cell,
            self.node_in,
            self.node_sibling,
            self.node_first,
            self.node_sel,
            self.node_vis,
            self.node_full,
        )

    def rec_arrays(self) -> tuple:
        return (self.rec_node, self.rec_edge, self.rec_n, self.rec_q, self.rec_next, self.rec_child)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (*self.node_arrays(), *self.rec_arrays(), self.mark))


@dataclass(frozen=True)
class SearchResult:
    """A tree search's answer. `exhausted`: no unvisited pose was reachable from the root
    (then the path is empty and `value` is nan)."""

    exhausted: bool
    poses: np.ndarray  # (n,) int64 target pose ids, in execution order, n <= horizon
    actions: np.ndarray  # (n,) int64 action ids
    edges: np.ndarray  # (n,) int64 model edge ids
    value: float  # backed-up reward 1 - C of the path: Q of its deepest edge
    step_values: np.ndarray  # (n,) Q of each edge on the path
    step_visits: np.ndarray  # (n,) N_a of each edge on the path
    n_nodes: int
    n_edge_records: int
    simulations: int
    # Eq. 4 steps resolved by a (y, a, z) tally row, by a (y, a) marginal row, by neither.
    observation_sources: tuple[int, int, int]
    tree: Tree | None = None

    @property
    def cost(self) -> float:
        return 1.0 - self.value


def model_arrays(model: ObservationModel) -> ModelArrays:
    """The observation model as the compiled code takes it (no copies of the model's arrays
    when they already have the compiled code's dtypes)."""

    def i32(a: np.ndarray) -> np.ndarray:
        # One compiled variant for every model: edges in int32 (int64 ones, from models saved
        # before, are converted; a model too large for int32 keeps its own).
        if a.dtype == np.int64 and len(a) < 2**31 - 1 and (len(a) == 0 or a.max() < 2**31 - 1):
            return np.ascontiguousarray(a, dtype=np.int32)
        return np.ascontiguousarray(a)

    def i64(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.int64)

    def f64(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.float64)

    tkey, trow, mkey, mrow = model.rows_by_action
    return ModelArrays(
        edge_ptr=i64(model.edge_ptr),
        edge_action=i32(model.edge_action),
        edge_target=i32(model.edge_target),
        edge_cost=f64(model.edge_cost),
        out_cell=i64(model.out_cell),
        out_ptr=i64(model.out_ptr),
        out_bin=i64(model.out_bin),
        tally_key=tkey,
        tally_row=trow,
        tally_ptr=i64(model.tally_ptr),
        tally_out=i64(model.tally_out),
        tally_cum=f64(model.tally_cum),
        marg_key=mkey,
        marg_row=mrow,
        marg_ptr=i64(model.marg_ptr),
        marg_out=i64(model.marg_out),
        marg_cum=f64(model.marg_cum),
        n_cells=np.int64(model.n_cells),
        action_cost=f64(model.action_cost),
    )


def unvisited_targets(model: ObservationModel, pose: int, visited: np.ndarray) -> np.ndarray:
    """Edge ids out of `pose` whose target is neither `pose` nor in `visited`."""
    visited = np.asarray(visited, dtype=np.int64).reshape(-1)
    if not 0 <= pose < model.n_poses:
        raise PlanningError(f"pose id {pose} outside the model's {model.n_poses} poses")
    if visited.size and (visited.min() < 0 or visited.max() >= model.n_poses):
        raise PlanningError(f"visited pose ids must lie in [0, {model.n_poses})")
    lo, hi = int(model.edge_ptr[pose]), int(model.edge_ptr[pose + 1])
    targets = model.edge_target[lo:hi]
    bad = np.zeros(model.n_poses, dtype=bool)
    bad[visited] = True
    bad[pose] = True
    return lo + np.flatnonzero(~bad[targets])


class TreeSearch:
    """The planner's search, bound to one observation model and classifier kernel.

    Converts the arrays once and keeps the tree storage between searches (it grows when a
    larger simulation budget is asked for), so repeated planning allocates nothing new. A
    result's `tree` (keep_tree=True) is therefore overwritten by the next search.
    `incremental`: keep linear classifier scores per added triangle (see `scores_add`)."""

    def __init__(
        self,
        model: ObservationModel,
        kernel: ClassifierKernel,
        *,
        incremental: bool = True,
        anytime: bool = False,
        objective: str | None = None,
        belief: BeliefTable | None = None,
    ) -> None:
        """`objective`: "final" (Eq. 1, the paper), "anytime" or "info_gain" (see the module
        notes); None takes "anytime" if `anytime` else "final" (the older keyword).
        `belief`: plan on the grasp-likelihood belief instead of the classifier
        (`KIND_BAYES`); each search then takes the real log-belief (`log_belief`)."""
        if belief is not None:
            G, K = np.shape(belief.log_lik)
            og = np.asarray(belief.outcome_grasp)
            if model.n_classes != K or og.shape != (model.n_outcomes,):
                raise PlanningError(
                    f"belief table for {K} classes and {og.shape[0]} outcomes, the observation "
                    f"model has {model.n_classes} classes and {model.n_outcomes} outcomes"
                )
            if len(og) and (og.min() < 0 or og.max() >= G):
                raise PlanningError(f"belief table: outcome grasps outside [0, {G})")
        if kernel.n_classes != model.n_classes:
            raise PlanningError(
                f"classifier has {kernel.n_classes} classes, observation model "
                f"{model.n_classes} ({', '.join(model.class_names)})"
            )
        if kernel.W.shape[1] != model.n_bins:
            raise PlanningError(
                f"classifier expects {kernel.W.shape[1]}-bin histograms, observation model "
                f"has {model.n_bins} bins"
            )
        self.model = model
        self.kernel = kernel
        objective = objective or ("anytime" if anytime else "final")
        if objective not in OBJECTIVE_CODES:
            raise PlanningError(
                f"objective must be one of {', '.join(OBJECTIVE_CODES)}, got {objective!r}"
            )
        self.objective = objective
        self.anytime = objective == "anytime"
        self._objective_code = OBJECTIVE_CODES[objective]
        self._m = model_arrays(model)
        self.bayes = belief is not None
        self._k = (
            bayes_kernel_tuple(belief) if belief is not None else kernel_tuple(kernel, incremental)
        )
        deg = np.diff(model.edge_ptr)
        self.max_degree = int(deg.max()) if deg.size else 0
        self._tree: Tree | None = None
        # Set by `interrupt()` from any thread; read by the compiled loop between simulations.
        self._stop = np.zeros(1, dtype=np.int64)

    def set_edge_cost(self, cost: np.ndarray) -> None:
        """Replace the model's edge costs c_m (E,) for this search's later trees."""
        c = np.ascontiguousarray(cost, dtype=np.float64).reshape(-1)
        if c.shape != self._m.edge_action.shape:
            raise ValueError(f"edge costs must be {self._m.edge_action.shape}, got {c.shape}")
        self._m = self._m._replace(edge_cost=c)

    def interrupt(self) -> None:
        """End the running search (and any later one) after its current simulation; it returns
        the best path of what it has, or raises `PlanningInterruptedError` if it has none yet."""
        self._stop[0] = 1

    def clear_interrupt(self) -> None:
        self._stop[0] = 0

    @property
    def interrupted(self) -> bool:
        return bool(self._stop[0])

    def _tree_for(self, simulations: int) -> Tree:
        if self._tree is None or self._tree.capacity < simulations:
            self._tree = Tree.allocate(simulations, self.max_degree)
        return self._tree

    def search(
        self,
        pose: int,
        visited: np.ndarray,
        counts: np.ndarray,
        cells: np.ndarray,
        *,
        horizon: int,
        simulations: int,
        rng: np.random.Generator,
        exploration_c: float = 1.0,
        lam: float = 0.5,
        keep_tree: bool = False,
        per_class_backoff: bool = False,
        belief_temperature: float = 1.0,
        log_belief: np.ndarray | None = None,
    ) -> SearchResult:
        """Build a tree from the root (`pose`, `counts`, `cells`) and extract its best path.

        `visited`: pose ids already executed (never targets; `pose` itself is added).
        `counts`: the real histogram so far (n_bins,). `cells`: conditioning cells of the last
        real grasp (one is drawn per simulation; empty: no conditioning, marginal rows).
        `log_belief` (K,): the real summed grasp log-likelihoods, for a search made with a
        belief table (ignored otherwise)."""
        model = self.model
        kern = self._k
        if self.bayes:
            if log_belief is None:
                raise PlanningError("this search plans on the grasp belief: give log_belief")
            lb = np.ascontiguousarray(log_belief, dtype=np.float64).reshape(-1)
            if lb.shape != (model.n_classes,) or not np.all(np.isfinite(lb)):
                raise PlanningError(f"log_belief must be {model.n_classes} finite values")
            kern = (*kern[:2], lb - lb.max(), *kern[3:])
        if not 0 <= pose < model.n_poses:
            raise PlanningError(f"pose id {pose} outside the model's {model.n_poses} poses")
        if horizon < 1:
            raise PlanningError(f"planning horizon must be >= 1, got {horizon}")
        if simulations < 1:
            raise PlanningError(f"number of simulations must be >= 1, got {simulations}")
        if not belief_temperature > 0:
            raise PlanningError(f"belief temperature must be > 0, got {belief_temperature}")
        hist = np.array(counts, dtype=np.float64).reshape(-1)
        if hist.shape[0] != model.n_bins:
            raise PlanningError(
                f"histogram has {hist.shape[0]} bins, the observation model {model.n_bins}"
            )
        visited = np.asarray(visited, dtype=np.int64).reshape(-1)
        if visited.size and (visited.min() < 0 or visited.max() >= model.n_poses):
            raise PlanningError(f"visited pose ids must lie in [0, {model.n_poses})")
        cells = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1)
        seed = int(rng.integers(0, 2**31 - 1))
        empty = np.zeros(0, dtype=np.int64)
        if unvisited_targets(model, pose, visited).size == 0:
            return SearchResult(
                exhausted=True,
                poses=empty,
                actions=empty,
                edges=empty,
                value=float("nan"),
                step_values=np.zeros(0),
                step_visits=empty,
                n_nodes=0,
                n_edge_records=0,
                simulations=0,
                observation_sources=(0, 0, 0),
            )
        used = np.zeros(model.n_poses, dtype=np.bool_)
        used[visited] = True
        used[pose] = True
        tree = self._tree_for(simulations)
        nodes, recs = tree.node_arrays(), tree.rec_arrays()
        counters = np.zeros(3, dtype=np.int64)
        n_nodes, n_recs, done = _run_simulations(
            self._m,
            kern,
            np.int64(pose),
            used,
            hist,
            cells,
            np.int64(horizon),
            np.int64(simulations),
            np.float64(exploration_c),
            np.float64(lam),
            bool(per_class_backoff),
            np.int64(self._objective_code),
            np.float64(1.0 / belief_temperature),
            np.int64(seed),
            nodes,
            recs,
            tree.mark,
            counters,
            self._stop,
        )
        path = np.empty(horizon, dtype=np.int64)
        k = int(_extract_path(np.int64(horizon), nodes, recs, path)) if done else 0
        if k == 0 and self.interrupted:
            raise PlanningInterruptedError(f"planning interrupted after {done} simulations")
        path = path[:k]
        edges = tree.rec_edge[path].copy()
        step_values = tree.rec_q[path].copy()
        return SearchResult(
            exhausted=False,
            poses=model.edge_target[edges].astype(np.int64),
            actions=model.edge_action[edges].astype(np.int64),
            edges=edges,
            value=float(step_values[-1]),
            step_values=step_values,
            step_visits=tree.rec_n[path].copy(),
            n_nodes=int(n_nodes),
            n_edge_records=int(n_recs),
            simulations=int(done),
            observation_sources=(int(counters[0]), int(counters[1]), int(counters[2])),
            tree=tree if keep_tree else None,
        )


def search(
    model: ObservationModel,
    kernel: ClassifierKernel,
    pose: int,
    visited: np.ndarray,
    counts: np.ndarray,
    cells: np.ndarray,
    *,
    horizon: int,
    simulations: int,
    rng: np.random.Generator,
    exploration_c: float = 1.0,
    lam: float = 0.5,
    per_class_backoff: bool = False,
    anytime: bool = False,
    objective: str | None = None,
) -> SearchResult:
    """One-off tree search (see `TreeSearch.search`); the paper's objective by default."""
    return TreeSearch(model, kernel, anytime=anytime, objective=objective).search(
        pose,
        visited,
        counts,
        cells,
        horizon=horizon,
        simulations=simulations,
        rng=rng,
        exploration_c=exploration_c,
        lam=lam,
        per_class_backoff=per_class_backoff,
    )
