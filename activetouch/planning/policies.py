"""Where to grasp next: the tree policy (MCTS, paper Algs. 2-4) and the paper's baselines.

Every policy answers `plan(state, rng) -> Plan`: the poses to execute next, in order. The caller
executes them, adds the real observations to the state (`PlanningState.advance`) and asks again
(`run_policy` is that loop). Policies draw randomness only from the Generator passed in.

- ``tree``: a tree of `simulations` simulations with horizon T; the plan is the extracted
  max-reward path (the paper's scheme: execute the whole path, then build a new tree).
  With ``replan_every_grasp`` only the path's first pose is returned, so a new tree is built
  after every executed grasp from the real observation.
- ``greedy``: the same search with horizon 1 (the paper's baseline).
- ``random``: one pose drawn uniformly from the unvisited poses reachable from the current one
  (the model's edges join every pair of poses, so: from all unvisited poses).
- ``mesh``: one grasp ahead on the class x placement belief, each class's mesh predicting how
  far the fingers close at each pose where the object may stand (planning/mesh_lookahead.py);
  greedy decides where the meshes tell no pose apart, or without a placement belief.
"""

from __future__ import annotations

import typing
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from activetouch.config import Eq4Sampling, Objective, PlannerConfig, PolicyName
from activetouch.errors import ConfigError, PlanningError
from activetouch.planning.mcts import SearchResult, TreeSearch, unvisited_targets
from activetouch.planning.mesh_lookahead import (
    PackedShapes,
    PlacementBelief,
    pack_shapes,
    predicted_values,
)
from activetouch.planning.observation_model import ObservationModel
from activetouch.planning.simulated_belief import BeliefTable
from activetouch.recognition.kernels import ClassifierKernel


def _i64(a: object) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=np.int64).reshape(-1))


@dataclass(frozen=True)
class PlanningState:
    """What the planner knows: the current pose, the poses executed so far, the real histogram
    counts, and the cells the last real grasp left (the root's conditioning z)."""

    pose: int
    visited: np.ndarray  # (n,) int64 executed pose ids, the current one included
    counts: np.ndarray  # (n_bins,) float64 histogram counts of all real grasps so far
    cells: np.ndarray  # (m,) int64 cells of the last real grasp
    # Summed log p(grasp | y, pose) of the real grasps (K,), when recognition.belief is
    # grasp_likelihood: the root belief of a policy made with a belief table.
    log_belief: np.ndarray | None = None
    # The class x placement belief with where the next grasp goes (`recognition.belief =
    # pose`, a ReFlex model): what the mesh policy plans on.
    placement: PlacementBelief | None = None

    @classmethod
    def start(cls, pose: int, counts: np.ndarray, cells: np.ndarray) -> PlanningState:
        """The state after the first (random) grasp at `pose`."""
        return cls(
            pose=int(pose),
            visited=np.array([pose], dtype=np.int64),
            counts=np.array(counts, dtype=np.float64).reshape(-1),
            cells=_i64(cells),
        )

    def advance(self, pose: int, grasp_counts: np.ndarray, cells: np.ndarray) -> PlanningState:
        """The state after executing a grasp at `pose` that added `grasp_counts` to the
        histogram and left `cells`."""
        return PlanningState(
            pose=int(pose),
            visited=np.append(self.visited, np.int64(pose)),
            counts=self.counts + np.asarray(grasp_counts, dtype=np.float64).reshape(-1),
            cells=_i64(cells),
        )


@dataclass(frozen=True)
class Plan:
    """Poses to execute next, in order, with the action (model action id) leading to each."""

    policy: str
    poses: np.ndarray  # (n,) int64; empty when exhausted
    actions: np.ndarray  # (n,) int64
    value: float  # backed-up reward 1 - C of the extracted path (nan: random / exhausted)
    exhausted: bool = False  # no unvisited pose is reachable: recognition must stop here
    search: SearchResult | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.poses)


def _exhausted(name: str) -> Plan:
    empty = np.zeros(0, dtype=np.int64)
    return Plan(policy=name, poses=empty, actions=empty, value=float("nan"), exhausted=True)


