"""The recognition session (paper Alg. 2, test stage) on any `Hand` + `WristMotion` pair.

A first grasp at a random training pose; then repeat: the policy plans the next poses from the
current histogram, the arm moves to each, the hand takes the preshape training used there and
grasps, the histogram grows and the
classifier answers after every grasp (the paper classified only after each whole path). Poses
that cannot be reached are skipped, marked visited and counted, as on the real robot. It stops
when the top class stays above `confidence` for `stable_grasps` grasps in a row, when the move
budget is spent, when no unvisited pose remains, or when cancelled.

Robot time: the session reports the seconds the arm moved (`motion_s`: the wrist's
`robot_seconds` over the run, trajectory time), the seconds of the hand's open / preshape /
guarded close (`grasp_s`: the hand's `robot_seconds` where it has them, as the twin does, else
wall time), and the wall seconds planning: the policy's search (`search_s`) plus the motion
layer's (`motion_planning_s`, the wrist's `planning_seconds`), together `planning_s`.
`total_s` is moving + grasping + planning, and `robot_s` holds that total after each grasp
(what "robot seconds to first correct" reads).

A wrist that can say which poses it reaches (`reachable(poses) -> bool array`, e.g. Baxter's
motion layer) is asked once for all the model's poses before the first grasp: the unreachable
ones are marked visited up front (`unreachable`; not grasped, not counted as `skipped`), so
neither the first grasp nor the policy picks them. The floating twin has no `reachable`: its
sessions are unchanged.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from activetouch.calibration.tactile import read_states
from activetouch.config import PlannerConfig, RecognitionConfig, SessionConfig
from activetouch.device_types import (
    DEFAULT_HAND,
    FAMILY_FINGER_SENSORS,
    FAMILY_SENSORS,
    config_class,
)
from activetouch.errors import (
    ActiveTouchError,
    ConfigError,
    PlanningInterruptedError,
    UnreachableError,
)
from activetouch.interfaces import N_SENSORS, Grasp, Hand, Pose
from activetouch.model import TrainedModel
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.mesh_lookahead import PlacementBelief
from activetouch.planning.motion.base import WristMotion
from activetouch.planning.observation_model import travel_edge_cost
from activetouch.planning.policies import Plan, PlanningState, Policy, make_policy
from activetouch.planning.simulated_belief import BeliefTable
from activetouch.recognition.contacts import drop_support_contacts, hand_to_object
from activetouch.recognition.grasp_likelihood import (
    GraspLikelihood,
    LikelihoodParams,
    placement_offsets,
    pose_at_offset,
    softmax_belief,
)
from activetouch.recognition.pose_belief import (
    SDF_VERSION,
    ClassShape,
    PoseBelief,
    PoseParams,
    free_sites_for,
)
from activetouch.session.sensors import RecognitionSensors
from activetouch.storage import atomic_write_bytes

log = logging.getLogger(__name__)

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
    motion_s: float = 0.0  # robot seconds moving since the session started
    # For a live view: this grasp's contacts in the object frame ((n, 3), table contacts
    # dropped; None: not given) and p(y|h) of every class after it (empty before a grasp felt
    # anything).
    contacts: np.ndarray | None = None
    belief: list[tuple[str, float]] = field(default_factory=list)


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
    search_s: float = 0.0  # the policy's search (wall seconds)
    belief_s: float = 0.0  # updating the belief with each grasp (wall seconds)
    elapsed_s: float = 0.0
    stop_reason: str = ""  # confident | budget | exhausted | cancelled | skips
    motion_s: float = 0.0  # the arm moving: sum of executed trajectory durations
    motion_planning_s: float = 0.0  # the motion layer planning (wall seconds, failures too)
    grasp_s: float = 0.0  # the hand's open / preshape / guarded close (wall seconds)
    unreachable: int = 0  # poses the wrist's `reachable()` ruled out before the first grasp
    reachability_s: float = 0.0  # that check (wall seconds; once per placement, not per grasp)
    robot_s: list[float] = field(default_factory=list)  # total_s so far, after each grasp
    # Sensors ignored for the whole recognition, and why: flagged by the hand's tactile
    # calibration, in contact with the hand open before the first grasp (they cannot be
    # touched: stuck, or a zero that drifted), or reading nothing at all at rest (dead).
    masked_sensors: list[int] = field(default_factory=list)
    masked_reasons: dict[int, str] = field(default_factory=dict)
    # recognition.belief = pose: where the object stands off its nominal placement under the
    # label (dx_m, dy_m, yaw_deg, and their standard deviations sd_*)
    pose_estimate: dict[str, float] | None = None
    # The configuration's profile and the settings that define the method (set by who ran it)
    profile: str = ""
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def moves(self) -> int:
        return len(self.labels)

    @property
    def planning_s(self) -> float:
        """Planning: the policy's search plus the motion layer's (the robot waits for both)."""
        return self.search_s + self.motion_planning_s

    @property
    def total_s(self) -> float:
        """Robot time of the recognition: moving, grasping and planning. The reachability check
        is left out: it is paid once per placement, not per recognition."""
        return self.motion_s + self.grasp_s + self.planning_s


# A simulated hand's readings come at once; the session counts each as a ReFlex packet (40 Hz)
# of robot time where it waits for them.
SIM_READING_PERIOD_S = 0.025


def display_label(label: str) -> str:
    return label if label != NO_LABEL else "nothing (no triangle felt)"


def top_k(p: np.ndarray, names: tuple[str, ...], k: int = 3) -> list[tuple[str, float]]:
    order = np.argsort(-p, kind="stable")[:k]
    return [(names[i], float(p[i])) for i in order]


def motion_clock(wrist: WristMotion) -> tuple[float, float] | None:
    """The wrist's (robot_seconds, planning_seconds), or None if they cannot be read (a remote
    arm node that does not answer them): robot time is reported, never worth failing for."""
    try:  # duck-typed wrists without the counters count nothing
        return (
            float(getattr(wrist, "robot_seconds", 0.0)),
            float(getattr(wrist, "planning_seconds", 0.0)),
        )
    except ActiveTouchError as e:
        log.warning("cannot read the wrist's robot seconds: %s", e)
        return None


def training_preshapes(model: TrainedModel) -> np.ndarray:
    """(P,) the preshape training used at each of the model's poses: the grid has one preshape
    for all its poses (`grid.preshape`, stored with the model's config)."""
    preshape = float(model.config.get("grid", {}).get("preshape", 0.0))
    return np.full(len(model.observation.pose_xyz), preshape)


class SessionRecorder(Protocol):
    """What a session tells a recording (`activetouch.recordings.writer.SafeRecorder`)."""

    def wrist_goal(self, move: int, pose_id: int, pose: np.ndarray) -> None: ...
    def plan(self, move: int, plan: dict[str, Any]) -> None: ...
    def error(
        self, move: int, kind: str, error: str, error_type: str = "", **extra: Any
    ) -> None: ...
    def grasp(
        self,
        move: int,
        pose_id: int,
        pose: np.ndarray,
        grasp: Grasp,
        probabilities: np.ndarray,
        label: str,
        felt: bool,
        robot_time: dict[str, float],
        ignored: np.ndarray | None = None,
        support_z: float | None = None,
    ) -> None: ...


def plan_record(plan: Plan, search_s: float) -> dict[str, Any]:
    """The planner's choice and its values, for a recording."""
    out: dict[str, Any] = {
        "policy": plan.policy,
        "poses": [int(v) for v in plan.poses],
        "actions": [int(v) for v in plan.actions],
        "value": float(plan.value),
        "exhausted": bool(plan.exhausted),
        "search_s": float(search_s),
    }
    sr = plan.search
    if sr is not None:
        out["step_values"] = [float(v) for v in sr.step_values]
        out["step_visits"] = [int(v) for v in sr.step_visits]
        out["simulations"] = int(sr.simulations)
        out["n_nodes"] = int(sr.n_nodes)
    return out


class BeliefTracker:
    """p(y | the grasps so far), one grasp at a time: the histogram classifier on the summed
    triangle histogram (the paper), or Bayes over the grasps' likelihoods at their poses
    (`recognition.belief = grasp_likelihood`). The session and `replay` share it, so a replay
    gives the recorded labels bit for bit."""

    def __init__(
        self,
        model: TrainedModel,
        likelihood: tuple[GraspLikelihood, LikelihoodParams] | None,
        pose: PoseBelief | None = None,
    ) -> None:
        """`pose` (`recognition.belief = pose`): the belief over class x placement that
        decides p(y | ...) instead of the grasp likelihood (the planner still plans with
        the grasp likelihood's table, on this belief's class marginal)."""
        self.model, self.likelihood, self.pose = model, likelihood, pose
        self._finger_sensors = finger_sensors_of(model)
        self.counts = np.zeros(model.spec.n_bins)
        self._log_b = np.zeros(len(model.class_names))  # summed log p(grasp | y, pose)

    @property
    def log_belief(self) -> np.ndarray | None:
        return None if self.likelihood is None else self._log_b

    def update(
        self, grasp: Grasp, pose: Pose, ignore: np.ndarray | None = None
    ) -> tuple[np.ndarray, bool, np.ndarray]:
        """(p(y | ...), whether anything was felt that tells classes apart, the grasp's
        observation cells) after adding `grasp`, made at wrist `pose` (object frame).
        `ignore`: the sensors masked this recognition; the likelihood compares the others only
        (the histogram has no per-sensor part: their contacts are already dropped)."""
        tris = self.model.triangles(grasp.xyz)
        add = self.model.spec.counts(tris)
        cells = self.model.observation.cells_of(tris)
        self.counts = self.counts + add
        if self.pose is not None:
            self.pose.update(grasp, pose, ignore)
            self._log_b = self.pose.class_log_belief()
            p = softmax_belief(self._log_b)
            felt = bool(np.ptp(p) > 1e-12)
        elif self.likelihood is None:
            p = self.model.proba(self.counts)
            # No triangle yet: p is uniform and its argmax (class 0) says nothing.
            felt = bool(self.counts.any())
        else:
            model_l, params = self.likelihood
            self._log_b = self._log_b + model_l.log_likelihood(
                grasp, pose, params, ignore, self._finger_sensors
            )
            p = softmax_belief(self._log_b)
            felt = bool(np.ptp(p) > 1e-12)  # even an empty grasp may tell classes apart
        return p, felt, cells


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
        recognition: RecognitionConfig | None = None,
        recorder: SessionRecorder | None = None,
        library: ObjectLibrary | None = None,
    ) -> None:
        """`support_z`: the table plane in the object frame (the object pose is known, as in
        the paper, from the workcell); contacts on it are dropped, as in training.
        `recognition`: the settings that choose the belief (`recognition.belief`); default the
        model's own. `recorder`: told every wrist goal, grasp (as observed, table contacts
        dropped), belief, plan and skipped pose (`recordings.writer.SafeRecorder`).
        `library`: the classes' meshes, for `recognition.belief = pose`."""
        if cfg.max_moves < 1:
            raise ConfigError(f"the move budget must be at least 1, got {cfg.max_moves}")
        if cfg.stable_grasps < 1:
            raise ConfigError(f"session.stable_grasps must be >= 1, got {cfg.stable_grasps}")
        for name in ("confirm_readings", "average_readings", "rezero_readings"):
            n = getattr(cfg, name)
            if not 0 <= n <= 40:
                raise ConfigError(f"session.{name} must be in 0..40 (readings at 40 Hz), got {n}")
        if cfg.average_readings and cfg.confirm_readings:
            raise ConfigError(
                "session.average_readings and session.confirm_readings each decide the contacts "
                "after a close: set one of them to 0"
            )
        check_model_hand(model, hand)
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
        self._grasp_s = 0.0
        self._likelihood = grasp_likelihood_of(model, recognition)
        self._pose_of = pose_belief_of(model, recognition, library)
        self._family = model_hand_family(model)
        # Only a pose belief has a placement to follow (`belief.pose` is None otherwise).
        self._follow = (recognition or saved_recognition(model)).pose_follow
        # Where the object is believed to stand off its nominal placement (dx, dy, yaw): the
        # grasps go there with `recognition.pose_follow`; zeros otherwise.
        self._offset = np.zeros(3)
        self.recorder = recorder
        self.sensors = RecognitionSensors(hand, cfg, self._read_waiting)

    def _mask_at_rest(self) -> dict[int, str]:
        """Open the hand, away from the object, and mask and set thresholds from its sensors
        at rest (`RecognitionSensors.mask_at_rest`)."""
        self._hand(self.hand.open)
        return self.sensors.mask_at_rest()

    def _read_waiting(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """`read_states` of `n` readings (what a hand gives within 2 s), their time added to the
        grasping seconds: the robot waits for them (wall time, or for a simulated hand, whose
        readings come at once, a reading period each)."""
        t = time.perf_counter()
        pressures, contact = read_states(self.hand, n, timeout_s=2.0)
        if self.hand.robot_seconds is None:
            self._grasp_s += time.perf_counter() - t
        else:
            self._grasp_s += len(pressures) * SIM_READING_PERIOD_S
        return pressures, contact

    def _rezero(self, res: RecognitionResult) -> None:
        """Before a grasp after the first: re-zero the sensors (`session.rezero_readings`)
        and report those newly masked."""
        new = self.sensors.rezero(len(res.labels) + 1)
        if new:
            res.masked_reasons.update(new)
            res.masked_sensors = [int(i) for i in self.sensors.masked]

    def _hand(self, fn: Callable[[], Grasp | None]) -> Grasp | None:
        """`fn()` (a hand command), its time added to the grasping seconds: the hand's robot
        seconds where it keeps them (a simulated hand), else wall time."""
        t, r = time.perf_counter(), self.hand.robot_seconds
        try:
            return fn()
        finally:
            r1 = self.hand.robot_seconds
            if r is not None and r1 is not None:
                self._grasp_s += r1 - r
            else:
                self._grasp_s += time.perf_counter() - t

    def _placement(self, belief: BeliefTracker) -> PlacementBelief | None:
        """The class x placement belief for the mesh policy, where the next grasp goes and
        with what preshape; None without a pose belief or for a hand the meshes' finger
        sweeps do not model (the ReFlex's only)."""
        if belief.pose is None or self._family != "reflex":
            return None
        return PlacementBelief(belief.pose, self._offset.copy(), float(self._preshapes[0]))

    def _target(self, pose_id: int) -> Pose:
        """The wrist pose (object frame) of training pose `pose_id` on the object as it is
        believed to stand."""
        if not self._offset.any():
            return Pose.from_array(self._poses[pose_id])
        return Pose.from_array(pose_at_offset(self._poses[pose_id], self._offset))

    def _grasp_at(self, pose_id: int, pose: Pose) -> Grasp:
        """Grasp at wrist pose `pose` (object frame) with training pose `pose_id`'s preshape."""
        preshape = float(self._preshapes[pose_id])
        self._hand(self.hand.open)
        self._hand(lambda: self.hand.preshape(preshape))  # as training grasped here
        self.wrist.move_to(pose)  # raises UnreachableError
        grasp = self._hand(self.hand.guarded_close)
        assert grasp is not None
        grasp = self.sensors.after_close(grasp)
        self._hand(self.hand.open)
        grasp = self.sensors.counted(grasp)
        if self.support_z is not None:
            grasp = drop_support_contacts(grasp, pose, self.support_z, self.support_margin_m)
        return grasp

    def _unreachable(self, res: RecognitionResult) -> list[int]:
        """The model's poses the wrist says it cannot reach (none without `reachable`)."""
        reachable = getattr(self.wrist, "reachable", None)
        if reachable is None:
            return []
        t = time.perf_counter()
        ok = np.asarray(reachable(self._poses), dtype=bool).reshape(-1)
        res.reachability_s = time.perf_counter() - t
        if ok.shape != (len(self._poses),):
            raise ActiveTouchError(
                f"the wrist's reachable() gave {ok.shape[0]} verdicts for {len(self._poses)} poses"
            )
        out = [int(i) for i in np.flatnonzero(~ok)]
        res.unreachable = len(out)
        log.info(
            "poses the arm reaches: %d of %d (checked in %.1f s)",
            len(ok) - len(out),
            len(ok),
            res.reachability_s,
        )
        return out

    def _clock(self, res: RecognitionResult, clock0: tuple[float, float] | None) -> None:
        """Bring `res`'s robot time up to now: grasping, and the wrist's moving and motion
        planning since `clock0` (left as they were if the wrist cannot tell)."""
        res.grasp_s = self._grasp_s
        now = motion_clock(self.wrist)
        if clock0 is not None and now is not None:
            res.motion_s = now[0] - clock0[0]
            res.motion_planning_s = now[1] - clock0[1]

    def _travel_costs(self) -> None:
        """With ``planner.movement_cost = "travel_time"``: c_m of every model edge from the
        wrist's estimated move durations (`travel_times`, e.g. Baxter's), once per recognition."""
        if self.policy.movement_cost != "travel_time":
            return
        travel = getattr(self.wrist, "travel_times", None)
        if travel is None:
            log.warning(
                "planner.movement_cost=travel_time: this arm does not estimate travel times; "
                "the movement cost stays the pose difference"
            )
            return
        seconds = np.asarray(travel(self._poses), dtype=np.float64)
        self.policy.set_edge_cost(travel_edge_cost(self.model.observation, seconds))

    def run(self) -> RecognitionResult:
        t0 = time.perf_counter()
        names = self.model.class_names
        res = RecognitionResult(label="", probability=0.0)
        self._grasp_s = 0.0
        self._offset = np.zeros(3)
        clock0 = motion_clock(self.wrist)
        res.masked_reasons = self._mask_at_rest()
        res.masked_sensors = list(res.masked_reasons)
        # Unreachable poses are visited from the start: never a first grasp, never planned.
        visited: list[int] = self._unreachable(res)
        self._travel_costs()
        ruled_out = set(visited)
        belief = BeliefTracker(self.model, self._likelihood, self._pose_of(self.support_z))
        state: PlanningState | None = None
        streak = 0
        rec = self.recorder

        def observe(pose_id: int, grasp: Grasp, pose: Pose) -> None:
            nonlocal state, streak
            visited.append(pose_id)
            tb = time.perf_counter()
            p, felt, cells = belief.update(grasp, pose, self.sensors.masked)
            res.belief_s += time.perf_counter() - tb
            best = int(np.argmax(p))
            if self._follow and belief.pose is not None and felt:
                self._offset = belief.pose.placement_peak()
            state = PlanningState(
                pose=pose_id,
                visited=np.array(visited, dtype=np.int64),
                counts=belief.counts,
                cells=cells,
                log_belief=belief.log_belief,
                placement=self._placement(belief),
            )
            res.labels.append(names[best] if felt else NO_LABEL)
            res.probabilities.append([float(v) for v in p])
            res.pose_ids.append(pose_id)
            res.contacts.append(hand_to_object(pose, grasp.xyz))
            self._clock(res, clock0)
            res.robot_s.append(res.total_s)
            if rec is not None:
                rec.grasp(
                    len(res.labels),
                    pose_id,
                    pose.as_array(),
                    grasp,
                    p,
                    res.labels[-1],
                    felt,
                    {
                        "motion_s": res.motion_s,
                        "grasp_s": res.grasp_s,
                        "search_s": res.search_s,
                        "motion_planning_s": res.motion_planning_s,
                        "total_s": res.total_s,
                        "elapsed_s": time.perf_counter() - t0,
                    },
                    ignored=self.sensors.masked,
                    support_z=self.support_z,
                )
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
                        pose=pose.as_array(),
                        n_contacts=grasp.n_contacts,
                        top=top_k(p, names) if felt else [],
                        skipped=res.skipped,
                        elapsed_s=time.perf_counter() - t0,
                        motion_s=res.motion_s,
                        contacts=res.contacts[-1],
                        belief=[(n, float(v)) for n, v in zip(names, p, strict=True)]
                        if felt
                        else [],
                    )
                )

        def skip(pose_id: int, error: UnreachableError) -> None:
            nonlocal state
            visited.append(pose_id)
            res.skipped += 1
            if rec is not None:
                rec.error(
                    len(res.labels), "skipped", str(error), type(error).__name__, pose_id=pose_id
                )
            if state is not None:  # the arm stayed where it was
                state = PlanningState(
                    pose=state.pose,
                    visited=np.array(visited, dtype=np.int64),
                    counts=state.counts,
                    cells=state.cells,
                    log_belief=state.log_belief,
                    placement=state.placement,
                )

        def attempt(pose_id: int) -> bool:
            """Grasp at `pose_id`; an unreachable pose is skipped. True if it was grasped."""
            pose = self._target(pose_id)
            if rec is not None:
                rec.wrist_goal(len(res.labels) + 1, pose_id, pose.as_array())
            if res.labels:
                self._rezero(res)
            try:
                grasp = self._grasp_at(pose_id, pose)
            except UnreachableError as e:
                skip(pose_id, e)
                return False
            observe(pose_id, grasp, pose)
            return True

        # First grasp: a random training pose that can be reached.
        for pid in self.rng.permutation(len(self._poses)):
            if int(pid) in ruled_out:
                continue  # the same permutation as without the check: only these are left out
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
                res.search_s += time.perf_counter() - tp
            if rec is not None:
                rec.plan(len(res.labels), plan_record(plan, time.perf_counter() - tp))
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
        res.counts = belief.counts
        if res.labels:
            p = np.asarray(res.probabilities[-1])
            res.label = res.labels[-1]
            res.probability = float(p.max()) if res.label != NO_LABEL else 0.0
            if belief.pose is not None:
                res.pose_estimate = belief.pose.estimate(int(np.argmax(p))).as_dict()
        self._clock(res, clock0)
        res.elapsed_s = time.perf_counter() - t0
        return res


