"""The robot's devices served as nodes: hand, arm, ``sim/place`` when simulated, calibration."""

from __future__ import annotations

import logging
from typing import Any

import zenoh

from activetouch.daemon.calibration_node import CalibrationNode
from activetouch.daemon.nodes import ArmNode, HandNode, PlaceNode
from activetouch.daemon.serving import ServedNode

log = logging.getLogger(__name__)


class DeviceNodes:
    """The robot's devices served as its hand and arm nodes (and ``sim/place`` when they are
    simulated), all holding the devices' one lock. Whatever the device types: the twin, the
    fakes or real drivers (activetouch.devices)."""

    def __init__(self, devices: Any, session: zenoh.Session, robot: str, state_hz: float) -> None:
        self.devices = devices
        self.nodes: list[ServedNode] = []
        lock = devices.lock
        try:
            self.nodes.append(HandNode(devices.hand, session, robot, state_hz=state_hz, lock=lock))
            self.nodes.append(
                ArmNode(
                    devices.arm,
                    session,
                    robot,
                    wrist=devices.wrist,
                    placement=devices.placement,
                    state_hz=state_hz,
                    lock=lock,
                )
            )
            if devices.simulated and devices.ctx.place is not None:
                self.nodes.append(PlaceNode(devices.ctx.place, session, robot, lock=lock))
            # calibrate/<kind>: the procedures of activetouch.calibration on these devices.
            self.nodes.append(CalibrationNode(devices, session, robot, lock=lock))
        except Exception:
            self.close()
            raise
        cfg = devices.ctx.cfg
        log.info(
            "device nodes serving",
            extra={
                "robot": robot,
                "hand": cfg.hand.type,
                "arm": cfg.arm.type,
                "nodes": ",".join(n.node_name for n in self.nodes),
            },
        )

    def healthy(self) -> bool:
        return all(n._worker.is_alive() for n in self.nodes)

    def close(self, join_timeout: float = 1.0) -> None:
        for node in reversed(self.nodes):
            node.close(join_timeout)
        self.nodes.clear()
