from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from activetouch import paths
from activetouch.errors import ConfigError, UnreachableError
from activetouch.interfaces import Grasp, Pose
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.motion.base import WristMotion
from activetouch.planning.policies import make_policy
from activetouch.recognition.grasp_likelihood import pose_at_offset, softmax_belief
from activetouch.session.local import recognize_in_twin
from activetouch.session.loop import (
    NO_LABEL,
    SIM_READING_PERIOD_S,
    Progress,
    RecognitionSession,
    belief_table_of,
    display_label,
    grasp_likelihood_of,
)
from activetouch.sim.twin import open_twin
from tests.conftest import SMALL_OBJECTS, small_config


def _run(home, model, obj="cup", policy="tree", seed=0, **kw):
    lib = ObjectLibrary(paths.objects_dir(home))
    return recognize_in_twin(model, lib, obj, policy, seed, small_config(), **kw)


@pytest.mark.parametrize("policy", ["tree", "greedy", "random", "mesh"])
def test_each_policy_recognises_and_never_repeats_a_pose(trained_home, small_model, policy):
    res = _run(trained_home, small_model, "bottle", policy, seed=1, max_moves=8)
    assert 1 <= res.moves <= 8
    assert len(res.labels) == len(res.probabilities) == len(res.pose_ids) == res.moves
    assert len(set(res.pose_ids)) == len(res.pose_ids)
    for p in res.probabilities:
        assert sum(p) == pytest.approx(1.0)
        assert len(p) == len(SMALL_OBJECTS)
    assert res.stop_reason in ("confident", "budget", "exhausted")
    assert res.label == res.labels[-1]


def test_stops_when_confident_for_k_grasps(trained_home, small_model):
    cfg = small_config()
    res = _run(trained_home, small_model, "sphere", "tree", seed=2, max_moves=20)
    if res.stop_reason == "confident":
        k = cfg.session.stable_grasps
        tail = res.probabilities[-k:]
        assert len({res.labels[-i] for i in range(1, k + 1)}) == 1
        assert all(max(p) >= cfg.session.confidence for p in tail)
    else:  # never confident for k grasps in a row: then the budget must be spent
        assert res.moves == 20 or res.stop_reason == "exhausted"


def test_equal_seeds_give_equal_sessions(trained_home, small_model):
    a = _run(trained_home, small_model, "cup", "tree", seed=5, max_moves=6)
    b = _run(trained_home, small_model, "cup", "tree", seed=5, max_moves=6)
    assert a.pose_ids == b.pose_ids and a.labels == b.labels
    np.testing.assert_allclose(a.probabilities, b.probabilities)


def test_progress_after_every_grasp_and_cancel(trained_home, small_model):
    cancel = threading.Event()
    events = []

    def on_progress(ev):
        events.append(ev)
        if ev.move == 2:
            cancel.set()

    res = _run(
        trained_home,
        small_model,
        "cup",
        "random",
        seed=3,
        max_moves=10,
        on_progress=on_progress,
        cancel=cancel,
    )
    assert res.stop_reason == "cancelled"
    assert res.moves == 2
    assert [e.move for e in events] == [1, 2]
    # The top three once something was felt; nothing ranked before (uniform p).
    assert [len(e.top) for e in events] == [3 if lab != NO_LABEL else 0 for lab in res.labels]


class FlakyWrist:
    """Wraps the twin's wrist motion; every other requested pose is unreachable."""

    def __init__(self, wrist):
        self.wrist = wrist
        self.calls = 0

    def move_to(self, pose: Pose) -> None:
        self.calls += 1
        if self.calls % 2 == 0:
            raise UnreachableError("blocked in this test")
        self.wrist.move_to(pose)


def _random_session(hand, wrist, model, cfg, max_moves: int) -> RecognitionSession:
    """A session with the random policy that never stops confident (runs its budget)."""
    policy = make_policy("random", cfg.planner, model.observation, model.classifier.kernel())
    return RecognitionSession(
        hand,
        wrist,
        model,
        policy,  # type: ignore[arg-type]
        type(cfg.session)(max_moves=max_moves, confidence=1.1),
        np.random.default_rng(0),
    )


