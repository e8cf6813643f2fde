"""The robot's devices served as nodes: hand, arm, ``sim/place`` when simulated, calibration."""

from __future__ import annotations

import logging
from typing import Any

import zenoh

from activetouch.daemon.calibration_node import CalibrationNode
from activetouch.daemon.nodes import ArmNode, HandNode, PlaceNode
from activetouch.daemon.serving import ServedNode
from activetouch.daemon.supervision import DeviceLink, LinkSettings, arm_probe, hand_probe
from activetouch.transport.keys import ARM_NODE, HAND_NODE

log = logging.getLogger(__name__)


class DeviceNodes:
    """The robot's devices served as its hand and arm nodes (and ``sim/place`` when they are
    simulated), all holding the devices' one lock. Whatever the device types: the twin, the
    fakes or real drivers (activetouch.devices).

    With `links` (LinkSettings), the devices come unconnected (``make_devices(...,
    connect=False)``): a `DeviceLink` per device connects it when it appears and reconnects it
    after a loss; its node serves only while it is connected and says why not otherwise."""

    def __init__(
        self,
        devices: Any,
        session: zenoh.Session,
        robot: str,
        state_hz: float,
        links: LinkSettings | None = None,
    ) -> None:
        self.devices = devices
        self.nodes: list[ServedNode] = []
        self.links: list[DeviceLink] = []
        lock = devices.lock
        cfg = devices.ctx.cfg
        hand_link = arm_link = None
        if links is not None:
            hand_link = DeviceLink(HAND_NODE, cfg.hand.type, devices.hand, hand_probe, lock, links)
            arm_link = DeviceLink(ARM_NODE, cfg.arm.type, devices.arm, arm_probe, lock, links)
            self.links = [hand_link, arm_link]
        try:
            self.nodes.append(
                HandNode(
                    devices.hand,
                    session,
                    robot,
                    state_hz=state_hz,
                    lock=lock,
                    link=hand_link,
                    device=cfg.hand.type,
                )
            )
            self.nodes.append(
                ArmNode(
                    devices.arm,
                    session,
                    robot,
                    wrist=devices.wrist,
                    placement=devices.placement,
                    state_hz=state_hz,
                    lock=lock,
                    link=arm_link,
                )
            )
            if devices.simulated and devices.ctx.place is not None:
                self.nodes.append(PlaceNode(devices.ctx.place, session, robot, lock=lock))
            # calibrate/<kind>: the procedures of activetouch.calibration on these devices.
            self.nodes.append(CalibrationNode(devices, session, robot, lock=lock))
            for link in self.links:  # after the nodes listen to them
                link.start()
        except Exception:
            self.close()
            raise
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
        return all(n.workers_alive() for n in self.nodes)

    def close(self, join_timeout: float = 1.0) -> None:
        for link in self.links:  # no reconnection while closing
            link.close(join_timeout)
        for node in reversed(self.nodes):
            node.close(join_timeout)
        self.nodes.clear()