class Policy:
    """Interface: `plan(state, rng) -> Plan`."""

    name: str = ""

    def plan(self, state: PlanningState, rng: np.random.Generator) -> Plan:
        raise NotImplementedError

    def interrupt(self) -> None:
        """End a running `plan` soon, from any thread (a policy that plans at once ignores it)."""

    def clear_interrupt(self) -> None:
        """Let later plans run to their end again."""

    # What c_m in Eq. 1 measures: "pose" (the model's own pose-difference cost, the paper's)
    # or "travel_time" (the arm's move durations, given with `set_edge_cost` by the session).
    movement_cost: str = "pose"

    def set_edge_cost(self, cost: np.ndarray) -> None:
        """Use `cost` (E,) as the model edges' c_m from now on (a policy without a movement
        term ignores it)."""


class TreePolicy(Policy):
    """MCTS with horizon `horizon` and `simulations` simulations per tree."""

    name = "tree"

    def __init__(
        self,
        model: ObservationModel,
        kernel: ClassifierKernel,
        *,
        horizon: int,
        simulations: int,
        exploration_c: float = 1.0,
        lam: float = 0.5,
        replan_every_grasp: bool = False,
        eq4_sampling: str = "renormalise",
        objective: str = "final",
        belief_temperature: float = 1.0,
        belief: BeliefTable | None = None,
    ) -> None:
        if horizon < 1:
            raise ConfigError(f"planner.horizon must be >= 1, got {horizon}")
        if simulations < 1:
            raise ConfigError(f"planner.simulations must be >= 1, got {simulations}")
        if not 0.0 <= lam <= 1.0:
            raise ConfigError(f"planner.lam must lie in [0, 1], got {lam}")
        if exploration_c < 0.0:
            raise ConfigError(f"planner.exploration_c must be >= 0, got {exploration_c}")
        if not belief_temperature > 0.0:
            raise ConfigError(f"planner.belief_temperature must be > 0, got {belief_temperature}")
        self.belief_temperature = float(belief_temperature)
        self.horizon = int(horizon)
        self.simulations = int(simulations)
        self.exploration_c = float(exploration_c)
        self.lam = float(lam)
        self.replan_every_grasp = bool(replan_every_grasp)
        if eq4_sampling not in EQ4_SAMPLING:
            raise ConfigError(
                f"planner.eq4_sampling must be one of {', '.join(EQ4_SAMPLING)}, "
                f"got {eq4_sampling!r}"
            )
        self.per_class_backoff = eq4_sampling == "per_class"
        if objective not in OBJECTIVES:
            raise ConfigError(
                f"planner.objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}"
            )
        self.search = TreeSearch(model, kernel, objective=objective, belief=belief)

    def interrupt(self) -> None:
        self.search.interrupt()

    def set_edge_cost(self, cost: np.ndarray) -> None:
        self.search.set_edge_cost(cost)

    def clear_interrupt(self) -> None:
        self.search.clear_interrupt()

    def plan(self, state: PlanningState, rng: np.random.Generator) -> Plan:
        res = self.search.search(
            state.pose,
            state.visited,
            state.counts,
            state.cells,
            horizon=self.horizon,
            simulations=self.simulations,
            rng=rng,
            exploration_c=self.exploration_c,
            lam=self.lam,
            per_class_backoff=self.per_class_backoff,
            belief_temperature=self.belief_temperature,
            log_belief=state.log_belief,
        )
        if res.exhausted:
            return _exhausted(self.name)
        n = 1 if self.replan_every_grasp else len(res.poses)
        return Plan(
            policy=self.name,
            poses=res.poses[:n],
            actions=res.actions[:n],
            value=res.value,
            search=res,
        )


class GreedyPolicy(TreePolicy):
    """The paper's greedy baseline: the same search with horizon 1."""

    name = "greedy"

    def __init__(self, model: ObservationModel, kernel: ClassifierKernel, **kw: object) -> None:
        kw["horizon"] = 1
        super().__init__(model, kernel, **kw)  # type: ignore[arg-type]