def test_the_mesh_policy_plans_on_the_placement_belief_the_session_gives_it(
    trained_home, small_model
):
    # The cup 2 cm and 20 deg off: before each plan the session hands the policy its class x
    # placement belief (the probabilities it reports) and the offset it then grasps at.
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    policy = make_policy(
        "mesh",
        cfg.planner,
        small_model.observation,
        small_model.classifier.kernel(),
        belief_table_of(small_model, cfg.recognition),
    )
    seen: list = []
    grasped: list = []  # progress reports: one per grasp
    goals: list[np.ndarray] = []  # every wrist goal, those found unreachable too
    plan = policy.plan

    def spy(state, rng):
        out = plan(state, rng)
        where = state.placement
        seen.append(
            (len(grasped), len(goals), where.belief.class_probabilities(), where.offset, out)
        )
        return out

    policy.plan = spy  # type: ignore[method-assign]
    sim = dataclasses.replace(cfg.sim, placement_error_m=0.02, placement_error_deg=20.0)
    with open_twin(lib.get("cup"), sim, seed=3, workcell=cfg.workcell) as twin:
        move_to = twin.wrist.move_to
        twin.wrist.move_to = lambda pose: (goals.append(pose.as_array()), move_to(pose))[1]
        res = RecognitionSession(
            twin.hand,
            twin.wrist,
            small_model,
            policy,
            type(cfg.session)(max_moves=5, confidence=1.1),
            np.random.default_rng(3),
            on_progress=grasped.append,
            support_z=twin.support_z,
            recognition=cfg.recognition,
            library=lib,
        ).run()
    assert res.moves == 5 and len(seen) >= 4
    obs = small_model.observation
    poses = np.concatenate([obs.pose_xyz, obs.pose_quat], axis=1)
    moved = False
    for n_grasps, n_goals, p, offset, out in seen:
        assert p == pytest.approx(res.probabilities[n_grasps - 1])
        want = pose_at_offset(poses[out.poses[0]], offset)
        assert goals[n_goals][:3] == pytest.approx(want[:3])
        moved |= bool(np.any(offset))
    assert moved  # the object was found off its frame and the grasps followed it


def test_unreachable_poses_are_skipped_counted_and_not_retried(trained_home, small_model):
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    with open_twin(lib.get("cup"), cfg.sim, seed=0) as twin:
        arm = FlakyWrist(twin.wrist)
        res = _random_session(twin.hand, arm, small_model, cfg, max_moves=5).run()
    assert res.moves == 5
    assert res.skipped >= 4
    assert arm.calls == res.moves + res.skipped


def test_bad_budget_is_a_clear_error(trained_home, small_model):
    with pytest.raises(ConfigError, match="move budget"):
        _run(trained_home, small_model, max_moves=0)
    with pytest.raises(ConfigError, match="unknown policy"):
        _run(trained_home, small_model, policy="psychic")


class NumbFirstHand:
    """Wraps the twin's hand; the first guarded close feels nothing."""

    def __init__(self, hand):
        self.hand = hand
        self.closes = 0

    def __getattr__(self, name):
        return getattr(self.hand, name)

    def guarded_close(self):
        self.closes += 1
        g = self.hand.guarded_close()
        if self.closes == 1:
            return Grasp(np.zeros(0), np.zeros((0, 3)), np.zeros(0), g.finger_angles)
        return g


def test_no_label_until_something_is_felt(trained_home, small_model):
    # With an empty histogram p(y|h) is uniform; its argmax (class 0, the cup) must not count
    # as a recognition of the cup. (The histogram belief: with the others an empty grasp is
    # evidence already.)
    cfg = small_config()
    cfg.recognition.belief = "histogram"
    events = []
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    policy = make_policy(
        "random", cfg.planner, small_model.observation, small_model.classifier.kernel()
    )
    with open_twin(lib.get("cup"), cfg.sim, seed=0) as twin:
        s = RecognitionSession(
            NumbFirstHand(twin.hand),
            twin.wrist,
            small_model,
            policy,  # type: ignore[arg-type]
            type(cfg.session)(max_moves=3, confidence=1.1),
            np.random.default_rng(0),
            on_progress=events.append,
            recognition=cfg.recognition,
        )
        res = s.run()
    assert events[0].top == []  # no ranking of a uniform distribution
    assert res.labels[0] == NO_LABEL
    assert res.probabilities[0] == pytest.approx([1 / 3] * 3)
    assert res.labels[1] != NO_LABEL or res.labels[2] != NO_LABEL
    assert display_label(NO_LABEL) != NO_LABEL


