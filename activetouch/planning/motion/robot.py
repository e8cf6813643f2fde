"""Baxter's kinematic and collision model for one arm, loaded offline with pinocchio.

The URDF and SRDF come from the `example-robot-data` wheel (found under the `cmeel` prefix of
this interpreter, no network); any other path can be configured. The model is reduced to one
arm's seven joints (the head, the other arm and the grippers are locked: the other arm at
Baxter's tucked pose, where it stays out of the workspace). The electric gripper's collision
shapes are dropped and the ReFlex hand's boxes are attached at the hand mount instead.

Frames: the robot base frame is the URDF's ``base`` (x forward, z up, at the torso). The hand
frame is the ReFlex base link frame (palm normal along +z, pad at z = 0.0896 m), fixed to
``<side>_hand_link`` by the hand mount transform.

Default hand mount (an estimate; `calibration` refines it): the ReFlex base turned 90 degrees
about z from ``<side>_hand_link``, no offset. ``<side>_hand_link`` sits on the wrist flange with
z out of the flange, so the ReFlex palm (its +z) points where Baxter's gripper would; the ReFlex
mounting plate bolts flat to the flange (its thickness is taken as 0). The 90 degree turn puts
the thumb-to-fingers axis (ReFlex x) along the hand link's y, the direction Baxter's parallel
gripper opens in, which is how a ReFlex adapter is usually clocked on Baxter's flange; either
clocking gives the same reachable set up to a w2 turn of 90 degrees.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.errors import ConfigError, DataError
from activetouch.interfaces import JointLimits, Pose
from activetouch.models.reflex import Box, collision_boxes

ARM_JOINTS = ("s0", "s1", "e0", "e1", "w0", "w1", "w2")
# Baxter's tucked pose (baxter_tools tuck_arms.py), left arm; the right arm mirrors s0, e0, w0, w2.
TUCKED_LEFT = (-1.0, -2.07, 3.0, 2.55, 0.0, 0.01, 0.0)
# A bent pose with the hand in front of the robot, palm down: q = 0 is a singular straight arm.
READY_LEFT = (0.0, -0.55, 0.0, 1.25, 0.0, 0.87, 0.0)
DESCRIPTION = "example-robot-data/robots/baxter_description"
# A Baxter workcell (base frame): a 0.75 m-high table in front of the robot (Baxter's base
# frame is ~0.93 m above the floor), the object ahead of the left arm. Measured in
# python -m activetouch bench motion against other placements: see docs/motion.md.
BAXTER_TABLE_CENTER = (0.85, 0.2, -0.205)
BAXTER_TABLE_SIZE = (0.8, 1.4, 0.05)
BAXTER_OBJECT_XY = (0.6, 0.25)


def mirror_arm(q_left: tuple[float, ...] | np.ndarray) -> np.ndarray:
    """The right arm's configuration that mirrors a left arm one in the x-z plane."""
    return np.asarray(q_left, dtype=np.float64) * np.array([-1, 1, -1, 1, -1, 1, -1])


