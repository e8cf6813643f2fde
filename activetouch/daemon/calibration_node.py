"""The calibration procedures as daemon queries: ``calibrate/<kind>`` on the robot's devices.

| key | kind | payload |
|---|---|---|
| calibrate/tactile | queryable | CalibrateRequest -> Reply[CalibrateResult] |
| calibrate/fingers | queryable | CalibrateRequest -> Reply[CalibrateResult] |
| calibrate/mount | queryable | CalibrateRequest -> Reply[CalibrateResult] |
| calibrate/object | queryable | CalibrateRequest (object named) -> Reply[CalibrateResult] |
| alive/calibration | liveliness token | (none) |

Each query runs the same function as `activetouch calibrate <kind>` on the node's hand and arm
with the devices' one lock held (no grasp or motion of another node interleaves), stores the
record under the data directory unless ``store`` is false, and answers with the record's
values and quality (never a local path). A refusal (`CalibrationRefusedError`) comes back as
an error reply of that type; nothing is stored. A stored object placement is also handed to
the motion layer (`wrist.set_placement`), so the next recognition uses it.

Served by `CalibrationNode(devices, session, robot)`; `DeviceNodes` adds it with one line
(docs/calibration.md, "Hooks").
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated, Any

import msgspec
import numpy as np
import zenoh

from activetouch import paths
from activetouch.calibration import store
from activetouch.calibration.fingers import calibrate_fingers
from activetouch.calibration.probing import FloatingFlange
from activetouch.calibration.store import KINDS, CalibrationRecord, device_name
from activetouch.calibration.tactile import TactileSettings, apply_tactile, calibrate_tactile
from activetouch.daemon.serving import Op, ServedNode
from activetouch.errors import ActiveTouchError
from activetouch.interfaces import Pose
from activetouch.objects.library import ObjectLibrary
from activetouch.transport.keys import Keys
from activetouch.transport.messages import Label, Message, Name

log = logging.getLogger(__name__)

CALIBRATION_NODE = "calibration"
Seconds = Annotated[float, msgspec.Meta(gt=0.0, le=60.0)]


def calibrate_key(keys: Keys, kind: str) -> str:
    """``activetouch/<robot>/calibrate/<kind>``."""
    store.check_kind(kind)
    return f"{keys.prefix}/calibrate/{kind}"


class CalibrateRequest(Message, kw_only=True):
    """Run one procedure. ``store`` false: measure and answer, store nothing (a dry run)."""

    store: bool = True
    device: Name | None = None  # the record's device name (default as the CLI's)
    object: Name | None = None  # object: its name in the object library (required)
    duration_s: Seconds | None = None  # tactile: seconds of samples


class CalibrateResult(Message, kw_only=True):
    kind: Label
    device: Name
    measured_at: Label
    values: dict[str, Any]
    quality: dict[str, Any]
    stored: bool


def hand_device(cfg: Any, explicit: str | None) -> str:
    return device_name(cfg, explicit)


def run_tactile(devices: Any, root: Path, req: CalibrateRequest) -> CalibrationRecord:

    device = hand_device(devices.ctx.cfg, req.device)
    st = TactileSettings()
    if req.duration_s is not None:
        st.duration_s = float(req.duration_s)
    rec, fit = calibrate_tactile(devices.hand, device, st, store.load(root, "tactile", device))
    if req.store:
        apply_tactile(devices.hand, fit.zero, fit.threshold)
    return rec


def run_fingers(devices: Any, root: Path, req: CalibrateRequest) -> CalibrationRecord:

    rec, _ = calibrate_fingers(devices.hand, hand_device(devices.ctx.cfg, req.device))
    return rec


def _stored_mount(root: Path, mount_device: str) -> Pose:
    rec = store.load(root, "mount", mount_device)
    if rec is None:
        return Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    return Pose(np.asarray(rec.values["xyz"]), np.asarray(rec.values["quat_xyzw"]))


def run_mount(devices: Any, root: Path, req: CalibrateRequest) -> CalibrationRecord:
    # deferred: loads scipy
    from activetouch.calibration.mount import calibrate_mount

    cfg = devices.ctx.cfg
    mount_device = f"{hand_device(cfg, req.device)}-on-{cfg.arm.type}"
    rec, _, _ = calibrate_mount(
        devices.hand,
        FloatingFlange(devices.arm),
        _stored_mount(root, mount_device),
        cfg.workcell.table_top_z,
        mount_device,
        threshold=float(cfg.sim.contact_threshold),
    )
    return rec


def run_object(devices: Any, root: Path, req: CalibrateRequest) -> CalibrationRecord:
    # deferred: loads numba, scipy
    from activetouch.calibration.object_frame import (
        DEFAULT_DEVICE,
        IDENTITY,
        calibrate_object,
        nominal_placement,
    )

    # deferred: loads pybullet
    from activetouch.sim.world import geometry_from_config

    if not req.object:
        raise ActiveTouchError("calibrate/object: name the object (`object`)")
    cfg = devices.ctx.cfg
    spec = ObjectLibrary.in_data_dir(root).get(req.object)
    mount = IDENTITY
    if not devices.simulated:  # the twin's floating arm carries the hand itself
        mount = _stored_mount(root, f"{hand_device(cfg, None)}-on-{cfg.arm.type}")
    rec, fit, _ = calibrate_object(
        devices.hand,
        FloatingFlange(devices.arm),
        spec,
        nominal_placement(cfg.workcell, spec.extents),
        cfg.workcell.table_top_z,
        req.device or DEFAULT_DEVICE,
        mount=mount,
        geometry=geometry_from_config(cfg.sim),
        threshold=float(cfg.sim.contact_threshold),
    )
    if req.store:
        devices.wrist.set_placement(fit.placement)  # the twin's wrist keeps its own
    return rec


PROCEDURES = {
    "tactile": run_tactile,
    "fingers": run_fingers,
    "mount": run_mount,
    "object": run_object,
}


class CalibrationNode(ServedNode):
    """``calibrate/<kind>`` for every procedure, run on `devices` (`activetouch.devices.Devices`)
    with `lock` (the devices' lock, by default) held."""

    node_name = CALIBRATION_NODE

    def __init__(self, devices: Any, session: zenoh.Session, robot: str, *, lock=None) -> None:
        keys = Keys(robot)
        super().__init__(
            session,
            robot,
            state_key=calibrate_key(keys, "tactile"),
            state_hz=0.0,
            lock=lock if lock is not None else devices.lock,
        )
        self.devices = devices
        self.root = paths.data_dir(devices.ctx.data)
        self._ops = {
            kind: Op(calibrate_key(keys, kind), CalibrateRequest, self._runner(kind))
            for kind in KINDS
        }
        self._start()

    def _runner(self, kind: str):
        def run(req: CalibrateRequest) -> CalibrateResult:
            rec = PROCEDURES[kind](self.devices, self.root, req)
            if req.store:
                path = store.save(self.root, rec)
                log.info("calibration %s of %s stored in %s", kind, rec.device, path)
            return CalibrateResult(
                kind=rec.kind,
                device=rec.device,
                measured_at=rec.measured_at,
                values=rec.values,
                quality=rec.quality,
                stored=bool(req.store),
            )

        return run
