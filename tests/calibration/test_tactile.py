"""Tactile calibration: the pure fit on synthetic samples with known truth, then against the
TakkTile emulator and an independent hand-built packet source through the real driver."""

from __future__ import annotations

import numpy as np
import pytest

from activetouch.calibration import store
from activetouch.calibration.tactile import (
    CalibrationRefusedError,
    TactileSettings,
    apply_tactile,
    calibrate_tactile,
    fit_tactile,
    touching_reasons,
)
from activetouch.drivers.reflex.takktile import ReflexTakktileConfig, ReflexTakktileHand
from activetouch.emulators.reflex_takktile import (
    EmulatorConfig,
    Faults,
    KinematicFingers,
    TakktileEmulator,
)

from .board import NoisyBoard, free_udp_port


def synthetic(n=80, noise=2.0, seed=0):
    rng = np.random.default_rng(seed)
    offsets = rng.uniform(200, 900, 38)
    t = np.arange(n) / 40.0
    raw = np.rint(offsets + rng.normal(0, noise, (n, 38)))
    return t, raw, offsets


def test_fit_recovers_offsets_and_noise_within_a_count():
    t, raw, offsets = synthetic(noise=2.0)
    fit = fit_tactile(t, raw, TactileSettings())
    assert np.max(np.abs(fit.zero - offsets)) < 1.0
    assert np.all((fit.sigma > 1.4) & (fit.sigma < 2.7))
    assert np.all(fit.threshold == 20.0)  # 6 sigma < the 20-count minimum
    assert fit.dead == fit.saturated == fit.drifting == []


def test_fit_ignores_glitched_packets():
    t, raw, offsets = synthetic(noise=2.0, seed=1)
    raw[10, 3] += 4000  # a corrupted packet
    raw[50, :] += 900  # a whole glitched packet
    fit = fit_tactile(t, raw, TactileSettings())
    assert np.max(np.abs(fit.zero - offsets)) < 1.0
    assert fit.outliers[3] >= 2
    # reflex-ros-pkg's one-sample zero would be off by the noise or by the glitch
    assert np.max(np.abs(raw[50] - offsets)) > 800


def test_fit_flags_dead_saturated_and_drifting():
    t, raw, offsets = synthetic(noise=2.0, seed=2)
    raw[:, 4] = 512  # dead: no variation
    raw[:, 7] = 0  # dead: stuck at zero
    raw[:, 30] = 65535  # saturated
    raw[:, 12] += 10.0 * t  # drifts 20 counts in 2 s
    fit = fit_tactile(t, raw, TactileSettings())
    assert fit.dead == [4, 7]
    assert fit.saturated == [30]
    assert fit.drifting == [12]
    assert fit.threshold[4] == fit.threshold[30] == 65535.0
    assert abs(fit.drift[12] - 10.0 * t[-1]) < 2.0
    assert abs(fit.zero[12] - (offsets[12] + 10.0 * t[-1])) < 1.5  # what it reads now
    assert fit.threshold[12] > 20.0 + 15.0
    good = [i for i in range(38) if i not in (4, 7, 12, 30)]
    assert np.max(np.abs(fit.zero[good] - offsets[good])) < 1.0


def test_noisy_sensor_gets_a_higher_threshold():
    t, raw, _ = synthetic(noise=2.0, seed=3)
    raw[:, 20] += np.random.default_rng(9).normal(0, 8.0, len(t))
    fit = fit_tactile(t, raw, TactileSettings(k_sigma=6.0, min_threshold=20.0))
    assert fit.threshold[20] > 40.0
    assert fit.threshold[19] == 20.0
    assert fit.noisy == []  # 4x the others' sigma: a higher threshold, still in use


def test_a_sensor_far_noisier_than_the_rest_is_flagged_noisy():
    t, raw, _ = synthetic(noise=2.0, seed=4)
    raw[:, 9] += np.random.default_rng(1).normal(0, 15.0, len(t))  # ~7.5x the others
    raw[:, 4] = 512  # dead: its zero sigma does not lower the median
    fit = fit_tactile(t, raw, TactileSettings())
    assert fit.noisy == [9] and fit.dead == [4]
    from activetouch.calibration.tactile import flags_by_sensor, rec_flags

    assert flags_by_sensor(rec_flags(fit)) == {4: "dead", 9: "noisy"}


def test_touching_reasons():
    st = TactileSettings()
    prev = np.full(38, 500.0)
    med = prev.copy()
    assert touching_reasons(med, np.zeros(3), st, prev, np.full(38, 20.0)) == []
    med[5] += 200
    r = touching_reasons(med, np.zeros(3), st, prev, np.full(38, 20.0))
    assert len(r) == 1 and "sensor 5" in r[0]
    r = touching_reasons(prev, np.array([0.0, 0.6, 0.0]), st, prev, None)
    assert len(r) == 1 and "fingers not open" in r[0]


def test_too_few_samples_refused():
    t, raw, _ = synthetic(n=5)
    with pytest.raises(CalibrationRefusedError, match="only 5 samples"):
        fit_tactile(t, raw, TactileSettings())


# -- through the driver ---------------------------------------------------------------------


def _driver(state_port, command_port, **kw):
    # 0.6 s, not the driver's 0.2 s: a loaded 2-core machine can hold the emulator's thread.
    kw.setdefault("stream_timeout_s", 0.6)
    cfg = ReflexTakktileConfig(
        type="reflex-takktile",
        state_listen=f"127.0.0.1:{state_port}",
        command_to=f"127.0.0.1:{command_port}",
        multicast_group="",
        **kw,
    )
    return ReflexTakktileHand(cfg)


