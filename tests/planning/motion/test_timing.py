import numpy as np
import pytest

from activetouch.planning.motion.timing import (
    path_limits,
    rest_to_rest,
    sample,
    straight_duration,
    time_path,
)

V = np.array([1.5] * 4 + [4.0] * 3)
A = np.full(7, 1.5)
J = np.full(7, 10.0)


def test_path_limits_scale_by_travel():
    v, a, j = path_limits(np.array([2.0, -0.5, 0, 0, 0, 0, 0]), V, A, J)
    assert v == pytest.approx(0.75) and a == pytest.approx(0.75) and j == pytest.approx(5.0)


def test_1khz_samples_within_limits_on_the_line_and_at_rest():
    rng = np.random.default_rng(0)
    wp = rng.uniform(-1.5, 1.5, (4, 7))
    segs = time_path(wp, V, A, J)
    assert len(segs) == 3
    t, p, v, a = sample(segs, 0.001)
    assert np.all(np.diff(t) > 0) and np.all(np.diff(t) <= 0.001 + 1e-12)
    assert np.all(np.abs(v) <= V * (1 + 1e-6))
    assert np.all(np.abs(a) <= A * (1 + 1e-6))
    np.testing.assert_allclose(p[0], wp[0])
    np.testing.assert_allclose(p[-1], wp[-1], atol=1e-9)
    np.testing.assert_allclose(v[-1], 0, atol=1e-9)
    # Finite differences agree with the reported velocities (the samples are one motion).
    np.testing.assert_allclose(
        np.diff(p, axis=0) / np.diff(t)[:, None], (v[1:] + v[:-1]) / 2, atol=2e-3
    )
    for seg in segs:  # straight lines between waypoints: what was collision-checked
        ts = np.linspace(0, seg.duration, 50)
        q = np.array([seg.at_time(x)[0] for x in ts])
        d = seg.end - seg.start
        s = (q - seg.start) @ d / (d @ d)
        np.testing.assert_allclose(q, seg.start + s[:, None] * d, atol=1e-12)
        assert np.all(np.diff(s) >= -1e-12)


def test_closed_form_duration_is_ruckigs():
    # Short moves (jerk only), medium (acceleration reached) and long (cruising at v).
    rng = np.random.default_rng(1)
    for scale in (1e-3, 1e-2, 0.1, 0.5, 2.0):
        for _ in range(10):
            a = rng.uniform(-1.5, 1.5, 7)
            b = a + rng.uniform(-1, 1, 7) * scale
            exact = rest_to_rest(a, b, V, A, J).duration
            assert straight_duration(b - a, V, A, J) == pytest.approx(exact, rel=1e-9)
    deltas = rng.uniform(-1, 1, (3, 4, 7))  # broadcasts over leading axes
    assert straight_duration(deltas, V, A, J).shape == (3, 4)
    assert straight_duration(np.zeros(7), V, A, J) == 0.0


def test_zero_length_steps_are_skipped():
    q = np.zeros(7)
    assert time_path(np.array([q, q]), V, A, J) == []