def model_hand_family(model: TrainedModel) -> str:
    """The hand family the model was trained for ("reflex" unless its config names another
    hand type's family; models from before hand families are the ReFlex's)."""
    hand_type = model.config.get("hand", {}).get("type", DEFAULT_HAND)
    try:
        return config_class("hand", str(hand_type)).family
    except ConfigError:
        return "reflex"


def finger_sensors_of(model: TrainedModel) -> int:
    """The sensors per finger of the hand the model was trained for (`FAMILY_FINGER_SENSORS`;
    0 for a family whose layout is not known: its fingers are then compared as before)."""
    return FAMILY_FINGER_SENSORS.get(model_hand_family(model), 0)


def check_model_hand(model: TrainedModel, hand: Hand) -> None:
    """ConfigError unless the hand has the sensors the model was trained with."""
    family = model_hand_family(model)
    expected = FAMILY_SENSORS.get(family, N_SENSORS)
    if hand.n_sensors != expected:
        raise ConfigError(
            f"the model was trained for the {family} hand ({expected} sensors) and this hand "
            f"has {hand.n_sensors}: train a model for it (`activetouch train --set "
            "hand.type=...`, written to its own models/default-<hand>) or pass --model"
        )


def grasp_likelihood_of(
    model: TrainedModel, recognition: RecognitionConfig | None
) -> tuple[GraspLikelihood, LikelihoodParams] | None:
    """The per-grasp likelihood and its widths when `recognition.belief` asks for it (None for
    the paper's histogram classifier); ConfigError if the model has none (for the pose belief,
    the default: a warning, and the histogram belief)."""
    if recognition is None:
        recognition = saved_recognition(model)
    if recognition.belief == "histogram":
        return None
    if recognition.belief not in ("grasp_likelihood", "pose"):
        raise ConfigError(
            f"recognition.belief: {recognition.belief!r} is not one of histogram, "
            "grasp_likelihood, pose"
        )
    if model.likelihood is None:
        why = (
            "this model has no grasp likelihood (trained before it existed); retrain it with "
            "`activetouch train` (the grasps are reused)"
        )
        if recognition.belief == "pose":
            _warn_once(f"recognition.belief=pose: {why}; using the histogram belief")
            return None
        raise ConfigError(f"recognition.belief=grasp_likelihood: {why}")
    return model.likelihood, LikelihoodParams.from_config(recognition)