class RecordingHand:
    """Wraps a hand; records preshapes and grasps in order, and can add one contact."""

    def __init__(self, hand, extra_object_point=None):
        self.hand = hand
        self.calls: list[tuple] = []
        self.extra = extra_object_point  # an object-frame point to report as a contact
        self.wrist = None

    def __getattr__(self, name):
        return getattr(self.hand, name)

    def preshape(self, angle):
        self.calls.append(("preshape", angle))
        self.hand.preshape(angle)

    def guarded_close(self):
        self.calls.append(("close",))
        g = self.hand.guarded_close()
        if self.extra is None:
            return g
        from activetouch.planning.motion.floating import wrist_joints_to_pose

        # The extra point, in the hand frame at the current wrist pose.
        pose = self.wrist.placement.to_object(
            wrist_joints_to_pose(self.wrist.arm.joint_state().position)
        )
        from scipy.spatial.transform import Rotation

        p = Rotation.from_quat(pose.quat).inv().apply(self.extra - pose.xyz)
        return Grasp(
            np.append(g.sensor_ids, 27),
            np.vstack([g.xyz, p]),
            np.append(g.pressures, 99.0),
            g.finger_angles,
            g.preshape,
        )


def _session_on_fakes(home, model, hand_wrap, max_moves=3):
    from activetouch.config import load_config
    from activetouch.devices import make_devices
    from activetouch.planning.motion.base import workcell_placement

    cfg = load_config(None, ["hand.type=fake", "arm.type=fake"])
    devices = make_devices(cfg, home)
    devices.ctx.place("cup")
    devices.wrist.set_placement(devices.placement())
    hand = hand_wrap(devices.hand)
    hand.wrist = devices.wrist
    policy = make_policy("random", cfg.planner, model.observation, model.classifier.kernel())
    placement = devices.placement()
    assert placement.xyz[2] != workcell_placement(cfg.workcell).xyz[2]  # the cup stands
    s = RecognitionSession(
        hand,
        devices.wrist,
        model,
        policy,  # type: ignore[arg-type]
        type(cfg.session)(max_moves=max_moves, confidence=1.1),
        np.random.default_rng(0),
        support_z=placement.support_z(cfg.workcell.table_top_z),
    )
    return s.run(), hand


def test_the_session_sets_the_training_preshape_before_each_grasp(trained_home, small_model):
    model = small_model
    model.config.setdefault("grid", {})
    saved = model.config["grid"].get("preshape", 0.0)
    model.config["grid"]["preshape"] = 0.8  # as if training had grasped spherically
    try:
        res, hand = _session_on_fakes(trained_home, model, RecordingHand)
    finally:
        model.config["grid"]["preshape"] = saved
    assert res.moves == 3
    closes = [i for i, c in enumerate(hand.calls) if c[0] == "close"]
    assert len(closes) == 3
    for i in closes:  # right before every close: the training preshape
        assert hand.calls[i - 1] == ("preshape", 0.8)


