"""The tree search's compiled simulation loop (`mcts.py` holds the Python side).

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

from typing import NamedTuple

import numpy as np
from numba import njit

from activetouch.planning.simulated_belief import (
    norm_entropy,
    pmax,
    proba_scores,
    scores_add,
    scores_init,
)

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
def run_simulations(
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
def extract_path(horizon: int, nodes: tuple, recs: tuple, out_recs: np.ndarray) -> int:
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
