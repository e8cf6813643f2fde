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

The compiled simulation loop, its tree layout and its random draws are in `mcts_kernels.py`;
this module holds the tree's storage, the search object the policies call and the path pick.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from activetouch.errors import PlanningError, PlanningInterruptedError
from activetouch.planning.mcts_kernels import (
    OBJECTIVE_CODES,
    ModelArrays,
    extract_path,
    run_simulations,
)
from activetouch.planning.observation_model import ObservationModel
from activetouch.planning.simulated_belief import (
    BeliefTable,
    bayes_kernel_tuple,
    kernel_tuple,
)
from activetouch.recognition.kernels import ClassifierKernel


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
        n_nodes, n_recs, done = run_simulations(
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
        k = int(extract_path(np.int64(horizon), nodes, recs, path)) if done else 0
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