def test_table_contacts_are_dropped_on_a_non_twin_device(trained_home, small_model):
    """The fake devices have no table of their own: the table plane comes from the workcell,
    and a contact reported on it never reaches the histogram."""
    from activetouch.config import load_config

    top = load_config().workcell.table_top_z
    plain, hand = _session_on_fakes(trained_home, small_model, RecordingHand, 2)
    half = hand.wrist.placement.xyz[2] - top  # the cup stands on the table: half its height

    def adding(z_above_table):
        point = np.array([0.05, 0.0, -half + z_above_table])  # object frame
        return lambda h: RecordingHand(h, extra_object_point=point)

    on_table, _ = _session_on_fakes(trained_home, small_model, adding(0.001), 2)
    assert on_table.pose_ids == plain.pose_ids
    for a, b in zip(on_table.contacts, plain.contacts, strict=True):
        np.testing.assert_allclose(a, b)
    np.testing.assert_allclose(on_table.counts, plain.counts)
    # 3 cm above the table it is the object's: kept (so the test can tell the difference).
    above, _ = _session_on_fakes(trained_home, small_model, adding(0.03), 2)
    assert sum(map(len, above.contacts)) == sum(map(len, plain.contacts)) + 2


class ReachWrist(WristMotion):
    """Wraps a wrist motion and says which poses it reaches (`reach(i)` for pose index i),
    as Baxter's motion layer does; records the poses it was asked to move to."""

    def __init__(self, wrist, reach):
        self.wrist, self.reach = wrist, reach
        self.asked: list[int] = []  # how many poses each reachable() call got
        self.moved: list[np.ndarray] = []

    def reachable(self, poses: np.ndarray) -> np.ndarray:
        self.asked.append(len(poses))
        return np.array([self.reach(i) for i in range(len(poses))])

    def move_to(self, pose: Pose) -> None:
        self.moved.append(pose.as_array())
        self.wrist.move_to(pose)

    @property  # type: ignore[override]
    def robot_seconds(self) -> float:
        return self.wrist.robot_seconds

    @property  # type: ignore[override]
    def planning_seconds(self) -> float:
        return self.wrist.planning_seconds


def _twin_session(home, model, wrist_wrap=None, seed=3, max_moves=6, on_progress=None):
    """A tree-policy session on a fresh floating twin with the bottle; also the durations of
    the trajectories the twin's arm completed."""
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(home))
    pol = make_policy("tree", cfg.planner, model.observation, model.classifier.kernel())
    with open_twin(lib.get("bottle"), cfg.sim, seed=seed) as twin:
        durations: list[float] = []
        execute = twin.wrist.arm.execute

        def recording(traj):  # the trajectories the twin's arm completed
            execute(traj)
            durations.append(float(traj.times[-1] - traj.times[0]))

        twin.wrist.arm.execute = recording
        wrist = wrist_wrap(twin.wrist) if wrist_wrap else twin.wrist
        s = RecognitionSession(
            twin.hand,
            wrist,
            model,
            pol,  # type: ignore[arg-type]
            type(cfg.session)(max_moves=max_moves, rezero_readings=8),
            np.random.default_rng(seed),
            on_progress,
            support_z=twin.support_z,
        )
        rezero, rezeros = s._rezero, []

        def counted(res):  # each re-zero before a grasp waits for its readings
            rezeros.append(1)
            rezero(res)

        s._rezero = counted
        res = s.run()
        reads = len(rezeros) * s.cfg.rezero_readings * SIM_READING_PERIOD_S
        assert rezeros and reads > 0
        assert res.grasp_s == pytest.approx(twin.hand.robot_seconds + reads)  # the twin's
        return res, wrist, durations


def test_robot_time_of_a_floating_twin_recognition(trained_home, small_model):
    events = []
    res, wrist, durations = _twin_session(trained_home, small_model, on_progress=events.append)
    assert res.moves >= 1 and len(durations) == res.moves
    assert res.motion_s == pytest.approx(sum(durations), rel=1e-9) and res.motion_s > 0
    assert res.motion_s == pytest.approx(wrist.robot_seconds)  # a fresh twin: all of it
    assert res.motion_planning_s == 0.0  # a floating wrist plans nothing
    # The twin's hand keeps robot time (spool steps at the 40 Hz packet rate; `_twin_session`
    # checks grasp_s is the hand's own count), not wall time: a ReFlex close takes about a
    # second. (Not compared with the wall time: on a cold start compiling takes longer.)
    assert 0.3 < res.grasp_s / res.moves < 3.0
    assert res.planning_s == res.search_s  # no motion planning
    assert res.total_s == pytest.approx(res.motion_s + res.grasp_s + res.planning_s)
    # Robot time after each grasp: rising, the last one the whole recognition's.
    assert len(res.robot_s) == res.moves and res.robot_s == sorted(res.robot_s)
    assert res.robot_s[-1] == pytest.approx(res.total_s)
    assert res.unreachable == 0 and res.reachability_s == 0.0
    moved = [e.motion_s for e in events]
    assert moved == sorted(moved) and moved[-1] == pytest.approx(res.motion_s)


