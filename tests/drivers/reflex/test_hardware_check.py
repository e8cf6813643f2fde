"""`activetouch hardware check` on a TakkTile hand played by the emulator at upstream's
baselines with no calibration stored: the check says so, with the command, and moves nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from activetouch.calibration import store
from activetouch.calibration.store import CalibrationRecord
from activetouch.config import load_config
from activetouch.pipelines.hardware_check import FAIL, OK, hardware_check
from tests.drivers.reflex.conftest import driver_config


def steps_by_name(steps):
    return {(s.device, s.name): s for s in steps}


def test_an_uncalibrated_takktile_hand_fails_the_check_with_the_fix(
    ports, emulator, tmp_path: Path
):
    cfg = load_config(None, ["arm.type=fake"])
    cfg.hand = driver_config(*ports)
    spool = emulator.joint_state()
    steps = steps_by_name(hardware_check(cfg, tmp_path, seconds=0.5))
    assert steps[("hand", "connect")].status == OK
    assert steps[("hand", "stream")].status in (OK, "warn")  # a loaded machine polls slower
    tactile = steps[("hand", "tactile calibration")]
    assert tactile.status == FAIL and "calibrate tactile" in tactile.fix
    assert steps[("hand", "fingers calibration")].status == "warn"
    assert steps[("arm", "connect")].status == OK
    after = emulator.joint_state()
    # Nothing moved: the hold goals are the measured positions, within one servo tick.
    np.testing.assert_allclose(after[0], spool[0], atol=0.01)
    assert abs(after[1] - spool[1]) < 0.01


def test_a_calibrated_hand_passes_and_its_age_is_shown(ports, emulator, tmp_path: Path):
    cfg = load_config(None, ["arm.type=fake"])
    cfg.hand = driver_config(*ports)
    device = store.device_name(cfg, None)
    baselines = [300.0 + 10 * i for i in range(38)]  # the emulator's (conftest)
    store.save(
        tmp_path,
        CalibrationRecord("tactile", device, {"zero": baselines, "threshold": [20.0] * 38}),
    )
    steps = steps_by_name(hardware_check(cfg, tmp_path, seconds=0.5))
    assert steps[("hand", "tactile calibration")].status == OK
    assert "days old" in steps[("hand", "tactile calibration")].detail
    assert steps[("hand", "contacts at rest")].status == OK