class RandomPolicy(Policy):
    """The paper's random baseline: a uniformly random unvisited pose."""

    name = "random"

    def __init__(self, model: ObservationModel) -> None:
        self.model = model

    def plan(self, state: PlanningState, rng: np.random.Generator) -> Plan:
        edges = unvisited_targets(self.model, state.pose, state.visited)
        if edges.size == 0:
            return _exhausted(self.name)
        e = int(edges[rng.integers(0, edges.size)])
        return Plan(
            policy=self.name,
            poses=np.array([self.model.edge_target[e]], dtype=np.int64),
            actions=np.array([self.model.edge_action[e]], dtype=np.int64),
            value=float("nan"),
        )


class MeshPolicy(Policy):
    """One grasp ahead on the class x placement belief (`predicted_values`): the unvisited pose
    whose predicted finger closures leave the likeliest class the most probable. Where no pose
    beats the belief's present maximum by `min_gain`, or the state has no placement belief,
    `fallback` (greedy on the training grasps) plans."""

    name = "mesh"

    def __init__(
        self,
        model: ObservationModel,
        fallback: Policy,
        *,
        hypotheses: int,
        sigma_rad: float,
        min_gain: float,
    ) -> None:
        if hypotheses < 1:
            raise ConfigError(f"planner.mesh_hypotheses must be >= 1, got {hypotheses}")
        if not sigma_rad > 0:
            raise ConfigError(f"planner.mesh_sigma_rad must be > 0, got {sigma_rad}")
        if not 0.0 <= min_gain < 1.0:
            raise ConfigError(f"planner.mesh_min_gain must lie in [0, 1), got {min_gain}")
        self.model, self.fallback = model, fallback
        self.hypotheses, self.sigma_rad, self.min_gain = int(hypotheses), float(sigma_rad), min_gain
        self._poses = np.concatenate([model.pose_xyz, model.pose_quat], axis=1)
        # The belief's grids packed for the compiled reads, and the list they were packed
        # from: every recognition's belief shares its session's list, so once per session.
        self._packed: tuple[list, PackedShapes] | None = None

    def interrupt(self) -> None:
        self.fallback.interrupt()

    def clear_interrupt(self) -> None:
        self.fallback.clear_interrupt()

    def set_edge_cost(self, cost: np.ndarray) -> None:
        self.fallback.set_edge_cost(cost)

    def plan(self, state: PlanningState, rng: np.random.Generator) -> Plan:
        edges = unvisited_targets(self.model, state.pose, state.visited)
        if edges.size == 0:
            return _exhausted(self.name)
        where = state.placement
        if where is None:
            return self._fallback(state, rng)
        if where.belief.class_probabilities().max() >= 1.0 - self.min_gain:
            return self._fallback(state, rng)  # no grasp can add min_gain: skip the meshes
        targets = self.model.edge_target[edges]
        v, now = predicted_values(
            where.belief,
            self._poses[targets],
            where.preshape,
            where.offset,
            hypotheses=self.hypotheses,
            sigma_rad=self.sigma_rad,
            packed=self._packed_for(where.belief.shapes),
        )
        best = int(np.argmax(v))
        if v[best] < now + self.min_gain:
            return self._fallback(state, rng)
        return Plan(
            policy=self.name,
            poses=np.array([targets[best]], dtype=np.int64),
            actions=np.array([self.model.edge_action[edges[best]]], dtype=np.int64),
            value=float(v[best]),
        )

    def _packed_for(self, shapes: list) -> PackedShapes:
        if self._packed is None or self._packed[0] is not shapes:
            self._packed = (shapes, pack_shapes(shapes))
        return self._packed[1]

    def _fallback(self, state: PlanningState, rng: np.random.Generator) -> Plan:
        plan = self.fallback.plan(state, rng)
        return Plan(
            plan.policy, plan.poses[:1], plan.actions[:1], plan.value, plan.exhausted, plan.search
        )


