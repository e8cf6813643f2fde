"""The twin's world: a PyBullet DIRECT client with a table, one object and the ReFlex hand,
and `SimArm`, the floating wrist that carries the hand.

Conventions: the world is the robot base frame, and the table is the workcell's box (by
default its top at z = 0, centred at the origin). An object's frame has its origin at the
object's bounding-box centre, axes parallel to the world's; the object stands on the table at
the workcell's object x, y and is fixed. `place(spec, offset_xy=..., yaw_rad=...)` stands the
body off that by a placement error (the real robot's: the object is never exactly where the
workcell says): the object frame (`object_origin`, wrist poses, the support plane) stays the
nominal one, so everything that reads it believes the nominal placement, while Bullet's body is
shifted and turned about its vertical axis (`PlacedObject.offset`, `yaw_rad`). Wrist poses
are of the hand (ReFlex base link) frame expressed in the object frame. With no object on the
table the object frame is the world frame.

The hand is a free (non-fixed) body that is never stepped: it is posed kinematically and Bullet's
collision detection (`performCollisionDetection` + `getContactPoints`) reports where it meets the
table and the object. A free base matters: Bullet skips pairs of static bodies, and the table
and the object are static.

Every world owns its client, so several worlds can live in one process; `close()` disconnects.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial.transform import Rotation

from activetouch.config import SimConfig, WorkcellConfig
from activetouch.errors import ActiveTouchError, UnreachableError
from activetouch.interfaces import (
    N_FINGERS,
    N_SENSORS,
    SENSORS_PER_FINGER,
    Arm,
    JointLimits,
    JointState,
    JointTrajectory,
    Pose,
    StopLatch,
)
from activetouch.models.reflex import (
    DISTAL_JOINTS,
    DISTAL_LINKS,
    N_PROXIMAL_SENSORS,
    PAD_LINK,
    PRESHAPE_JOINTS,
    PROXIMAL_JOINTS,
    PROXIMAL_LINKS,
    ReflexGeometry,
    coupled_joints,
    geometry_with_distal_sites,
    sensor_positions,
    urdf_file,
)
from activetouch.planning.motion.floating import (
    WRIST_JOINTS,
    floating_limits,
    pose_to_wrist_joints,
    wrap_angles,
    wrist_joints_to_pose,
    wrist_trajectory_positions,
)
from activetouch.sim import PATHS
from activetouch.sim.pybullet import pb
from activetouch.sim.spawn import spawn_object

if TYPE_CHECKING:
    from activetouch.objects.library import ObjectSpec

FAR_AWAY = (0.0, 0.0, 1.0e3)  # where the hand goes to drop Bullet's cached contact manifolds


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """3x3 rotation of a unit quaternion (x, y, z, w)."""
    return Rotation.from_quat(np.asarray(q, dtype=np.float64)).as_matrix()


def geometry_from_config(cfg: SimConfig) -> ReflexGeometry:
    return geometry_with_distal_sites(
        cfg.distal_sensor_x, cfg.distal_sensor_z, cfg.proximal_zero_pitch_rad
    )


@dataclass(frozen=True)
class HandLinks:
    """PyBullet indices of the loaded hand (a joint's index is its child link's)."""

    preshape: tuple[int, int]
    proximal: tuple[int, int, int]
    distal: tuple[int, int, int]
    pad: int
    collision_links: tuple[int, ...]  # links with collision geometry, base (-1) included
    site_link: np.ndarray  # (38,) link carrying each sensor site


@dataclass(frozen=True)
class HandContacts:
    """Where the hand meets other bodies at one instant (only touching/penetrating points)."""

    link: np.ndarray  # (n,) hand link index (-1 = base)
    position: np.ndarray  # (n, 3) world position of the point on the hand
    depth: np.ndarray  # (n,) penetration, metres, >= 0
    body: np.ndarray  # (n,) the other body

    def __len__(self) -> int:
        return len(self.link)


@dataclass(frozen=True)
class PlacedObject:
    body: int
    name: str
    extents: np.ndarray  # (3,) bounding-box size, metres
    origin: np.ndarray  # (3,) world position of the object frame origin (the nominal one)
    # The placement error: where the body's centre really is in the object frame, and how far
    # it is turned about z. Only Bullet's body knows it; the object frame is nominal.
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw_rad: float = 0.0


class SimWorld:
    """A PyBullet world with a table, at most one object, and the ReFlex hand."""

    def __init__(
        self,
        cfg: SimConfig | None = None,
        geometry: ReflexGeometry | None = None,
        urdf_cache: Path | None = None,
        workcell: WorkcellConfig | None = None,
    ) -> None:
        self.cfg = cfg or SimConfig()
        self.workcell = workcell or WorkcellConfig()
        self.geometry = geometry or geometry_from_config(self.cfg)
        self.client: int | None = pb.connect(pb.DIRECT)
        self._object: PlacedObject | None = None
        c = self.client
        try:
            size = np.asarray(self.workcell.table_size, dtype=np.float64).reshape(3)
            table_shape = pb.createCollisionShape(
                pb.GEOM_BOX, halfExtents=(size / 2).tolist(), physicsClientId=c
            )
            self.table = pb.createMultiBody(
                0.0,
                table_shape,
                basePosition=[float(v) for v in self.workcell.table_center],
                physicsClientId=c,
            )
            path = self._hand_urdf(urdf_cache)
            self.hand = pb.loadURDF(
                str(path), FAR_AWAY, [0, 0, 0, 1], useFixedBase=False, physicsClientId=c
            )
        except Exception:
            self.close()
            raise
        self.links = self._index_links()
        dyn = pb.getDynamicsInfo(self.hand, -1, physicsClientId=c)
        # PyBullet poses a base by its centre of mass; keep the URDF frame -> COM offset.
        self._com_pos, self._com_orn = tuple(dyn[3]), tuple(dyn[4])
        self._finger_joint_ids = list(self.links.proximal) + list(self.links.distal)
        self._wrist = Pose(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0]))
        self._preshape = float("nan")
        self._proximal = np.zeros(N_FINGERS)
        self._distal = np.zeros(N_FINGERS)
        self._preshape_signs = self._spread_signs()
        self.set_hand(0.0, self._proximal, self._distal)
        self.open_fingers()
        self.set_wrist(self._wrist)

    # -- lifetime -------------------------------------------------------------------------

    def close(self) -> None:
        """Disconnect the client (idempotent)."""
        client = getattr(self, "client", None)
        if client is not None:
            self.client = None
            with contextlib.suppress(pb.error):  # already gone
                pb.disconnect(physicsClientId=client)

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        # A forgotten world still frees its client; at interpreter exit pybullet may be gone.
        with contextlib.suppress(Exception):
            self.close()

    @property
    def cid(self) -> int:
        if self.client is None:
            raise ActiveTouchError("the simulated world is closed")
        return self.client

    def _hand_urdf(self, cache: Path | None) -> Path:
        """The hand's URDF file (the ReFlex's; `sim.bh8.BH8World` loads the BarrettHand's)."""
        return urdf_file(self.geometry, cache)

    def _spread_signs(self) -> list[list[float]]:
        """Joint values of the two preshape joints per unit of preshape (ReFlex: +-)."""
        return [[1.0], [-1.0]]

    def _hand_indices(self) -> tuple[dict[str, int], dict[str, int], list[int]]:
        """The loaded hand's joint index by joint name and by child link name, and the links
        with collision geometry (base, -1, included)."""
        c = self.cid
        by_joint: dict[str, int] = {}
        by_link: dict[str, int] = {}
        for j in range(pb.getNumJoints(self.hand, physicsClientId=c)):
            info = pb.getJointInfo(self.hand, j, physicsClientId=c)
            by_joint[info[1].decode()] = j
            by_link[info[12].decode()] = j
        collision = [-1] + [
            j for j in by_link.values() if pb.getCollisionShapeData(self.hand, j, physicsClientId=c)
        ]
        return by_joint, by_link, collision

    def _index_links(self) -> HandLinks:
        by_joint, by_link, collision = self._hand_indices()
        site_link = np.empty(N_SENSORS, dtype=np.int64)
        for f in range(N_FINGERS):
            for s in range(SENSORS_PER_FINGER):
                links = PROXIMAL_LINKS if s < N_PROXIMAL_SENSORS else DISTAL_LINKS
                site_link[f * SENSORS_PER_FINGER + s] = by_link[links[f]]
        site_link[N_FINGERS * SENSORS_PER_FINGER :] = by_link[PAD_LINK]
        return HandLinks(
            preshape=(by_joint[PRESHAPE_JOINTS[0]], by_joint[PRESHAPE_JOINTS[1]]),
            proximal=tuple(by_joint[n] for n in PROXIMAL_JOINTS),  # type: ignore[arg-type]
            distal=tuple(by_joint[n] for n in DISTAL_JOINTS),  # type: ignore[arg-type]
            pad=by_link[PAD_LINK],
            collision_links=tuple(sorted(collision)),
            site_link=site_link,
        )

    # -- the object -----------------------------------------------------------------------

    @property
    def object(self) -> PlacedObject | None:
        return self._object

    @property
    def object_origin(self) -> np.ndarray:
        """World position of the object frame's origin (the world origin with no object)."""
        return np.zeros(3) if self._object is None else self._object.origin.copy()

    @property
    def support_z(self) -> float:
        """The table plane in the object frame."""
        return self.workcell.table_top_z - float(self.object_origin[2])

    def place(
        self, spec: ObjectSpec, offset_xy: tuple[float, float] = (0.0, 0.0), yaw_rad: float = 0.0
    ) -> int:
        """Put a library object on the table (removing any previous one); its body id.
        `offset_xy` (metres) and `yaw_rad` (about the vertical through its centre) misplace
        the body without telling the object frame (see the module notes)."""
        self.clear()
        ext = np.asarray(spec.extents, dtype=np.float64)
        offset = np.array([float(offset_xy[0]), float(offset_xy[1]), 0.0])
        if not np.all(np.isfinite(offset)) or not np.isfinite(yaw_rad):
            raise ValueError(f"placement error must be finite, got {offset_xy}, {yaw_rad}")
        pos = self.object_centre(ext) + offset
        body = spawn_object(self.cid, spec, position=tuple(pos.tolist()))
        if yaw_rad != 0.0:
            # Turning about z keeps the bounding box's bottom on the table (z is unchanged).
            quat = Rotation.from_euler("z", float(yaw_rad)).as_quat()
            pb.resetBasePositionAndOrientation(
                body, pos.tolist(), quat.tolist(), physicsClientId=self.cid
            )
        return self.place_body(body, ext, spec.name, offset=offset, yaw_rad=float(yaw_rad))

    def object_centre(self, extents: np.ndarray) -> np.ndarray:
        """Where an object of `extents` stands: at the workcell's object x, y, on the table."""
        wc = self.workcell
        return np.array(
            [wc.object_xyz[0], wc.object_xyz[1], wc.table_top_z + float(extents[2]) / 2]
        )

    def place_body(
        self,
        body: int,
        extents: np.ndarray,
        name: str = "",
        offset: np.ndarray | None = None,
        yaw_rad: float = 0.0,
    ) -> int:
        """Adopt `body` (already created in this world's client, fixed, standing on the table
        at `object_centre(extents)`, or off it by `offset` and turned by `yaw_rad` when it
        was misplaced on purpose) as the object; the world removes it on `clear()`."""
        ext = np.asarray(extents, dtype=np.float64).reshape(3)
        if np.any(ext <= 0) or not np.all(np.isfinite(ext)):
            raise ValueError(f"object extents must be positive, got {ext}")
        if self._object is not None and self._object.body != body:
            self.clear()
        off = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64).reshape(3)
        self._object = PlacedObject(body, name, ext, self.object_centre(ext), off, float(yaw_rad))
        self.set_wrist(self._wrist)  # the wrist pose is object-relative: re-pose the hand
        return body

    def place_primitive(self, kind: str, size: float | tuple[float, ...] | list[float]) -> int:
        """A fixed primitive on the table: "sphere" (radius), "cylinder" (radius, height, axis
        vertical) or "box" (x, y, z sizes)."""
        dims = np.atleast_1d(np.asarray(size, dtype=np.float64))
        c = self.cid
        if kind == "sphere" and dims.size == 1:
            shape = pb.createCollisionShape(
                pb.GEOM_SPHERE, radius=float(dims[0]), physicsClientId=c
            )
            ext = np.full(3, 2 * dims[0])
        elif kind == "cylinder" and dims.size == 2:
            shape = pb.createCollisionShape(
                pb.GEOM_CYLINDER, radius=float(dims[0]), height=float(dims[1]), physicsClientId=c
            )
            ext = np.array([2 * dims[0], 2 * dims[0], dims[1]])
        elif kind == "box" and dims.size == 3:
            shape = pb.createCollisionShape(
                pb.GEOM_BOX, halfExtents=(dims / 2).tolist(), physicsClientId=c
            )
            ext = dims.copy()
        else:
            raise ValueError(f"bad primitive {kind!r} with size {size!r}")
        if np.any(ext <= 0):
            raise ValueError(f"primitive sizes must be positive, got {size!r}")
        self.clear()
        body = pb.createMultiBody(
            0.0, shape, basePosition=self.object_centre(ext).tolist(), physicsClientId=c
        )
        return self.place_body(body, ext, kind)

    def clear(self) -> None:
        """Remove the object, leaving the empty table."""
        if self._object is not None:
            pb.removeBody(self._object.body, physicsClientId=self.cid)
            self._object = None
            self.set_wrist(self._wrist)

    # -- the hand -------------------------------------------------------------------------

    @property
    def wrist_pose(self) -> Pose:
        """Hand frame in the object frame."""
        return self._wrist

    def wrist_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Hand frame in the world: position (3,), quaternion (4,) x y z w."""
        return self._wrist.xyz + self.object_origin, self._wrist.quat.copy()

    def set_wrist(self, pose: Pose) -> None:
        """Teleport the hand frame to `pose` (object frame). No collision check: see SimArm."""
        self._wrist = pose
        pos, quat = self.wrist_world()
        com_pos, com_orn = pb.multiplyTransforms(
            pos.tolist(), quat.tolist(), self._com_pos, self._com_orn
        )
        pb.resetBasePositionAndOrientation(self.hand, com_pos, com_orn, physicsClientId=self.cid)

    @property
    def preshape_angle(self) -> float:
        return self._preshape

    @property
    def proximal(self) -> np.ndarray:
        return self._proximal.copy()

    @property
    def distal(self) -> np.ndarray:
        return self._distal.copy()

    def set_hand(self, preshape: float, proximal: np.ndarray, distal: np.ndarray) -> None:
        """Pose the hand's joints: preshape (fingers 0, 1 swivel by +-preshape), proximal and
        distal angles per finger."""
        prox = np.asarray(proximal, dtype=np.float64).reshape(N_FINGERS)
        dist = np.asarray(distal, dtype=np.float64).reshape(N_FINGERS)
        c = self.cid
        if preshape != self._preshape:  # NaN before the first call
            pb.resetJointStatesMultiDof(
                self.hand,
                list(self.links.preshape),
                [[preshape * s[0]] for s in self._preshape_signs],
                physicsClientId=c,
            )
        pb.resetJointStatesMultiDof(
            self.hand,
            self._finger_joint_ids,
            [[float(v)] for v in np.concatenate([prox, dist])],
            physicsClientId=c,
        )
        self._preshape = float(preshape)
        self._proximal = prox.copy()
        self._distal = dist.copy()

    def open_fingers(self) -> None:
        """Open every finger to the configured open spool angle (0: flat), preshape kept."""
        spool = np.full(N_FINGERS, self.cfg.open_spool_rad)
        prox, dist = coupled_joints(
            spool,
            np.zeros(N_FINGERS),
            np.zeros(N_FINGERS, dtype=bool),
            self.cfg.flexure_coupling,
            self.geometry.proximal_limit,
            self.geometry.distal_limit,
        )
        self.set_hand(self._preshape, prox, dist)

    def check_hand_pose(self, pose: Pose) -> str | None:
        """Why the open hand could not be at `pose` (object frame): it would sink into the
        table or the object (`collision_reason`); None if it can. Nothing moves."""
        before = (self.wrist_pose, self.preshape_angle, self.proximal, self.distal)
        try:
            self.open_fingers()
            self.set_wrist(pose)
            return self.collision_reason()
        finally:
            self.set_wrist(before[0])
            self.set_hand(before[1], before[2], before[3])

    def sensor_sites_hand(self, proximal: np.ndarray | None = None) -> np.ndarray:
        """(38, 3) sensor-site XYZ in the hand frame at the current joint angles (or with the
        proximal joints at `proximal`)."""
        prox = self._proximal if proximal is None else proximal
        return sensor_positions(self.geometry, self._preshape, prox, self._distal)

    def hand_to_world(self, xyz_hand: np.ndarray) -> np.ndarray:
        pos, quat = self.wrist_world()
        return np.asarray(xyz_hand) @ quat_to_matrix(quat).T + pos

    def world_to_hand(self, xyz_world: np.ndarray) -> np.ndarray:
        pos, quat = self.wrist_world()
        return (np.asarray(xyz_world) - pos) @ quat_to_matrix(quat)

    # -- collision queries ----------------------------------------------------------------

    def flush_contacts(self) -> None:
        """Drop Bullet's cached contact manifolds of the hand, so the next query depends only
        on the current configuration (not on the path that led to it)."""
        c = self.cid
        pb.resetBasePositionAndOrientation(self.hand, FAR_AWAY, [0, 0, 0, 1], physicsClientId=c)
        pb.performCollisionDetection(physicsClientId=c)
        self.set_wrist(self._wrist)

    def hand_contacts(self) -> HandContacts:
        """Run collision detection; the hand's touching or penetrating points."""
        c = self.cid
        pb.performCollisionDetection(physicsClientId=c)
        links, pos, depth, bodies = [], [], [], []
        for cp in pb.getContactPoints(bodyA=self.hand, physicsClientId=c):
            if cp[8] > 0.0:
                continue  # a near miss kept in the manifold, not a contact
            if cp[1] == self.hand:
                links.append(cp[3])
                pos.append(cp[5])
                bodies.append(cp[2])
            else:
                links.append(cp[4])
                pos.append(cp[6])
                bodies.append(cp[1])
            depth.append(-cp[8])
        return HandContacts(
            link=np.asarray(links, dtype=np.int64),
            position=np.asarray(pos, dtype=np.float64).reshape(-1, 3),
            depth=np.asarray(depth, dtype=np.float64),
            body=np.asarray(bodies, dtype=np.int64),
        )

    def object_pushes(self) -> np.ndarray:
        """(n, 3) how each of the hand's contacts with the object pushes it: the contact
        normal into the object times the penetration (zero rows for none)."""
        if self._object is None:
            return np.zeros((0, 3))
        c, body = self.cid, self._object.body
        pb.performCollisionDetection(physicsClientId=c)
        out = []
        for cp in pb.getContactPoints(bodyA=self.hand, bodyB=body, physicsClientId=c):
            if cp[8] >= 0.0:
                continue
            # Bullet's normal points from B to A: from the object to the hand here.
            sign = -1.0 if cp[1] == self.hand else 1.0
            out.append(sign * np.asarray(cp[7], dtype=np.float64) * -cp[8])
        return np.asarray(out, dtype=np.float64).reshape(-1, 3)

    def shift_object(self, delta_xy: np.ndarray) -> None:
        """Slide the object on the table by `delta_xy` (world metres); the object frame stays
        where the workcell says, as for a placement error."""
        obj = self._object
        if obj is None:
            return
        d = np.array([float(delta_xy[0]), float(delta_xy[1]), 0.0])
        offset = obj.offset + d
        pos, quat = pb.getBasePositionAndOrientation(obj.body, physicsClientId=self.cid)
        pb.resetBasePositionAndOrientation(
            obj.body, (np.asarray(pos) + d).tolist(), quat, physicsClientId=self.cid
        )
        self._object = dataclasses.replace(obj, offset=offset)

    def object_clear_of_hand(self, tol_m: float) -> bool:
        """No point of the hand deeper than `tol_m` in the object."""
        if self._object is None:
            return True
        c = self.cid
        pb.performCollisionDetection(physicsClientId=c)
        pts = pb.getContactPoints(bodyA=self.hand, bodyB=self._object.body, physicsClientId=c)
        return all(-cp[8] <= tol_m for cp in pts)

    def hand_min_z(self, over_table: bool = False) -> float:
        """Lowest world z of the hand's collision geometry, from the links' axis-aligned boxes
        (exact for an upright hand, a few mm low for tilted compound links: conservative).
        `over_table`: only links above the table's footprint (inf if none is)."""
        c = self.cid
        wc = self.workcell
        cx, cy = float(wc.table_center[0]), float(wc.table_center[1])
        hx, hy = float(wc.table_size[0]) / 2, float(wc.table_size[1]) / 2
        low = float("inf")
        for j in self.links.collision_links:
            (x0, y0, z0), (x1, y1, _z1) = pb.getAABB(self.hand, j, physicsClientId=c)
            if over_table and (x1 < cx - hx or x0 > cx + hx or y1 < cy - hy or y0 > cy + hy):
                continue  # beside the table: nothing to go under
            low = min(low, z0)
        return low

    def collision_reason(self, below_table: bool = True) -> str | None:
        """Why the hand cannot be where it is (None if it may): below the table top where the
        table is, or overlapping the table or the object deeper than the configured
        tolerance. The first test (links' bounding boxes: conservative for tilted links) is
        for a hand that may teleport under the table; a hand that moves in small steps, as on
        an arm, cannot get there without touching it first: `below_table=False` skips it."""
        tol = self.cfg.wrist_penetration_tol_m
        if below_table:
            low = self.hand_min_z(over_table=True) - self.workcell.table_top_z
            if low < -tol:
                return f"the hand reaches {-low * 1000:.1f} mm below the table top"
        self.flush_contacts()
        contacts = self.hand_contacts()
        if len(contacts) and contacts.depth.max() > tol:
            i = int(np.argmax(contacts.depth))
            what = "table" if contacts.body[i] == self.table else "object"
            return f"the hand penetrates the {what} by {contacts.depth[i] * 1000:.1f} mm"
        return None