def test_unreachable_poses_are_ruled_out_before_the_first_grasp(trained_home, small_model):
    """A wrist with `reachable` is asked once for every model pose; the unreachable ones are
    never moved to, never skipped, never planned; with every pose reachable the session is the
    one without the check (the floating twin's results do not change)."""
    n = len(small_model.observation.pose_xyz)
    plain, _, _ = _twin_session(trained_home, small_model)
    every, w_all, _ = _twin_session(
        trained_home, small_model, lambda w: ReachWrist(w, lambda i: True)
    )
    assert w_all.asked == [n] and every.unreachable == 0
    assert every.pose_ids == plain.pose_ids and every.labels == plain.labels
    assert every.probabilities == plain.probabilities

    # Rule out the poses the plain run grasped at (and every third one).
    out = set(plain.pose_ids) | set(range(0, n, 3))
    res, w, _ = _twin_session(
        trained_home, small_model, lambda w: ReachWrist(w, lambda i: i not in out)
    )
    assert w.asked == [n] and res.unreachable == len(out)
    assert res.moves >= 1 and not set(res.pose_ids) & out
    poses = np.concatenate(
        [small_model.observation.pose_xyz, small_model.observation.pose_quat], axis=1
    )
    for p in w.moved:
        i = int(np.argmin(np.linalg.norm(poses - p, axis=1)))
        assert i not in out
    assert len(w.moved) == res.moves + res.skipped  # skips: only poses that were tried


def test_recognize_in_twin_runs_other_arms_on_the_configured_devices(
    trained_home, small_model, monkeypatch
):
    """`arm.type` other than twin-floating: recognize_in_twin places the object through the
    devices' sim/place (the fakes here: no physics) and reports their robot seconds."""
    from activetouch.config import load_config
    from activetouch.sim import twin

    cfg = load_config(None, ["grid.step_deg=40", "hand.type=fake", "arm.type=fake"])
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    with monkeypatch.context() as mp:
        mp.setattr(twin, "open_twin", lambda *a, **k: pytest.fail("opened the floating twin"))
        res = recognize_in_twin(small_model, lib, "sphere", "random", 0, cfg, max_moves=6)
        again = recognize_in_twin(small_model, lib, "sphere", "random", 0, cfg, max_moves=6)
    assert 1 <= res.moves <= 6 and res.pose_ids == again.pose_ids
    assert sum(len(c) for c in res.contacts) > 0  # the fake hand replayed sphere grasps
    assert res.motion_s > 0 and res.motion_s == pytest.approx(again.motion_s)
    floating = _run(trained_home, small_model, obj="sphere", max_moves=4)
    assert floating.motion_s > 0


