"""Guarded touches with the hand: move the flange, step along a direction until a tactile
sensor reports contact, press a little further, and find where the contact began.

The flange is what the arm positions (`Flange`): for a floating wrist its joints are the
flange pose directly (`FloatingFlange`); a Baxter needs its forward kinematics (a hook: see
docs/calibration.md). Everything is in the robot base frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.calibration.tactile import (
    CalibrationRefusedError,
    read_states,
    wait_new_states,
)
from activetouch.errors import UnreachableError
from activetouch.interfaces import Arm, Hand, Pose
from activetouch.models.reflex import DISTAL_LINKS, PROXIMAL_LINKS, collision_boxes
from activetouch.planning.motion.floating import (
    WRIST_JOINTS,
    pose_to_wrist_joints,
    straight_trajectory,
    wrist_joints_to_pose,
)


class Flange(Protocol):
    def pose(self) -> Pose: ...

    def move_to(self, pose: Pose) -> None: ...


class FloatingFlange:
    """A floating-wrist arm (joints x y z roll pitch yaw): its joints are the flange pose."""

    def __init__(self, arm: Arm) -> None:

        if tuple(arm.joint_names) != WRIST_JOINTS:
            raise CalibrationRefusedError(
                "touch calibration here drives a floating wrist; this arm has joints "
                f"{', '.join(arm.joint_names)} (needs the flange hook, docs/calibration.md)"
            )
        self.arm = arm

    def pose(self) -> Pose:

        return wrist_joints_to_pose(self.arm.joint_state().position)

    def move_to(self, pose: Pose) -> None:

        start = self.arm.joint_state().position
        goal = pose_to_wrist_joints(pose)
        self.arm.execute(straight_trajectory(start, goal, self.arm.limits.velocity))


def onset_height(z: np.ndarray, pressure: np.ndarray, threshold: float) -> float:
    """Height where a pressure that rises linearly with depth (z decreasing) starts: a line
    through the readings over `threshold`, at pressure 0. Falls back to the first reading
    over threshold when fewer than two readings rise."""
    z = np.asarray(z, dtype=np.float64)
    p = np.asarray(pressure, dtype=np.float64)
    sel = p > threshold
    if sel.sum() >= 2 and np.ptp(z[sel]) > 1e-9:
        a, b = np.polyfit(z[sel], p[sel], 1)
        if a < 0:
            return float(-b / a)
    return float(z[sel].max()) if sel.any() else float("nan")


def hand_points(preshape: float = 0.0, proximal=None, distal=None) -> np.ndarray:
    """(n, 3) corners of every finger link's collision boxes (proximal, distal, fingertip) in
    the hand frame at these joint angles (open by default): the hand's known geometry."""

    fingers = set(PROXIMAL_LINKS + DISTAL_LINKS)  # not the palm's housing, pad and swivels
    boxes = collision_boxes(None, preshape, proximal, distal)
    return np.concatenate([b.corners() for b in boxes if b.link in fingers])


@dataclass(frozen=True)
class TouchResult:
    flange: Pose  # flange pose where the contact began
    sensor: int  # the sensor that pressed hardest
    readings: int  # hand readings taken in the descent


def _max_contact(hand: Hand, ignore: np.ndarray | None = None) -> tuple[float, int, bool]:
    s = hand.state()
    p = np.asarray(s.pressures, dtype=np.float64)
    c = np.asarray(s.contact, dtype=bool).copy()
    if ignore is not None and len(ignore):
        c[ignore] = False
        p = p.copy()
        p[ignore] = -np.inf
    i = int(np.argmax(np.where(c, p, -np.inf))) if c.any() else int(np.argmax(p))
    return float(p[i]), i, bool(c.any())


def _confirmed_contact(hand: Hand, ignore: np.ndarray | None) -> tuple[float, int, bool]:
    """`_max_contact`, a contact counted only if the hand's next state has one too (a noise
    spike over the threshold does not last two readings; a touch does)."""
    p, i, touching = _max_contact(hand, ignore)
    if not touching:
        return p, i, False
    wait_new_states(hand, 1)  # the same packet read twice would confirm its own spike
    return _max_contact(hand, ignore)