def _format_pose(pose: Pose) -> str:
    x, y, z = pose.xyz
    return f"({x:.3f}, {y:.3f}, {z:.3f})"


class SimArm(Arm):
    """A floating wrist: six joints x y z roll pitch yaw of the hand frame in the world (the
    robot base frame). With ``path="teleport"`` (the paper's simulation, and the default) the
    wrist jumps from point to point of a trajectory and only the points are checked; with
    ``"straight"`` every `execute_step_m` / `execute_step_rad` along the way is. The twin
    moves with the fingers open (preshape kept): a teleport carries nothing, and the check of
    a pose is of the open hand. A trajectory outside the workspace is refused before anything
    moves."""

    def __init__(self, world: SimWorld, path: str = "teleport") -> None:
        if path not in PATHS:
            raise ActiveTouchError(f"arm path must be one of {', '.join(PATHS)}, not {path!r}")
        self.world = world
        self.path = path
        self._limits = floating_limits(world.workcell)
        self.stop_latch = StopLatch()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return WRIST_JOINTS

    @property
    def limits(self) -> JointLimits:
        return self._limits

    def connect(self) -> None:
        pass

    def disconnect(self) -> None:
        pass  # the world owns the client

    def _world_pose(self) -> Pose:
        pos, quat = self.world.wrist_world()
        return Pose(pos, quat)

    def joint_state(self) -> JointState:
        return JointState(
            names=WRIST_JOINTS,
            position=pose_to_wrist_joints(self._world_pose()),
            velocity=np.zeros(6),
            stamp=time.monotonic(),
        )

    def _to_object(self, pose_world: Pose) -> Pose:
        return Pose(pose_world.xyz - self.world.object_origin, pose_world.quat)

    def _try_pose(self, pose: Pose) -> str | None:
        """Open the fingers, teleport (object frame), check; on failure restore everything."""
        w = self.world
        before = (w.wrist_pose, w.preshape_angle, w.proximal, w.distal)
        w.open_fingers()
        w.set_wrist(pose)
        reason = w.collision_reason()
        if reason is not None:
            w.set_wrist(before[0])
            w.set_hand(before[1], before[2], before[3])
        return reason

    def check_pose(self, pose: Pose) -> str | None:
        """Why the wrist could not be at `pose` (object frame), or None; nothing moves."""
        return self.world.check_hand_pose(pose)

    def execute(self, trajectory: JointTrajectory) -> None:
        """Follow a wrist trajectory (see the class); on a collision the hand stays at the last
        collision-free pose and UnreachableError names the time."""
        self.stop_latch.check("arm motion")
        q = wrist_trajectory_positions(trajectory)
        bad = self._limits.violations(WRIST_JOINTS, q)
        if bad:
            raise UnreachableError(f"wrist trajectory outside the workspace: {'; '.join(bad)}")
        cfg = self.world.cfg
        times = np.asarray(trajectory.times, dtype=np.float64).reshape(-1)
        current = pose_to_wrist_joints(self._world_pose())
        for i in range(len(q)):
            start = current if i == 0 else q[i - 1]
            delta = q[i] - start
            delta[3:] = wrap_angles(delta[3:])
            if self.path == "teleport":
                n = 1
            else:
                n = max(
                    1,
                    int(np.ceil(np.linalg.norm(delta[:3]) / cfg.execute_step_m)),
                    int(np.ceil(np.abs(delta[3:]).max() / cfg.execute_step_rad)),
                )
            if i == 0 and n == 1 and np.allclose(delta, 0.0, atol=1e-9):
                continue  # the trajectory starts where the wrist is
            for k in range(1, n + 1):
                self.stop_latch.check("arm motion")
                # The last step lands on the point itself, not on start + delta (rounding):
                # the twin's noise is keyed by the pose, so a pose must not depend on the path.
                q_k = q[i] if k == n else start + delta * (k / n)
                pose = self._to_object(wrist_joints_to_pose(q_k))
                reason = self._try_pose(pose)
                if reason is not None:
                    raise UnreachableError(
                        f"wrist trajectory blocked near t = {times[i]:.2f} s at "
                        f"{_format_pose(pose)} (object frame): {reason}"
                    )

    def stop(self) -> None:
        self.stop_latch.set()

    def clear_stop(self) -> None:
        self.stop_latch.clear()


__all__: list[Any] = [
    "WRIST_JOINTS",
    "HandContacts",
    "HandLinks",
    "PlacedObject",
    "SimArm",
    "SimWorld",
    "geometry_from_config",
    "pose_to_wrist_joints",
    "wrist_joints_to_pose",
]