@functools.lru_cache(maxsize=64)
def _warn_once(text: str) -> None:
    log.warning(text)


def saved_recognition(model: TrainedModel) -> RecognitionConfig:
    known = {f.name for f in dataclasses.fields(RecognitionConfig)}
    saved = model.config.get("recognition", {})
    return RecognitionConfig(**{k: v for k, v in saved.items() if k in known})


@functools.lru_cache(maxsize=256)
def _class_shape(mesh: str, mtime_ns: int) -> ClassShape:
    """The mesh's signed-distance grid, from the file beside it when that is as new (a few
    seconds per object to build: a daemon's first recognition should not wait for it)."""
    cache = Path(mesh).with_name(f".sdf-v{SDF_VERSION}-{mtime_ns}.npz")
    shape = None
    if cache.is_file():
        try:
            shape = ClassShape.from_arrays(dict(np.load(cache)))
        except (OSError, ValueError, KeyError):
            log.warning("%s: unreadable, rebuilt", cache)
        if shape is not None and shape.pivot is not None:  # this version's pivot stored too
            return shape
    if shape is None:
        # deferred: loads trimesh
        import trimesh

        m = trimesh.load(mesh, force="mesh")
        shape = ClassShape.from_mesh(m.vertices, m.faces)
    try:  # (a grid stored without this version's pivot: stored again with it)
        buf = io.BytesIO()
        np.savez(buf, **shape.to_arrays())
        atomic_write_bytes(cache, buf.getvalue())
    except OSError as e:  # a read-only library still works, only slower
        log.info("could not cache %s (%s)", cache, e)
    return shape


