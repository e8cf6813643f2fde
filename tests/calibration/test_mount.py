"""Mount calibration: the solver on exact synthetic touches, and the whole procedure in the
twin with a mount error whose true value the test knows (3 mm / 2 deg class)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from activetouch.calibration.mount import (
    MountSettings,
    Touch,
    calibrate_mount,
    solve_mount,
    touch_orientations,
)
from activetouch.calibration.probing import hand_points, lowest_point_start, onset_height
from activetouch.calibration.tactile import CalibrationRefusedError
from activetouch.interfaces import Pose

IDENTITY = Pose(np.zeros(3), [0, 0, 0, 1])
TRUE = Pose([0.003, -0.002, 0.004], Rotation.from_euler("xy", [2.0, -1.0], degrees=True).as_quat())


def synthetic_touches(true: Pose, noise_m: float = 0.0, seed: int = 0) -> list[Touch]:
    """Flange poses at which the true hand's lowest point is exactly on z = 0 (+ noise)."""
    rng = np.random.default_rng(seed)
    pts = hand_points()
    out = []
    for rot in touch_orientations(MountSettings()):
        # where the true hand touches: place it with the true mount, read the flange
        f = lowest_point_start(rot, true, pts, np.array([0.45, 0.0]), rng.normal(0, noise_m))
        f = Pose(f.xyz, f.quat)
        out.append(Touch(f, pts))
    return out


def errors(mount: Pose, true: Pose) -> tuple[float, float]:
    d = np.linalg.norm(mount.xyz - true.xyz)
    r = (Rotation.from_quat(mount.quat) * Rotation.from_quat(true.quat).inv()).magnitude()
    return float(d), float(np.degrees(r))


def test_compose_inverse():
    assert np.allclose(TRUE.compose(TRUE.inverse()).xyz, 0, atol=1e-12)


def test_solver_exact_touches():
    fit = solve_mount(synthetic_touches(TRUE), IDENTITY, 0.0)
    d, a = errors(fit.mount, TRUE)
    assert d < 0.5e-3 and a < 0.2, (d, a)
    assert fit.rms_m < 1e-5


def test_solver_noisy_touches_within_spec():
    fit = solve_mount(synthetic_touches(TRUE, noise_m=0.0001, seed=1), IDENTITY, 0.0)
    d, a = errors(fit.mount, TRUE)
    assert d < 2e-3 and a < 1.0, (d, a)


def test_implausible_correction_refused():
    big = Pose([0.0, 0.0, 0.03], [0, 0, 0, 1])  # 3 cm off: the configured mount is wrong
    with pytest.raises(CalibrationRefusedError, match="offset correction"):
        solve_mount(synthetic_touches(big), IDENTITY, 0.0)


def test_inconsistent_touches_refused():
    touches = synthetic_touches(TRUE)
    t = touches[3]
    touches[3] = Touch(Pose(t.flange.xyz + np.array([0, 0, 0.006]), t.flange.quat), t.points)
    touches[7] = Touch(
        Pose(touches[7].flange.xyz - [0, 0, 0.006], touches[7].flange.quat), t.points
    )
    with pytest.raises(CalibrationRefusedError, match="RMS residual"):
        solve_mount(touches, IDENTITY, 0.0, MountSettings(max_rms_m=0.0005))


def test_too_few_touches_refused():
    with pytest.raises(CalibrationRefusedError, match="touches"):
        solve_mount(synthetic_touches(TRUE)[:3], IDENTITY, 0.0)


def test_onset_height_extrapolates_to_zero_pressure():
    z = np.array([0.0010, 0.0008, 0.0006, 0.0004, 0.0002])
    p = np.clip(75_000 * (0.0007 - z), 0, None) + np.array([0.5, -0.3, 0.2, 0.1, -0.4])
    assert abs(onset_height(z, p, 10.0) - 0.0007) < 2e-5


@pytest.mark.slow
def test_twin_mount_recovered_within_2mm_1deg():
    from activetouch.calibration.probing import FloatingFlange
    from activetouch.calibration.sim import MountedArm
    from activetouch.config import SimConfig, WorkcellConfig
    from activetouch.sim.twin import open_twin

    wc = WorkcellConfig()
    # The twin's compound fingertip AABBs are conservative at a tilt (2-4 mm): allow the
    # press the probe needs.
    with open_twin(None, SimConfig(wrist_penetration_tol_m=0.006), workcell=wc) as tw:
        arm = MountedArm(tw.arm, TRUE)
        rec, fit, touches = calibrate_mount(
            tw.hand, FloatingFlange(arm), IDENTITY, wc.table_top_z, "twin"
        )
    d, a = errors(fit.mount, TRUE)
    assert d < 2e-3 and a < 1.0, (d, a)
    assert rec.quality["rms_residual_mm"] < 0.5
    assert len(touches) == 12