def test_the_grasp_likelihood_belief_is_what_the_session_reports_and_plans_on(
    trained_home, small_model
):
    """recognition.belief=grasp_likelihood: p after every grasp is Bayes' rule over the grasps
    made (recomputed here from what the hand felt), and every plan starts from that belief."""
    cfg = small_config()
    cfg.recognition.belief = "grasp_likelihood"
    lik, params = grasp_likelihood_of(small_model, cfg.recognition)
    pol = make_policy(
        "tree",
        cfg.planner,
        small_model.observation,
        small_model.classifier.kernel(),
        belief_table_of(small_model, cfg.recognition),
    )
    planned_from: dict[int, np.ndarray] = {}  # grasps made -> the belief a plan started from
    plan = pol.plan

    def spying(state, rng):
        planned_from[len(felt)] = state.log_belief.copy()
        return plan(state, rng)

    pol.plan = spying  # type: ignore[method-assign]
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    felt: list[tuple[Grasp, Pose]] = []
    with open_twin(lib.get("bottle"), cfg.sim, seed=4) as twin:
        session = RecognitionSession(
            twin.hand,
            twin.wrist,
            small_model,
            pol,
            type(cfg.session)(max_moves=5),
            np.random.default_rng(4),
            support_z=twin.support_z,
            recognition=cfg.recognition,
        )
        grasp_at = session._grasp_at

        def recording(pose_id, pose):
            g = grasp_at(pose_id, pose)
            felt.append((g, pose))
            return g

        session._grasp_at = recording  # type: ignore[method-assign]
        res = session.run()
    assert res.moves == len(felt) >= 2
    assert planned_from and 0 not in planned_from
    log_b = np.zeros(len(SMALL_OBJECTS))
    for i, (g, pose) in enumerate(felt, 1):
        log_b += lik.log_likelihood(g, pose, params)
        np.testing.assert_allclose(res.probabilities[i - 1], softmax_belief(log_b), atol=1e-12)
        if i in planned_from:  # a plan after i grasps starts from the belief after them
            np.testing.assert_allclose(planned_from[i], log_b, atol=1e-12)
    # The histogram belief (the default) gives other probabilities for the same session.
    plain = _run(trained_home, small_model, "bottle", "random", seed=4, max_moves=3)
    cfg_b = small_config()
    cfg_b.recognition.belief = "grasp_likelihood"
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    bayes = recognize_in_twin(small_model, lib, "bottle", "random", 4, cfg_b, max_moves=3)
    assert plain.pose_ids == bayes.pose_ids
    assert not np.allclose(plain.probabilities, bayes.probabilities)


def test_a_model_without_a_grasp_likelihood_says_to_retrain(trained_home, small_model):
    cfg = small_config()
    cfg.recognition.belief = "grasp_likelihood"
    old = dataclasses.replace(small_model, likelihood=None)
    with pytest.raises(ConfigError, match="retrain"):
        belief_table_of(old, cfg.recognition)
    with pytest.raises(ConfigError, match="retrain"):
        recognize_in_twin(
            old, ObjectLibrary(paths.objects_dir(trained_home)), "cup", "random", 0, cfg
        )
    older = dataclasses.replace(
        small_model,
        observation=dataclasses.replace(small_model.observation, out_grasp=np.zeros(0, np.int64)),
    )
    with pytest.raises(ConfigError, match="retrain"):
        belief_table_of(older, cfg.recognition)


def test_a_stuck_sensor_is_ignored_for_the_whole_recognition(trained_home, small_model):
    # Issue 24: the sensor that reads contact with the hand open before the first grasp is
    # masked (no finger stops on it) and none of its contacts reaches the belief.
    cfg = small_config()
    cfg.sim.fault_stuck = 1
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    res = recognize_in_twin(small_model, lib, "cup", "tree", 3, cfg, max_moves=4)
    with open_twin(lib.get("cup"), cfg.sim, seed=3) as twin:
        stuck = twin.hand.faulty.stuck.tolist()
    assert res.masked_sensors == stuck and len(stuck) == 1
    nominal = recognize_in_twin(small_model, lib, "cup", "tree", 3, small_config(), max_moves=4)
    assert nominal.masked_sensors == []
    assert res.masked_reasons == {stuck[0]: "in contact with the hand open"}