def class_shapes(names: list[str], library: ObjectLibrary) -> list[ClassShape]:
    """Each class's surface samples from its library mesh (cached per file and version)."""
    out = []
    for name in names:
        if name not in library:
            raise ConfigError(
                f"recognition.belief=pose: class {name!r} is not in the object library at "
                f"{library.root}: the pose belief needs every class's mesh"
            )
        mesh = library.get(name).visual_mesh
        out.append(_class_shape(str(mesh), mesh.stat().st_mtime_ns))
    return out


def pose_belief_of(
    model: TrainedModel, recognition: RecognitionConfig | None, library: ObjectLibrary | None
) -> Callable[[float | None], PoseBelief | None]:
    """A maker of fresh pose beliefs when `recognition.belief = pose` (one per recognition,
    given the table plane in the object frame if known: with `recognition.pose_on_table` each
    class stands on it), else of None. Without every class's mesh (objects trained on a robot
    without one, or no library) or without a grasp likelihood, a warning says so and the
    session uses the grasp likelihood, or the histogram, with the placement taken as known."""
    rc = recognition or saved_recognition(model)
    if rc.belief != "pose" or model.likelihood is None:
        return lambda support_z: None
    missing = (
        list(model.class_names)
        if library is None
        else [n for n in model.class_names if n not in library]
    )
    if missing:
        _warn_once(
            "recognition.belief=pose: no mesh for "
            + ", ".join(missing[:5])
            + (" ..." if len(missing) > 5 else "")
            + " in the object library: using the grasp likelihood, the placement taken as known"
        )
        return lambda support_z: None
    assert library is not None
    shapes = class_shapes(list(model.class_names), library)
    params = PoseParams.from_config(rc)
    free = free_sites_for(model_hand_family(model))
    grasps = grasp_likelihood_of(model, rc) if rc.pose_with_grasps else None
    on_table = rc.pose_on_table
    per_finger = finger_sensors_of(model)
    return lambda support_z: PoseBelief(
        shapes, params, free, grasps, support_z if on_table else None, per_finger
    )


