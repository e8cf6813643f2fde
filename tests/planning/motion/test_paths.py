import numpy as np
import pytest

from activetouch.planning.motion import paths
from activetouch.planning.motion.baxter import BAXTER_TABLE_CENTER, BAXTER_TABLE_SIZE
from activetouch.planning.motion.collision import CollisionScene

READY = np.array([0.0, -0.55, 0.0, 1.25, 0.0, 0.87, 0.0])
STEP_RAD, STEP_M = 0.02, 0.01


@pytest.fixture(scope="module")
def scene(baxter):
    pytest.importorskip("ompl")
    return CollisionScene(baxter, BAXTER_TABLE_CENTER, BAXTER_TABLE_SIZE)


def plan(scene, baxter, time_s=1.0):
    q1 = READY + np.array([0.6, 0.0, 0.0, -0.3, 0.0, 0.0, 0.5])
    wp = paths.rrt_connect(
        scene, READY, q1, baxter.lower, baxter.upper, time_s, STEP_RAD, STEP_M, False
    )
    return q1, wp


def test_a_path_that_fails_the_dense_check_is_searched_again(scene, baxter, monkeypatch):
    real = paths.path_free
    verdicts: list[bool] = []

    def first_two_rejected(*args, **kwargs) -> bool:
        # The simplified path and then the raw one of the first search fail the re-check.
        verdicts.append(len(verdicts) >= 2 and real(*args, **kwargs))
        return verdicts[-1]

    monkeypatch.setattr(paths, "path_free", first_two_rejected)
    q1, wp = plan(scene, baxter)
    assert wp is not None and verdicts[:2] == [False, False] and verdicts[-1]
    np.testing.assert_allclose(wp[0], READY)
    np.testing.assert_allclose(wp[-1], q1)
    assert real(scene, wp, False, STEP_RAD, STEP_M)


def test_no_path_passing_the_dense_check_is_none_within_the_budget(scene, baxter, monkeypatch):
    checks: list[int] = []
    monkeypatch.setattr(paths, "path_free", lambda *a, **k: checks.append(1) and False)
    ticks = iter(np.arange(0.0, 100.0, 1.0))  # a clock 1 s on at every look, not wall time
    q1 = READY + np.array([0.6, 0.0, 0.0, -0.3, 0.0, 0.0, 0.5])
    wp = paths.rrt_connect(
        scene,
        READY,
        q1,
        baxter.lower,
        baxter.upper,
        3.5,
        STEP_RAD,
        STEP_M,
        False,
        clock=lambda: float(next(ticks)),
    )
    # Searched again while the budget lasted, then given up: None, not a path that failed
    # the check. The first round tries the shortcut and the raw path; the second (0.5 s for
    # OMPL) the raw one if OMPL finds one in time, and then the budget is spent.
    assert wp is None and len(checks) in (2, 3)