# The allowed words live with the config; policies built without a config check them too.
POLICY_NAMES: tuple[str, ...] = typing.get_args(PolicyName)
EQ4_SAMPLING: tuple[str, ...] = typing.get_args(Eq4Sampling)
OBJECTIVES: tuple[str, ...] = typing.get_args(Objective)


def make_policy(
    name: str,
    cfg: PlannerConfig,
    model: ObservationModel,
    kernel: ClassifierKernel,
    belief: BeliefTable | None = None,
) -> Policy:
    """A policy by its configuration name (tree | greedy | random | mesh), parameters from `cfg`.
    `belief`: plan on the grasp-likelihood belief (`TreeSearch`)."""
    policy = _make(name, cfg, model, kernel, belief)
    policy.movement_cost = cfg.movement_cost
    return policy


def _make(
    name: str,
    cfg: PlannerConfig,
    model: ObservationModel,
    kernel: ClassifierKernel,
    belief: BeliefTable | None,
) -> Policy:
    if name == "random":
        return RandomPolicy(model)
    kw = {
        "simulations": cfg.simulations,
        "exploration_c": cfg.exploration_c,
        "lam": cfg.lam,
        "replan_every_grasp": cfg.replan_every_grasp,
        "eq4_sampling": cfg.eq4_sampling,
        "objective": cfg.objective,
        "belief_temperature": cfg.belief_temperature,
        "belief": belief,
    }
    if name == "tree":
        return TreePolicy(model, kernel, horizon=cfg.horizon, **kw)  # type: ignore[arg-type]
    if name == "greedy":
        return GreedyPolicy(model, kernel, **kw)
    if name == "mesh":
        return MeshPolicy(
            model,
            GreedyPolicy(model, kernel, **kw),
            hypotheses=cfg.mesh_hypotheses,
            sigma_rad=cfg.mesh_sigma_rad,
            min_gain=cfg.mesh_min_gain,
        )
    raise ConfigError(f"unknown planner policy {name!r}; choose from {', '.join(POLICY_NAMES)}")


# An observation at a pose: (histogram counts it adds (n_bins,), cells it leaves (m,)).
Observe = Callable[[int], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Episode:
    state: PlanningState  # after the last executed grasp
    poses: np.ndarray  # (n,) executed pose ids after the start, in order
    plans: tuple[Plan, ...]  # every plan asked for, the last one may be exhausted
    exhausted: bool


def run_policy(
    policy: Policy,
    state: PlanningState,
    observe: Observe,
    *,
    max_moves: int,
    rng: np.random.Generator,
    stop: Callable[[PlanningState], bool] | None = None,
) -> Episode:
    """Plan, execute each planned pose through `observe`, update the state, plan again, until
    `max_moves` grasps were executed, `stop(state)` holds after a grasp, or no pose is left.

    Both schemes run through this loop: a policy with ``replan_every_grasp`` returns one pose
    per plan, so a new tree sees every real observation; otherwise the whole path is executed
    before the next tree (Alg. 2)."""
    if max_moves < 0:
        raise PlanningError(f"max_moves must be >= 0, got {max_moves}")
    executed: list[int] = []
    plans: list[Plan] = []
    while len(executed) < max_moves:
        plan = policy.plan(state, rng)
        plans.append(plan)
        if plan.exhausted:
            return Episode(state, np.array(executed, dtype=np.int64), tuple(plans), True)
        for pose in plan.poses:
            counts, cells = observe(int(pose))
            state = state.advance(int(pose), counts, cells)
            executed.append(int(pose))
            if len(executed) >= max_moves or (stop is not None and stop(state)):
                return Episode(state, np.array(executed, dtype=np.int64), tuple(plans), False)
    return Episode(state, np.array(executed, dtype=np.int64), tuple(plans), False)


__all__ = [
    "POLICY_NAMES",
    "Episode",
    "GreedyPolicy",
    "MeshPolicy",
    "Observe",
    "Plan",
    "PlanningState",
    "Policy",
    "RandomPolicy",
    "TreePolicy",
    "make_policy",
    "run_policy",
]
