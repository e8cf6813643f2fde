"""Collision checking with coal through pinocchio: the arm against itself, the table and the
object, through a broadphase manager (DynamicAABBTree).

The object is an obstacle while moving and not while grasping (the hand must touch it then):
its pairs are switched on and off with `CollisionScene.in_collision(q, with_object=...)`."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from activetouch.planning.motion.base import Placement
from activetouch.planning.motion.robot import ArmModel


def object_geometry(hull_points: np.ndarray | None, extents: np.ndarray | None):
    """A coal shape for the object: the convex hull of `hull_points` (object frame) if given,
    else a box of `extents` centred on the object frame."""
    # deferred: coal only for motion planning's collision checks
    import coal

    if hull_points is not None:
        pts = np.asarray(hull_points, dtype=np.float64).reshape(-1, 3)
        if len(pts) < 4:
            raise ValueError("an object hull needs at least 4 points")
        verts = coal.StdVec_Vec3s()
        verts.extend([np.array(v) for v in pts[ConvexHull(pts).vertices]])
        return coal.Convex.convexHull(verts, False, "")
    ext = np.asarray(extents, dtype=np.float64).reshape(3)
    return coal.Box(*ext)


class CollisionScene:
    """Arm + hand + table + object; `in_collision(q)` in tens of microseconds. Pairs closer
    than `clearance_m` count as touching (a margin for what lies between checked samples)."""

    def __init__(
        self,
        arm: ArmModel,
        table_center: np.ndarray | list[float],
        table_size: np.ndarray | list[float],
        placement: Placement | None = None,
        object_hull: np.ndarray | None = None,
        object_extents: np.ndarray | None = None,
        clearance_m: float = 0.0,
    ) -> None:
        self.arm = arm
        self.clearance_m = float(clearance_m)
        self.data = arm.model.createData()
        self.table_center = np.asarray(table_center, dtype=np.float64).reshape(3)
        self.table_size = np.asarray(table_size, dtype=np.float64).reshape(3)
        self.placement = placement
        self.object_hull = object_hull
        self.object_extents = object_extents
        self._build()

    def set_object(
        self,
        placement: Placement | None,
        hull_points: np.ndarray | None = None,
        extents: np.ndarray | None = None,
    ) -> None:
        """Where the object is and its shape (hull points or box extents, object frame);
        `placement` None removes it."""
        self.placement = placement
        self.object_hull = hull_points
        self.object_extents = extents
        self._build()

    def _build(self) -> None:
        # deferred: coal only for motion planning's collision checks
        import coal

        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        geom = self.arm.geom.copy()
        moving = [i for i, o in enumerate(geom.geometryObjects) if o.parentJoint != 0]
        table = pin.GeometryObject(
            "table", 0, 0, pin.SE3(np.eye(3), self.table_center), coal.Box(*self.table_size)
        )
        tid = geom.addGeometryObject(table)
        for i in moving:
            geom.addCollisionPair(pin.CollisionPair(i, tid))
        self.object_pairs: list[int] = []
        self.arm_object_pairs: list[int] = []  # robot links (not the hand) against the object
        self.hand_object_pairs: list[int] = []
        has_object = self.placement is not None and (
            self.object_hull is not None or self.object_extents is not None
        )
        if has_object:
            shape = object_geometry(self.object_hull, self.object_extents)
            m = pin.SE3(self.placement.rotation.as_matrix(), self.placement.xyz)
            oid = geom.addGeometryObject(pin.GeometryObject("object", 0, 0, m, shape))
            hand = set(self.arm.hand_geoms)
            for i in moving:
                k = len(geom.collisionPairs)
                geom.addCollisionPair(pin.CollisionPair(i, oid))
                (self.hand_object_pairs if i in hand else self.arm_object_pairs).append(k)
            self.object_pairs = sorted(self.arm_object_pairs + self.hand_object_pairs)
        self.geom = geom
        self.gdata = pin.GeometryData(geom)
        for req in self.gdata.collisionRequests:  # pairs closer than this count as touching
            req.security_margin = self.clearance_m
        self.manager = pin.BroadPhaseManager_DynamicAABBTreeCollisionManager(
            self.arm.model, geom, self.gdata
        )
        self._arm_object_on = True
        self._hand_object_on = True

    def _object(self, arm_on: bool, hand_on: bool) -> None:
        for pairs, on, attr in (
            (self.arm_object_pairs, arm_on, "_arm_object_on"),
            (self.hand_object_pairs, hand_on, "_hand_object_on"),
        ):
            if on == getattr(self, attr):
                continue
            for k in pairs:
                if on:
                    self.gdata.activateCollisionPair(k)
                else:
                    self.gdata.deactivateCollisionPair(k)
            setattr(self, attr, on)

    def in_collision(
        self, q: np.ndarray, with_object: bool = True, hand_object: bool | None = None
    ) -> bool:
        """True if anything touches at `q`. The object counts only `with_object`; the hand
        against the object only `hand_object` (default: `with_object`), so a caller that checks
        the hand against the real object elsewhere can still check the arm against it."""
        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        self._object(with_object, with_object if hand_object is None else hand_object)
        return bool(pin.computeCollisions(self.arm.model, self.data, self.manager, q, True))

    def colliding_pairs(
        self, q: np.ndarray, with_object: bool = True, hand_object: bool | None = None
    ) -> list[tuple[str, str]]:
        """Names of every touching pair at `q` (slow path, for error messages and tests)."""
        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        self._object(with_object, with_object if hand_object is None else hand_object)
        pin.computeCollisions(self.arm.model, self.data, self.geom, self.gdata, q, False)
        out = []
        objs = self.geom.geometryObjects
        for k, res in enumerate(self.gdata.collisionResults):
            if self.gdata.activeCollisionPairs[k] and res.isCollision():
                p = self.geom.collisionPairs[k]
                out.append((str(objs[p.first].name), str(objs[p.second].name)))
        return out

    def hand_position(self) -> np.ndarray:
        """The hand origin at the last checked configuration."""
        # deferred: pinocchio only for arm kinematics and motion
        import pinocchio as pin

        return np.array(
            pin.updateFramePlacement(self.arm.model, self.data, self.arm.hand_frame).translation
        )
