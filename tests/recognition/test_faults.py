"""Sensor faults as pure transforms of the 38 pressures."""

from __future__ import annotations

import numpy as np
import pytest

from activetouch.interfaces import N_SENSORS
from activetouch.recognition.faults import (
    STUCK_FACTOR,
    SensorFaults,
    draw_faulty_sensors,
    fault_rng,
    faulty_reading,
    spurious_contacts,
)


def test_faulty_sensors_repeat_per_seed_and_are_disjoint():
    f = SensorFaults(dead=4, stuck=3)
    a, b = draw_faulty_sensors(f, 7), draw_faulty_sensors(f, 7)
    np.testing.assert_array_equal(a.dead, b.dead)
    np.testing.assert_array_equal(a.stuck, b.stuck)
    assert len(a.dead) == 4 and len(a.stuck) == 3
    assert not set(a.dead) & set(a.stuck)
    others = [draw_faulty_sensors(f, s).dead.tolist() for s in range(5)]
    assert len({tuple(o) for o in others}) > 1  # the seed picks them


def test_dead_read_zero_stuck_read_over_threshold_noise_moves_the_rest():
    f = SensorFaults(noise_std=3.0, dead=2, stuck=2)
    s = draw_faulty_sensors(f, 1)
    p = np.full(N_SENSORS, 50.0)
    out = faulty_reading(p, f, s, 20.0, fault_rng(1))
    assert np.all(out[s.dead] == 0.0)
    assert np.all(out[s.stuck] == STUCK_FACTOR * 20.0)
    rest = np.setdiff1d(np.arange(N_SENSORS), np.concatenate([s.dead, s.stuck]))
    assert np.all(out[rest] != 50.0) and abs(out[rest].mean() - 50.0) < 3.0
    assert np.all(p == 50.0)  # the input is not changed


def test_no_faults_is_the_identity():
    f = SensorFaults()
    assert not f.active
    p = np.arange(N_SENSORS, dtype=float)
    np.testing.assert_array_equal(
        faulty_reading(p, f, draw_faulty_sensors(f, 0), 20, fault_rng(0)), p
    )


def test_spurious_contacts_only_on_quiet_live_sensors():
    f = SensorFaults(dead=5, spurious=1.0)
    s = draw_faulty_sensors(f, 3)
    touching = np.zeros(N_SENSORS, dtype=bool)
    touching[[0, 1, 2]] = True
    extra = spurious_contacts(touching, f, s, fault_rng(3))
    expected = set(range(N_SENSORS)) - {0, 1, 2} - set(s.dead.tolist())
    assert set(extra.tolist()) == expected
    rate = SensorFaults(spurious=0.1)
    n = [
        len(spurious_contacts(np.zeros(N_SENSORS, bool), rate, s, fault_rng(i))) for i in range(200)
    ]
    assert 2.5 < np.mean(n) < 5.0  # about 0.1 x 38 per grasp


@pytest.mark.parametrize(
    "kwargs", [{"noise_std": -1.0}, {"dead": 30, "stuck": 10}, {"spurious": 1.5}, {"stuck": -1}]
)
def test_out_of_range_faults_are_refused(kwargs):
    with pytest.raises(ValueError):
        SensorFaults(**kwargs)


def test_sensor_drift_grows_with_the_grasps_done_and_keeps_the_other_faults():
    f = SensorFaults(dead=4, stuck=1, drift=2.0)
    s = draw_faulty_sensors(f, 3)
    plain = draw_faulty_sensors(SensorFaults(dead=4, stuck=1), 3)
    np.testing.assert_array_equal(s.dead, plain.dead)  # adding drift pairs with the level
    np.testing.assert_array_equal(s.stuck, plain.stuck)
    assert np.all(np.abs(s.drift_rate) <= 2.0) and np.ptp(s.drift_rate) > 1.0
    p = np.full(N_SENSORS, 10.0)
    at = [faulty_reading(p, f, s, 20.0, fault_rng(0), grasps_done=k) for k in (0, 5)]
    live = np.setdiff1d(np.arange(N_SENSORS), np.concatenate([s.dead, s.stuck]))
    np.testing.assert_allclose(at[0][live], 10.0)  # the zeros hold when they were measured
    np.testing.assert_allclose(at[1][live], 10.0 + 5 * s.drift_rate[live])
    assert np.all(at[1][s.dead] == 0.0)


def test_finger_offsets_are_drawn_within_their_bound_per_seed():
    f = SensorFaults(finger_offset_rad=0.05)
    a, b = draw_faulty_sensors(f, 11), draw_faulty_sensors(f, 11)
    np.testing.assert_array_equal(a.finger_offset, b.finger_offset)
    assert a.finger_offset.shape == (3,) and np.all(np.abs(a.finger_offset) <= 0.05)
    assert f.active and not SensorFaults().active
    assert not draw_faulty_sensors(SensorFaults(), 11).finger_offset.any()


@pytest.mark.parametrize("kwargs", [{"drift": -1.0}, {"finger_offset_rad": 0.7}])
def test_out_of_range_drift_is_refused(kwargs):
    with pytest.raises(ValueError):
        SensorFaults(**kwargs)