def test_before_each_grasp_drifting_zeros_are_followed_and_runaway_ones_masked(
    trained_home, small_model
):
    # Sensor zeros walking up to +-60 units a grasp; a contact is 20 units over the zero.
    # Before each grasp after the first the session reads the open hand again: a sensor that
    # walked past its threshold since the last reading is masked from then on and reported
    # with the grasp it was found before; every other sensor's threshold moves with its zero,
    # so one walking 9 to 16 units a grasp stays and reads no more contacts than without the
    # walk (held to the start's thresholds it would read contact at rest by the third grasp).
    # With the start's rest levels alone (rezero_readings=0) every sensor walking up ends in
    # the grasps' contacts. Random grasps, no early stop: the same poses each time.
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    counts: dict[str, list[int]] = {}

    def run(name: str, drift: float, rezero: int):
        cfg = small_config()
        cfg.sim.fault_sensor_drift = drift
        cfg.session.rezero_readings = rezero
        cfg.session.confidence = 2.0
        counts[name] = []
        return recognize_in_twin(
            small_model,
            lib,
            "cup",
            "random",
            7,
            cfg,
            max_moves=5,
            on_progress=lambda p: counts[name].append(p.n_contacts),
        )

    drifting, nominal, stale = run("drift", 60.0, 8), run("nominal", 0.0, 8), run("stale", 60.0, 0)
    assert drifting.pose_ids == nominal.pose_ids == stale.pose_ids and len(nominal.pose_ids) == 5
    # The result names the policy it planned with, not the configured one (tree).
    assert nominal.settings["planner.policy"] == "random" and nominal.profile == "robust"
    cfg = small_config()
    cfg.sim.fault_sensor_drift = 60.0
    with open_twin(lib.get("cup"), cfg.sim, seed=7) as twin:
        rate = twin.hand.faulty.drift_rate
    fast = {int(i) for i in np.flatnonzero(rate > 24.0)}
    followed = {int(i) for i in np.flatnonzero((rate > 4.0) & (rate < 16.0))}
    assert len(fast) >= 3 and len(followed) >= 3
    assert fast <= set(drifting.masked_sensors) <= {int(i) for i in np.flatnonzero(rate > 16.0)}
    assert {drifting.masked_reasons[i] for i in fast} == {
        "in contact with the hand open before grasp 2"
    }
    assert nominal.masked_sensors == [] and stale.masked_sensors == []
    # Followed, the drifting zeros add nothing: each grasp feels at most what the nominal hand
    # felt (less the masked sensors' share); stale, the late grasps fill with drifting sensors.
    assert all(d <= n for d, n in zip(counts["drift"], counts["nominal"], strict=True))
    assert sum(counts["stale"][2:]) >= sum(counts["nominal"][2:]) + 10


def test_dead_sensors_are_found_at_rest_and_left_out_of_the_likelihood(trained_home, small_model):
    # A dead sensor reads exactly nothing at rest while the others show their noise: it is
    # masked and reported, and the grasp likelihood compares the other sensors only.
    cfg = small_config()
    cfg.sim.fault_dead = 3
    cfg.recognition.belief = "grasp_likelihood"
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    res = recognize_in_twin(small_model, lib, "cup", "greedy", 5, cfg, max_moves=3)
    with open_twin(lib.get("cup"), cfg.sim, seed=5) as twin:
        dead = sorted(twin.hand.faulty.dead.tolist())
    assert res.masked_sensors == dead
    assert set(res.masked_reasons.values()) == {"reads nothing at rest (dead)"}


def test_with_pose_follow_the_grasps_go_where_the_object_is_believed_to_stand(
    trained_home, small_model
):
    # Issue 24: the object stands up to 2 cm off its nominal placement (not turned: the
    # objects are round, their yaw cannot be felt). Following the pose belief's estimate, the
    # grasps after the first land on the object as it really stands nearer their training
    # poses, on average within half the error; at the nominal placement they land the whole
    # error away.
    from activetouch.recognition.grasp_likelihood import poses_under_offsets
    from activetouch.sim.twin import placement_error

    lib = ObjectLibrary(paths.objects_dir(trained_home))
    obs = small_model.observation
    train = np.concatenate([obs.pose_xyz, obs.pose_quat], axis=1)

    def gaps(follow: bool, obj: str, seed: int) -> tuple[np.ndarray, float]:
        cfg = small_config()
        cfg.sim.placement_error_m = 0.02
        cfg.recognition.pose_follow = follow
        seen = []
        recognize_in_twin(
            small_model, lib, obj, "greedy", seed, cfg, max_moves=4, on_progress=seen.append
        )
        err = placement_error(cfg.sim, seed)
        true = np.array([[err.dx, err.dy, err.yaw_rad]])
        assert err.yaw_rad == 0.0
        np.testing.assert_array_equal(seen[0].pose, train[seen[0].pose_id])  # as trained
        on_object = [poses_under_offsets(s.pose, true)[0] for s in seen]
        gap = [
            np.linalg.norm(p[:3] - train[s.pose_id][:3])
            for p, s in zip(on_object, seen, strict=True)
        ]
        return np.array(gap), float(np.hypot(err.dx, err.dy))

    for obj, seed in (("bottle", 1), ("cup", 2)):
        nominal, off = gaps(False, obj, seed)
        followed, _ = gaps(True, obj, seed)
        np.testing.assert_allclose(nominal, off, atol=1e-9)  # every grasp the error away
        assert off > 0.01 and np.all(followed[1:] < nominal[1 : len(followed)])
        assert followed[1:].mean() < 0.5 * off