@dataclass
class BaxterMotionConfig:
    """Robot description, arm, hand mount and motion limits for the Baxter motion layer.

    (To be merged into the workcell configuration.)"""

    side: str = "left"
    urdf: str = ""  # "" finds example-robot-data's baxter.urdf
    srdf: str = ""  # "" finds example-robot-data's baxter_manipulation.srdf
    # Hand mount: the ReFlex base frame in <side>_hand_link.
    hand_mount_xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    hand_mount_rpy: list[float] = field(default_factory=lambda: [0.0, 0.0, float(np.pi / 2)])
    hand_preshape: float = 0.0  # the open hand's preshape while moving (collision shapes)
    # Ruckig limits (the URDF gives velocity; acceleration and jerk are ours).
    acceleration: float = 1.5  # rad/s^2, every joint
    jerk: float = 10.0  # rad/s^3, every joint
    velocity_scale: float = 1.0  # fraction of the URDF velocity limits used
    # Paths: retreat from a grasp and approach the next one along the hand's z by this much.
    approach_m: float = 0.08
    # Dense checks of timed trajectories: no more hand travel / joint motion between samples.
    check_step_m: float = 0.01
    check_step_rad: float = 0.02
    # Planned motions keep this clearance (the checks between samples see no thinner contact).
    clearance_m: float = 0.005
    # Where the straight transit collides: first over the top (hand raised by this much at
    # both ends; 0 skips it), then OMPL RRT-Connect.
    lift_m: float = 0.15
    ompl_time_s: float = 1.0
    # IK.
    ik_tol: float = 1e-4  # norm of the SE(3) log error (m and rad)
    ik_restarts: int = 30
    seed: int = 0

    def check(self) -> None:
        if self.side not in ("left", "right"):
            raise ConfigError(f"side must be left or right, got {self.side!r}")
        if len(self.hand_mount_xyz) != 3 or len(self.hand_mount_rpy) != 3:
            raise ConfigError("hand_mount_xyz and hand_mount_rpy need 3 numbers each")
        for name in ("acceleration", "jerk", "velocity_scale", "check_step_m", "check_step_rad"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be positive")

    @property
    def hand_mount(self) -> np.ndarray:
        """4x4 transform of the ReFlex base in <side>_hand_link."""
        t = np.eye(4)
        t[:3, :3] = Rotation.from_euler("xyz", self.hand_mount_rpy).as_matrix()
        t[:3, 3] = self.hand_mount_xyz
        return t


def description_dirs() -> list[Path]:
    """Where `example-robot-data` may live: the cmeel prefix of this interpreter's site-packages."""
    out = []
    for p in [*sys.path, sys.prefix]:
        for cand in (Path(p) / "cmeel.prefix" / "share", Path(p) / "share"):
            if (cand / DESCRIPTION / "urdf" / "baxter.urdf").is_file() and cand not in out:
                out.append(cand)
    try:
        # optional: cmeel comes with pin's PyPI wheel, not with a conda or ROS pinocchio
        import cmeel  # type: ignore[import-not-found]

        cand = Path(cmeel.__file__).resolve().parent.parent / "cmeel.prefix" / "share"
        if (cand / DESCRIPTION).is_dir() and cand not in out:
            out.append(cand)
    except ImportError:
        pass
    return out


def find_baxter_description(cfg: BaxterMotionConfig) -> tuple[Path, Path, Path]:
    """(urdf, srdf, package dir) for `cfg`, by path only."""
    dirs = description_dirs()
    share = dirs[0] if dirs else None
    urdf = (
        Path(cfg.urdf)
        if cfg.urdf
        else (share / DESCRIPTION / "urdf" / "baxter.urdf" if share else None)
    )
    srdf = (
        Path(cfg.srdf)
        if cfg.srdf
        else (share / DESCRIPTION / "srdf" / "baxter_manipulation.srdf" if share else None)
    )
    if urdf is None or not urdf.is_file():
        raise DataError(
            "Baxter URDF not found: install example-robot-data or set the urdf path "
            f"(looked in {[str(d) for d in dirs] or sys.path})"
        )
    if srdf is None or not srdf.is_file():
        raise DataError(f"Baxter SRDF not found ({srdf})")
    pkg = share if share is not None else urdf.parent.parent.parent.parent.parent
    return urdf, srdf, pkg


@dataclass
class ArmModel:
    """One Baxter arm: reduced pinocchio model (7 joints), its collision geometry (robot only,
    the hand attached) and the hand frame."""

    side: str
    model: object  # pinocchio.Model
    geom: object  # pinocchio.GeometryModel: robot links + ReFlex boxes, SRDF pairs removed
    hand_frame: int  # frame id of the ReFlex base
    link_frame: int  # frame id of <side>_hand_link
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    hand_geoms: tuple[int, ...]  # geometry ids of the hand's boxes
    urdf: Path
    package_dir: Path

    @property
    def nq(self) -> int:
        return len(self.joint_names)

    def limits(self, acceleration: float) -> JointLimits:
        return JointLimits(
            self.lower, self.upper, self.velocity, np.full(self.nq, float(acceleration))
        )

    @property
    def ready(self) -> np.ndarray:
        q = np.asarray(READY_LEFT) if self.side == "left" else mirror_arm(READY_LEFT)
        return np.clip(q, self.lower, self.upper)


def _box_geometry(pin, coal, name: str, joint: int, frame: int, hand_placement, box: Box):
    placement = hand_placement * pin.SE3(box.rotation, box.position)
    return pin.GeometryObject(name, int(joint), int(frame), placement, coal.Box(*box.size))


def load_arm(cfg: BaxterMotionConfig | None = None) -> ArmModel:
    """Load Baxter, reduce it to `cfg.side`'s arm and attach the ReFlex at the hand mount."""
    # deferred: coal only for motion planning's collision checks
    import coal

    # deferred: pinocchio only for arm kinematics and motion
    import pinocchio as pin

    cfg = cfg or BaxterMotionConfig()
    cfg.check()
    urdf, srdf, pkg = find_baxter_description(cfg)
    full, geom, _ = pin.buildModelsFromUrdf(str(urdf), package_dirs=[str(pkg)])
    geom.addAllCollisionPairs()
    pin.removeCollisionPairs(full, geom, str(srdf))

    side, other = cfg.side, ("right" if cfg.side == "left" else "left")
    keep = {f"{side}_{j}" for j in ARM_JOINTS}
    q_ref = pin.neutral(full)
    tucked_other = mirror_arm(TUCKED_LEFT) if other == "right" else np.asarray(TUCKED_LEFT)
    for j, v in zip(ARM_JOINTS, tucked_other, strict=True):
        jid = full.getJointId(f"{other}_{j}")
        q_ref[full.joints[jid].idx_q] = v
    lock = [jid for jid in range(1, full.njoints) if full.names[jid] not in keep]
    model, geoms = pin.buildReducedModel(full, [geom], lock, q_ref)
    geom = geoms[0]

    # Drop this arm's gripper (the ReFlex replaces it).
    prefix = "l_gripper" if side == "left" else "r_gripper"
    names_now = [str(g.name) for g in geom.geometryObjects]  # copy: removal edits the list
    for name in names_now:
        if name.startswith(prefix) or name.startswith(f"{side}_gripper"):
            geom.removeGeometryObject(name)

    link_frame = model.getFrameId(f"{side}_hand_link")
    if link_frame >= len(model.frames):
        raise DataError(f"{urdf}: no frame {side}_hand_link")
    link = model.frames[link_frame]
    mount = pin.SE3(cfg.hand_mount[:3, :3], cfg.hand_mount[:3, 3])
    hand_placement = link.placement * mount
    hand_frame = model.addFrame(
        pin.Frame(
            "reflex_base", link.parentJoint, link_frame, hand_placement, pin.FrameType.OP_FRAME
        )
    )
    hand_ids = []
    # The twin URDF's boxes with the fingers open (the hand moves open).
    for box in collision_boxes(None, cfg.hand_preshape):
        gid = geom.addGeometryObject(
            _box_geometry(
                pin, coal, f"reflex_{box.name}", link.parentJoint, hand_frame, hand_placement, box
            )
        )
        hand_ids.append(gid)

    _set_pairs(geom, hand_ids, skip_joints=_adjacent(model, link.parentJoint))
    names = tuple(f"{side}_{j}" for j in ARM_JOINTS)
    idx = [model.joints[model.getJointId(n)].idx_q for n in names]
    if idx != list(range(7)):
        raise DataError(f"{urdf}: unexpected joint order {idx}")
    return ArmModel(
        side=side,
        model=model,
        geom=geom,
        hand_frame=int(hand_frame),
        link_frame=int(link_frame),
        joint_names=names,
        lower=np.array(model.lowerPositionLimit),
        upper=np.array(model.upperPositionLimit),
        velocity=np.array(model.velocityLimit) * cfg.velocity_scale,
        hand_geoms=tuple(int(i) for i in hand_ids),
        urdf=urdf,
        package_dir=pkg,
    )


def _adjacent(model, joint: int) -> set[int]:
    """The joint carrying the hand and its parent: the hand touching them is the mount."""
    return {int(joint), int(model.parents[joint])}


def _set_pairs(geom, hand_ids: list[int], skip_joints: set[int]) -> None:
    """Keep only pairs that can change: drop those between two bodies fixed to the world; add
    the hand against every link not next to it."""
    # deferred: pinocchio only for arm kinematics and motion
    import pinocchio as pin

    objs = geom.geometryObjects
    parent = [int(o.parentJoint) for o in objs]
    pairs = {(int(p.first), int(p.second)) for p in geom.collisionPairs}  # copy first
    pairs = {(a, b) for a, b in pairs if parent[a] != 0 or parent[b] != 0}
    hand = set(hand_ids)
    for h in hand_ids:
        for g in range(len(objs)):
            if g not in hand and parent[g] not in skip_joints:
                pairs.add((min(h, g), max(h, g)))
    # Rebuilt from scratch: removing single pairs after removing geometry objects misses some.
    geom.removeAllCollisionPairs()
    for a, b in sorted(pairs):
        geom.addCollisionPair(pin.CollisionPair(a, b))


def fk(arm: ArmModel, data, q: np.ndarray, frame: int | None = None):
    """pinocchio SE3 of `frame` (default: the hand frame) at `q`, in the base frame."""
    # deferred: pinocchio only for arm kinematics and motion
    import pinocchio as pin

    f = arm.hand_frame if frame is None else frame
    pin.forwardKinematics(arm.model, data, q)
    return pin.updateFramePlacement(arm.model, data, f)


def se3_to_pose(m) -> Pose:
    """A pinocchio SE3 as a Pose (pinocchio's quaternion: scipy's `from_matrix` costs ~0.5 ms
    here, which the twin pays at every checked sample)."""
    # deferred: pinocchio only for arm kinematics and motion
    import pinocchio as pin

    return Pose(np.array(m.translation), np.array(pin.Quaternion(m.rotation).coeffs()))


def pose_to_se3(pose: Pose):
    # deferred: pinocchio only for arm kinematics and motion
    import pinocchio as pin

    return pin.SE3(Rotation.from_quat(pose.quat).as_matrix(), np.asarray(pose.xyz))


def hand_pose(arm: ArmModel, data, q: np.ndarray) -> Pose:
    """The hand frame (ReFlex base) in the base frame at `q`."""
    return se3_to_pose(fk(arm, data, q))