def belief_table_of(
    model: TrainedModel, recognition: RecognitionConfig | None
) -> BeliefTable | None:
    """What the planner needs to plan on the grasp-likelihood belief (`make_policy`'s
    `belief`), or None for the histogram belief; ConfigError if the model cannot give it."""
    lik = grasp_likelihood_of(model, recognition)
    if lik is None:
        return None
    model_l, params = lik
    out_grasp = model.observation.out_grasp
    rc = recognition or saved_recognition(model)
    if len(out_grasp) != model.observation.n_outcomes or model.observation.n_outcomes == 0:
        if rc.belief == "pose":
            _warn_once(
                "recognition.belief=pose: this model's observation model does not say which "
                "training grasp each outcome is: the planner plans on the histogram"
            )
            return None
        raise ConfigError(
            "recognition.belief=grasp_likelihood: the observation model does not say which "
            "training grasp each outcome is (observation.granularity=grasp, trained by this "
            "version); retrain with `activetouch train`"
        )
    if out_grasp.max() >= len(model_l.labels):
        raise ConfigError("the observation model and the grasp likelihood differ in grasps")
    offsets = None
    if rc.belief == "pose":  # plan as if the object may stand anywhere near the belief
        offsets = placement_offsets(rc.plan_placement_m, rc.plan_placement_deg)
    return BeliefTable(model_l.training_log_likelihoods(params, offsets), out_grasp)


def policy_for(
    model: TrainedModel,
    name: str,
    planner: PlannerConfig,
    recognition: RecognitionConfig | None,
) -> Policy:
    """The policy `name` as a recognition uses it: planning on the belief `recognition`
    configures (`belief_table_of`), so no caller can forget the belief and plan on the
    histogram instead."""
    return make_policy(
        name,
        planner,
        model.observation,
        model.classifier.kernel(),
        belief_table_of(model, recognition),
    )
