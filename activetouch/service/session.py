"""The recognition session (paper Alg. 2, test stage) on any `Hand` + `WristMotion` pair.

A first grasp at a random training pose; then repeat: the policy plans the next poses from the
current histogram, the arm moves to each, the hand takes the preshape training used there and
grasps, the histogram grows and the
classifier answers after every grasp (the paper classified only after each whole path). Poses
that cannot be reached are skipped, marked visited and counted, as on the real robot. It stops
when the top class stays above `confidence` for `stable_grasps` grasps in a row, when the move
budget is spent, when no unvisited pose remains, or when cancelled.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from activetouch.config import SessionConfig
from activetouch.errors import ConfigError, PlanningInterruptedError, UnreachableError
from activetouch.interfaces import Grasp, Hand, Pose
from activetouch.model import TrainedModel
from activetouch.planning.motion.base import WristMotion
from activetouch.planning.policies import Plan, PlanningState, Policy
from activetouch.recognition.contacts import drop_support_contacts, hand_to_object

NO_LABEL = ""  # the label while no grasp has given a triangle (nothing felt to classify)


@dataclass(frozen=True)
class Progress:
    """Published after every grasp."""

    move: int  # grasps so far, the first one included
    pose_id: int
    pose: np.ndarray  # (7,) wrist pose in the object frame
    n_contacts: int
    top: list[tuple[str, float]]  # the three most probable classes
    skipped: int
    elapsed_s: float


@dataclass
class RecognitionResult:
    label: str  # NO_LABEL if nothing was felt
    probability: float
    labels: list[str] = field(default_factory=list)  # after each grasp, NO_LABEL before a triangle
    probabilities: list[list[float]] = field(default_factory=list)  # p(y|h) after each grasp
    pose_ids: list[int] = field(default_factory=list)  # executed, in order
    contacts: list[np.ndarray] = field(default_factory=list)  # per grasp (n, 3), object frame
    counts: np.ndarray | None = None  # final histogram counts
    skipped: int = 0
    planning_s: float = 0.0
    elapsed_s: float = 0.0
    stop_reason: str = ""  # confident | budget | exhausted | cancelled | skips

    @property
    def moves(self) -> int:
        return len(self.labels)


def display_label(label: str) -> str:
    return label if label != NO_LABEL else "nothing (no triangle felt)"


def top_k(p: np.ndarray, names: tuple[str, ...], k: int = 3) -> list[tuple[str, float]]:
    order = np.argsort(-p, kind="stable")[:k]
    return [(names[i], float(p[i])) for i in order]


def training_preshapes(model: TrainedModel) -> np.ndarray:
    """(P,) the preshape training used at each of the model's poses: the grid has one preshape
    for all its poses (`grid.preshape`, stored with the model's config)."""
    preshape = float(model.config.get("grid", {}).get("preshape", 0.0))
    return np.full(len(model.observation.pose_xyz), preshape)


class RecognitionSession:
    def __init__(
        self,
        hand: Hand,
        wrist: WristMotion,
        model: TrainedModel,
        policy: Policy,
        cfg: SessionConfig,
        rng: np.random.Generator,
        on_progress: Callable[[Progress], None] | None = None,
        cancel: threading.Event | None = None,
        support_z: float | None = None,
    ) -> None:
        """`support_z`: the table plane in the object frame (the object pose is known, as in
        the paper, from the workcell); contacts on it are dropped, as in training."""
        if cfg.max_moves < 1:
            raise ConfigError(f"the move budget must be at least 1, got {cfg.max_moves}")
        if cfg.stable_grasps < 1:
            raise ConfigError(f"session.stable_grasps must be >= 1, got {cfg.stable_grasps}")
        self.hand, self.wrist, self.model, self.policy = hand, wrist, model, policy
        self.cfg, self.rng = cfg, rng
        self.on_progress = on_progress
        self.cancel = cancel or threading.Event()
        self.support_z = support_z
        self.support_margin_m = float(
            model.config.get("recognition", {}).get("support_margin_m", 0.005)
        )
        obs = model.observation
        self._poses = np.concatenate([obs.pose_xyz, obs.pose_quat], axis=1)
        self._preshapes = training_preshapes(model)

    def _grasp_at(self, pose_id: int) -> tuple[Grasp, Pose]:
        pose = Pose.from_array(self._poses[pose_id])
        self.hand.open()
        self.hand.preshape(float(self._preshapes[pose_id]))  # as training grasped here
        self.wrist.move_to(pose)  # raises UnreachableError
        grasp = self.hand.guarded_close()
        self.hand.open()
        if self.support_z is not None:
            grasp = drop_support_contacts(grasp, pose, self.support_z, self.support_margin_m)
        return grasp, pose

    def run(self) -> RecognitionResult:
        t0 = time.perf_counter()
        names = self.model.class_names
        res = RecognitionResult(label="", probability=0.0)
        visited: list[int] = []
        counts = np.zeros(self.model.spec.n_bins)
        state: PlanningState | None = None
        streak = 0

        def observe(pose_id: int, grasp: Grasp, pose: Pose) -> None:
            nonlocal counts, state, streak
            tris = self.model.triangles(grasp.xyz)
            add = self.model.spec.counts(tris)
            cells = self.model.observation.cells_of(tris)
            counts = counts + add
            visited.append(pose_id)
            state = PlanningState(
                pose=pose_id,
                visited=np.array(visited, dtype=np.int64),
                counts=counts,
                cells=cells,
            )
            p = self.model.proba(counts)
            best = int(np.argmax(p))
            # No triangle yet: p is uniform and its argmax (class 0) says nothing.
            felt = bool(counts.any())
            res.labels.append(names[best] if felt else NO_LABEL)
            res.probabilities.append([float(v) for v in p])
            res.pose_ids.append(pose_id)
            res.contacts.append(hand_to_object(pose, grasp.xyz))
            # Consecutive confident grasps agreeing on the same top class.
            if p[best] < self.cfg.confidence or not felt:
                streak = 0
            elif streak > 0 and res.labels[-2] == names[best]:
                streak += 1
            else:
                streak = 1
            if self.on_progress is not None:
                self.on_progress(
                    Progress(
                        move=len(res.labels),
                        pose_id=pose_id,
                        pose=self._poses[pose_id].copy(),
                        n_contacts=grasp.n_contacts,
                        top=top_k(p, names) if felt else [],
                        skipped=res.skipped,
                        elapsed_s=time.perf_counter() - t0,
                    )
                )

        def skip(pose_id: int) -> None:
            nonlocal state
            visited.append(pose_id)
            res.skipped += 1
            if state is not None:  # the arm stayed where it was
                state = PlanningState(
                    pose=state.pose,
                    visited=np.array(visited, dtype=np.int64),
                    counts=state.counts,
                    cells=state.cells,
                )

        def attempt(pose_id: int) -> bool:
            """Grasp at `pose_id`; an unreachable pose is skipped. True if it was grasped."""
            try:
                grasp, pose = self._grasp_at(pose_id)
            except UnreachableError:
                skip(pose_id)
                return False
            observe(pose_id, grasp, pose)
            return True

        # First grasp: a random training pose that can be reached.
        for pid in self.rng.permutation(len(self._poses)):
            if self.cancel.is_set() or res.skipped >= self.cfg.max_skips or attempt(int(pid)):
                break

        while state is not None:
            if self.cancel.is_set():
                res.stop_reason = "cancelled"
                break
            if streak >= self.cfg.stable_grasps:
                res.stop_reason = "confident"
                break
            if len(res.labels) >= self.cfg.max_moves:
                res.stop_reason = "budget"
                break
            if res.skipped >= self.cfg.max_skips:
                res.stop_reason = "skips"
                break
            tp = time.perf_counter()
            try:
                plan: Plan = self.policy.plan(state, self.rng)
            except PlanningInterruptedError:
                if not self.cancel.is_set():
                    raise
                res.stop_reason = "cancelled"  # cancel / e-stop ended the plan it was in
                break
            finally:
                res.planning_s += time.perf_counter() - tp
            if plan.exhausted:
                res.stop_reason = "exhausted"
                break
            for pid in plan.poses:
                if self.cancel.is_set() or len(res.labels) >= self.cfg.max_moves:
                    break
                if attempt(int(pid)) and streak >= self.cfg.stable_grasps:
                    break
        if not res.stop_reason:
            res.stop_reason = "cancelled" if self.cancel.is_set() else "skips"
        res.counts = counts
        if res.labels:
            p = np.asarray(res.probabilities[-1])
            res.label = res.labels[-1]
            res.probability = float(p.max()) if res.label != NO_LABEL else 0.0
        res.elapsed_s = time.perf_counter() - t0
        return res