def test_under_heavy_noise_the_contacts_are_decided_on_the_mean_of_the_closed_hand(
    trained_home, small_model
):
    # Noise +10 lifts every threshold to about 51 units: the close's own reading keeps only
    # firm contacts. Decided on the mean of 8 readings of the closed hand, the grasps at the
    # same poses report more of the sensors they press. A quiet hand (thresholds under the
    # hand's own 20) is read as before: the same recognition, grasp for grasp.
    lib = ObjectLibrary(paths.objects_dir(trained_home))

    def run(noise: float, readings: int) -> tuple[list[int], list[int], list[str]]:
        cfg = small_config()
        cfg.sim.fault_noise_std = noise
        cfg.session.average_readings = readings
        seen: list[Progress] = []
        res = recognize_in_twin(
            small_model, lib, "cup", "random", 6, cfg, max_moves=4, on_progress=seen.append
        )
        return res.pose_ids, [p.n_contacts for p in seen], res.labels

    assert run(0.0, 8) == run(0.0, 0)
    poses, close, _ = run(10.0, 0)
    poses_avg, averaged, _ = run(10.0, 8)
    assert poses_avg == poses  # the random policy's draws do not depend on the contacts
    assert sum(averaged) > sum(close), (close, averaged)
    with pytest.raises(ConfigError, match="set one of them to 0"):
        cfg = small_config()
        cfg.session.average_readings, cfg.session.confirm_readings = 4, 2
        recognize_in_twin(small_model, lib, "cup", "random", 6, cfg, max_moves=1)


def test_a_hand_that_stops_streaming_after_the_close_is_judged_on_the_readings_it_gave(
    trained_home, small_model, caplog
):
    # After each close this hand repeats one stamp (a stream gone quiet): the session gets
    # one new reading, not 16, within its 2 s, says so, and judges that one reading against
    # the thresholds for one, so no noise sensor passes for a contact.
    from activetouch.interfaces import HandState, HandWrapper

    class QuietAfterClose(HandWrapper):
        frozen: HandState | None = None

        def guarded_close(self) -> Grasp:
            g = self.inner.guarded_close()
            self.frozen = self.inner.state()
            return g

        def open(self) -> None:
            self.frozen = None
            self.inner.open()

        def state(self) -> HandState:
            return self.frozen if self.frozen is not None else self.inner.state()

    cfg = small_config()
    cfg.sim.fault_noise_std = 10.0
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    with open_twin(lib.get("cup"), cfg.sim, seed=6) as twin:
        s = _random_session(QuietAfterClose(twin.hand), twin.wrist, small_model, cfg, max_moves=2)
        seen: list[Grasp] = []
        close = s.sensors.averaged
        s.sensors.averaged = lambda g: seen.append(close(g)) or seen[-1]  # type: ignore[method-assign]
        with caplog.at_level("WARNING"):
            s.run()
        assert s.sensors.averaging is not None
        rest, own = s.sensors.averaging
    assert "gave 1 of 16 readings after the close" in caplog.text
    one = np.maximum(rest.mean + 5.0 * np.maximum(rest.std, np.median(rest.std)), own)
    for g in seen:
        assert np.all(g.pressures > one[g.sensor_ids])  # one reading, one reading's thresholds