def in_contact_at_rest(hand: Hand, readings: int = 5) -> np.ndarray:
    """Sensor ids in contact in most of `readings` distinct states while nothing touches the
    hand (stuck, or a zero that drifted): a touch procedure ignores them, as a recognition
    does (session.contacts.mask_reasons)."""
    _, contact = read_states(hand, readings)
    return np.flatnonzero(contact.mean(axis=0) > 0.5)


def guarded_descent(
    hand: Hand,
    flange: Flange,
    start: Pose,
    coarse_step: float,
    fine_step: float,
    press_m: float,
    press_pressure: float,
    max_search_m: float,
    threshold: float,
    direction: np.ndarray | None = None,
    ignore: np.ndarray | None = None,
) -> TouchResult:
    """From `start` (flange pose, base frame), step along `direction` (default straight
    down) until a sensor reports contact; back up one coarse step and re-approach finely,
    pressing at most `press_m` past the first contact or until `press_pressure`; then back
    off to `start`. The contact began where the pressure, linear in depth, extrapolates to 0.
    `ignore`: sensor ids whose contact does not count (`in_contact_at_rest`).
    """
    d = np.array([0.0, 0.0, -1.0]) if direction is None else np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    flange.move_to(start)
    at = lambda s: Pose(start.xyz + s * d, start.quat)  # noqa: E731
    s, n = 0.0, 0
    while True:
        s += coarse_step
        if s > max_search_m:
            flange.move_to(start)
            raise CalibrationRefusedError(
                f"no touch within {max_search_m * 1e3:.0f} mm of {np.round(start.xyz, 3)}"
            )
        try:
            flange.move_to(at(s))
        except UnreachableError as e:  # the arm (or twin) refuses to go deeper: stop here
            flange.move_to(start)
            raise CalibrationRefusedError(f"touch blocked before any sensor felt it: {e}") from e
        n += 1
        _, _, touching = _confirmed_contact(hand, ignore)
        if touching:
            break
    # Fine re-approach from one coarse step back.
    s -= coarse_step
    depth: list[float] = []
    press: list[float] = []
    sensor, first = -1, None
    while True:
        s += fine_step
        try:
            flange.move_to(at(s))
        except UnreachableError:
            break
        n += 1
        p, i, touching = _confirmed_contact(hand, ignore)
        if touching:
            first = s if first is None else first
            sensor = i if sensor < 0 else sensor
            depth.append(s)
            press.append(p)
            if p > press_pressure or s - first >= press_m:
                break
        else:  # below the threshold: still part of the rising line (or noise)
            depth.append(s)
            press.append(p)
        if s > max_search_m:
            break
    flange.move_to(start)
    if first is None:
        raise CalibrationRefusedError("the touch was lost on the fine approach")
    # Along the descent, "height" is -s: pressure rises as s grows.
    # Readings from half the threshold up count (the twin's noise is a tenth of it).
    s0 = -onset_height(-np.asarray(depth), np.asarray(press), 0.5 * threshold)
    return TouchResult(at(s0), sensor, n)


def lowest_point_start(
    orientation: Rotation, mount: Pose, points: np.ndarray, xy: np.ndarray, height: float
) -> Pose:
    """The flange pose that puts the hand (through `mount`) at `orientation` with its lowest
    point `points` (hand frame) at `height` above base z = 0, centred over `xy`."""
    rm = Rotation.from_quat(mount.quat)
    r_f = orientation * rm.inv()
    # hand points in the base frame with the flange at the origin
    p = r_f.apply(rm.apply(points) + mount.xyz)
    low = p[np.argmin(p[:, 2])]
    t = np.array([xy[0] - low[0], xy[1] - low[1], height - low[2]])
    return Pose(t, r_f.as_quat())
