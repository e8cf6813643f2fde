"""Hand-mount calibration: the hand frame in the arm's flange frame, from touches on the table.

Model. The arm knows its flange pose F (forward kinematics; a floating wrist's joints); the
hand is at H = F * M, M the mount (hand frame in the flange frame), configured roughly. The
hand, fingers open and sensors down, is lowered onto the table at several tilts; at each touch
the lowest point of the hand's known geometry (corners of the finger links' collision boxes,
hand frame) lies on the table plane z = z_table (workcell). Each touch gives one equation

    min_v  e_z . (R_F (R_M v + t_M) + t_F)  =  z_table

and M = M0 * (Exp(omega), tau) is found by robust least squares (scipy, soft-L1), with a
weak prior towards M0 so that directions the touches cannot see stay put (reported through the
Jacobian's singular values). The touch height is not the first reading over threshold (that
lags by the skin's give): the pressure rising linearly with depth is extrapolated back to zero.

Refused: fewer touches than `min_touches`, an RMS residual over `max_rms_m`, or a correction
larger than `max_offset_m` / `max_angle_deg` (the configured mount is roughly right or the
setup is wrong).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from activetouch.calibration.probing import guarded_descent, hand_points, lowest_point_start
from activetouch.calibration.store import CalibrationRecord
from activetouch.calibration.tactile import CalibrationRefusedError
from activetouch.interfaces import Pose


@dataclass
class MountSettings:
    # The sensor-down hand is tilted by each of `tilts_deg` about each horizontal axis at
    # `directions_deg` from base x: about y (90, 270 +- 30) the fingertips touch first, next to
    # their sensors; about x a finger's side edge would, far from any sensor.
    tilts_deg: list[float] = field(default_factory=lambda: [10.0, 20.0])
    directions_deg: list[float] = field(default_factory=lambda: [60, 90, 120, 240, 270, 300])
    yaws_deg: list[float] = field(default_factory=lambda: [0.0])
    centre_xy: list[float] = field(default_factory=lambda: [0.45, 0.0])  # where to touch
    start_clearance_m: float = 0.015  # lowest hand point above the table before descending
    coarse_step_m: float = 0.0005
    fine_step_m: float = 0.0001
    press_m: float = 0.0015  # deepest press past the first reading over threshold
    press_pressure: float = 120.0  # stop pressing above this
    max_search_m: float = 0.05  # no touch within this: refused
    min_touches: int = 8
    max_rms_m: float = 0.001
    max_offset_m: float = 0.02
    max_angle_deg: float = 5.0
    prior_weight: float = 1e-3  # metres of residual per metre / radian of correction


@dataclass(frozen=True)
class Touch:
    """One touch: the flange pose at contact and the hand-frame points that may touch."""

    flange: Pose
    points: np.ndarray  # (k, 3) hand frame


@dataclass
class MountFit:
    mount: Pose
    correction_xyz: np.ndarray
    correction_deg: float
    correction_rotvec: np.ndarray
    residuals: np.ndarray  # (n,) metres
    rms_m: float
    singular_values: np.ndarray  # (6,) of the touch Jacobian (prior excluded)


def perturbed(mount0: Pose, x: np.ndarray) -> Pose:
    """M0 with its rotation turned by Exp(x[:3]) (in the mount frame) and moved by x[3:]."""
    r = Rotation.from_quat(mount0.quat) * Rotation.from_rotvec(x[:3])
    return Pose(mount0.xyz + x[3:], r.as_quat())


def touch_heights(touches: list[Touch], mount: Pose) -> np.ndarray:
    """(n,) height of the lowest candidate point of every touch with this mount."""
    out = np.empty(len(touches))
    rm = Rotation.from_quat(mount.quat)
    for i, t in enumerate(touches):
        rf = Rotation.from_quat(t.flange.quat)
        p = rf.apply(rm.apply(t.points) + mount.xyz) + t.flange.xyz
        out[i] = p[:, 2].min()
    return out


def solve_mount(
    touches: list[Touch], mount0: Pose, table_z: float, settings: MountSettings | None = None
) -> MountFit:
    """Least-squares mount from touches (see the module); CalibrationRefusedError when it is
    implausible."""
    st = settings or MountSettings()
    if len(touches) < st.min_touches:
        raise CalibrationRefusedError(
            f"mount: {len(touches)} touches, need at least {st.min_touches}"
        )

    def resid(x: np.ndarray) -> np.ndarray:
        h = touch_heights(touches, perturbed(mount0, x)) - table_z
        return np.concatenate([h, st.prior_weight * x])

    sol = least_squares(resid, np.zeros(6), loss="soft_l1", f_scale=0.001, x_scale=0.01)
    x = sol.x
    mount = perturbed(mount0, x)
    r = touch_heights(touches, mount) - table_z
    rms = float(np.sqrt(np.mean(r**2)))
    jac = sol.jac[: len(touches)]
    sv = np.linalg.svd(jac, compute_uv=False) if jac.size else np.zeros(6)
    angle = float(np.degrees(np.linalg.norm(x[:3])))
    fit = MountFit(mount, x[3:].copy(), angle, x[:3].copy(), r, rms, sv)
    problems = []
    if rms > st.max_rms_m:
        problems.append(f"RMS residual {rms * 1e3:.2f} mm > {st.max_rms_m * 1e3:g} mm")
    if np.linalg.norm(x[3:]) > st.max_offset_m:
        problems.append(
            f"offset correction {np.linalg.norm(x[3:]) * 1e3:.1f} mm > {st.max_offset_m * 1e3:g} mm"
        )
    if angle > st.max_angle_deg:
        problems.append(f"tilt correction {angle:.2f} deg > {st.max_angle_deg:g} deg")
    if problems:
        raise CalibrationRefusedError("mount solution refused: " + "; ".join(problems))
    return fit


def touch_orientations(st: MountSettings) -> list[Rotation]:
    """Hand orientations for the touches: sensors down (hand z to base -z), yawed by each of
    `yaws_deg`, tilted by each of `tilts_deg` about each axis of `directions_deg`."""
    down = Rotation.from_euler("x", np.pi)
    out = []
    for yaw in st.yaws_deg:
        for tilt_deg in st.tilts_deg:
            for phi_deg in st.directions_deg:
                phi = np.radians(phi_deg + yaw)
                axis = np.array([np.cos(phi), np.sin(phi), 0.0])
                tilt = Rotation.from_rotvec(np.radians(tilt_deg) * axis)
                out.append(tilt * Rotation.from_euler("z", np.radians(yaw)) * down)
    return out


def mount_record(
    device: str,
    fit: MountFit,
    mount0: Pose,
    touches: list[Touch],
    settings: MountSettings,
    table_z: float,
) -> CalibrationRecord:
    return CalibrationRecord(
        kind="mount",
        device=device,
        values={
            "xyz": [round(float(v), 6) for v in fit.mount.xyz],
            "quat_xyzw": [round(float(v), 8) for v in fit.mount.quat],
            "frame": "hand (ReFlex base link) in the arm's flange frame",
        },
        quality={
            "n_touches": len(touches),
            "rms_residual_mm": round(fit.rms_m * 1e3, 4),
            "max_residual_mm": round(float(np.max(np.abs(fit.residuals))) * 1e3, 4),
            "correction_xyz_mm": [round(float(v) * 1e3, 3) for v in fit.correction_xyz],
            "correction_deg": round(fit.correction_deg, 4),
            "singular_values": [round(float(v), 6) for v in fit.singular_values],
        },
        method={
            "procedure": "mount",
            "configured_xyz": [float(v) for v in mount0.xyz],
            "configured_quat_xyzw": [float(v) for v in mount0.quat],
            "table_z": table_z,
            "model": "lowest hand-geometry point of each touch on the table plane; soft-L1 "
            "least squares with a weak prior to the configured mount",
            "settings": asdict(settings),
        },
    )


def calibrate_mount(
    hand,
    flange,
    mount0: Pose,
    table_z: float,
    device: str,
    settings: MountSettings | None = None,
    threshold: float = 20.0,
) -> tuple[CalibrationRecord, MountFit, list[Touch]]:
    """Touch the table at every orientation of `touch_orientations` and solve for the mount.
    `flange` is a `probing.Flange`; the hand is opened first (its open geometry is the probe).
    """

    st = settings or MountSettings()
    hand.open()
    pts = hand_points(preshape=float(hand.state().preshape))
    touches: list[Touch] = []
    xy = np.asarray(st.centre_xy, dtype=np.float64)
    for rot in touch_orientations(st):
        start = lowest_point_start(rot, mount0, pts, xy, table_z + st.start_clearance_m)
        res = guarded_descent(
            hand,
            flange,
            start,
            st.coarse_step_m,
            st.fine_step_m,
            st.press_m,
            st.press_pressure,
            st.max_search_m,
            threshold,
        )
        touches.append(Touch(res.flange, pts))
    fit = solve_mount(touches, mount0, table_z, st)
    return mount_record(device, fit, mount0, touches, st, table_z), fit, touches
