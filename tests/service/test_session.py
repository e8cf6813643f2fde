from __future__ import annotations

import threading

import numpy as np
import pytest

from activetouch import paths
from activetouch.errors import ConfigError, UnreachableError
from activetouch.interfaces import Grasp, Pose
from activetouch.planning.policies import make_policy
from activetouch.service.recognize import recognize_in_twin
from activetouch.service.session import NO_LABEL, RecognitionSession, display_label
from activetouch.sim.objects import ObjectLibrary
from activetouch.sim.twin import open_twin

from .conftest import SMALL_OBJECTS, small_config


def _run(home, model, obj="cup", policy="tree", seed=0, **kw):
    lib = ObjectLibrary(paths.objects_dir(home))
    return recognize_in_twin(model, lib, obj, policy, seed, small_config(), **kw)


@pytest.mark.parametrize("policy", ["tree", "greedy", "random"])
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


def test_unreachable_poses_are_skipped_counted_and_not_retried(trained_home, small_model):
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(trained_home))
    policy = make_policy(
        "random", cfg.planner, small_model.observation, small_model.classifier.kernel()
    )
    with open_twin(lib.get("cup"), cfg.sim, seed=0) as twin:
        arm = FlakyWrist(twin.wrist)
        s = RecognitionSession(
            twin.hand,
            arm,
            small_model,
            policy,  # type: ignore[arg-type]
            type(cfg.session)(max_moves=5, confidence=1.1),
            np.random.default_rng(0),
        )
        res = s.run()
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
    # as a recognition of the cup.
    cfg = small_config()
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
        )
        res = s.run()
    assert events[0].top == []  # no ranking of a uniform distribution
    assert res.labels[0] == NO_LABEL
    assert res.probabilities[0] == pytest.approx([1 / 3] * 3)
    assert res.labels[1] != NO_LABEL or res.labels[2] != NO_LABEL
    assert display_label(NO_LABEL) != NO_LABEL