MOTOR_ZERO = (56.0, 57.0, 55.5, 53.0)  # joint side
GEAR = (1.42, 1.42, 1.42, 1.5)


@pytest.fixture
def emulated(request):
    """Emulator with injected offsets, the default twin noise (2 counts) and stuck sensors;
    a driver configured with no offsets (as a fresh hand)."""
    state_port, cmd_port = free_udp_port(), free_udp_port()
    rng = np.random.default_rng(7)
    offsets = rng.uniform(150.0, 1200.0, 38)
    emu = TakktileEmulator(
        EmulatorConfig(
            state_to=f"127.0.0.1:{state_port}",
            command_listen=f"127.0.0.1:{cmd_port}",
            motor_zero_rad=MOTOR_ZERO,
            baselines=offsets.tolist(),
            noise_std=2.0,
            seed=3,
            faults=Faults(stuck_zero=[8], stuck_saturated=[33]),
        ),
        KinematicFingers(
            contact_spool=[0.6, 0.6, 0.6], contact_sensors=[[2, 3], [11, 12], [20, 21]]
        ),
    ).start()
    hand = _driver(
        state_port,
        cmd_port,
        motor_zero_points=[z * g for z, g in zip(MOTOR_ZERO, GEAR, strict=True)],
    )
    hand.connect()
    yield emu, hand, offsets
    hand.disconnect()
    emu.stop()


def test_emulator_offsets_recovered_and_faults_flagged(emulated, tmp_path):
    _emu, hand, offsets = emulated
    rec, _fit = calibrate_tactile(hand, "emu", TactileSettings(duration_s=2.0))
    good = [i for i in range(38) if i not in (8, 33)]
    err = np.abs(np.asarray(rec.values["zero"])[good] - offsets[good])
    assert err.max() < 1.0, err.max()
    assert rec.values["flags"]["dead"] == [8]
    assert rec.values["flags"]["saturated"] == [33]
    assert rec.values["flags"]["drifting"] == []
    assert rec.quality["n_samples"] >= 60
    # stored, reloaded, applied: the hand now reads about zero and no contact
    store.save(tmp_path, rec)
    back = store.load(tmp_path, "tactile", "emu")
    assert back.values["zero"] == rec.values["zero"]
    assert apply_tactile(hand, back.values["zero"], back.values["threshold"])
    s = hand.state()
    assert np.max(np.abs(s.pressures[good])) < 12.0
    assert not s.contact.any()


def test_emulator_refuses_when_fingers_closed_on_something(emulated):
    _emu, hand, _offsets = emulated
    # First calibration: fine. Then close on the object: pads press, fingers not open.
    rec, _ = calibrate_tactile(hand, "emu", TactileSettings(duration_s=1.0))
    apply_tactile(hand, rec.values["zero"], rec.values["threshold"])
    g = hand.guarded_close()
    assert len(g.sensor_ids) >= 3
    with pytest.raises(
        CalibrationRefusedError, match=r"fingers not open|above their previous zero"
    ):
        calibrate_tactile(hand, "emu", TactileSettings(duration_s=1.0, open_first=False), rec)


def test_independent_board_drift_and_touch_refusal():
    """Hand-built packets (not the emulator, not the codec) with known offsets, noise, a
    drifting, a dead and a saturated sensor, through the real driver."""
    rng = np.random.default_rng(11)
    offsets = rng.uniform(100.0, 3000.0, 38)
    with NoisyBoard(
        offsets, noise=2.0, seed=5, drift_per_s={17: 12.0}, dead={2: 777}, saturated=[29]
    ) as board:
        hand = _driver(board.state_port, board.command_port)
        hand.connect()
        try:
            st = TactileSettings(duration_s=2.0, open_first=False)
            rec, _fit = calibrate_tactile(hand, "board", st)
            good = [i for i in range(38) if i not in (2, 17, 29)]
            zero = np.asarray(rec.values["zero"])
            assert np.max(np.abs(zero[good] - offsets[good])) < 1.0
            assert rec.values["flags"] == {
                "dead": [2],
                "saturated": [29],
                "drifting": [17],
                "noisy": [],
            }
            # Something presses on sensor 22: refused against the stored zero.
            board.extra[22] = 300.0
            with pytest.raises(CalibrationRefusedError, match="sensor 22"):
                calibrate_tactile(
                    hand, "board", TactileSettings(duration_s=0.5, open_first=False), rec
                )
        finally:
            hand.disconnect()


def test_load_into_applies_stored_records_and_warns_when_missing(emulated, tmp_path, caplog):
    from activetouch.calibration.apply import load_into

    _emu, hand, offsets = emulated
    rec, _ = calibrate_tactile(hand, "emu", TactileSettings(duration_s=1.0))
    store.save(tmp_path, rec)
    hand.offsets = np.zeros(38)
    used = load_into(hand, "emu", tmp_path)
    assert used["tactile"] is not None and used["fingers"] is None
    # the driver knows the flagged sensors, so a recognition ignores them
    assert set(hand.sensor_flags()) == {8, 33}
    assert "run `activetouch calibrate fingers`" in caplog.text
    good = [i for i in range(38) if i not in (8, 33)]
    assert np.max(np.abs(hand.offsets[good] - offsets[good])) < 1.5
