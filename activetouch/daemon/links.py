"""What the recognition service reaches its robot through (`ServiceLinks`): the device nodes
over Zenoh in the daemon (`zenoh_links`), or the devices themselves in memory (`local_links`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import zenoh

from activetouch.daemon.liveliness import AliveNodes, DeviceHealthWatch, tokens_left
from activetouch.daemon.remote import Coalesced, RemoteArm, RemoteHand, RemotePlace
from activetouch.daemon.serving import JSON, direct
from activetouch.errors import (
    ActiveTouchError,
)
from activetouch.interfaces import Hand, Pose
from activetouch.planning.motion.base import WristMotion
from activetouch.transport.keys import Keys
from activetouch.transport.zenoh_session import undeclare_quietly

REQUESTER_CHECK_S = 0.5  # at the start of a recognition: does its requester hold a token?


@dataclass
class ServiceLinks:
    """What the service reaches the robot and its clients through. Over Zenoh (`zenoh_links`)
    in the daemon; in memory (`local_links`) in tests, so the admission, queue, cancel and
    e-stop logic runs without Zenoh or subprocesses."""

    hand: Hand
    arm: Any  # WristMotion (move_to) with stop, clear_stop, estop
    place: Any = None  # (object, seed) -> Placed / SimPlaceResult; None: a real robot
    alive: Any = None  # snapshot() / since(node): the nodes' liveliness; None: always alive
    health: Any = None  # node -> its device's last DeviceHealth, or None
    # node -> does it hold a liveliness token right now (asked, not cached); None: not asked
    confirm_alive: Any = None
    publish: Any = None  # bytes -> None: a progress sample
    # (session_id, on_gone) -> handle to undeclare, or None: the requester holds no token
    watch_requester: Any = None
    closers: list = field(default_factory=list)


def zenoh_links(session: zenoh.Session, robot: str, mode: str, svc: Any) -> ServiceLinks:
    """The devices through their Zenoh nodes, progress on `progress`, requesters' tokens."""
    keys = Keys(robot)
    timeouts = {"timeout": svc.node_timeout_s, "motion_timeout": svc.motion_timeout_s}
    alive = AliveNodes(session, robot)
    health = DeviceHealthWatch(session, robot)
    hand = RemoteHand(session, robot, **timeouts)
    arm = RemoteArm(session, robot, **timeouts)
    sim = RemotePlace(session, robot, svc.motion_timeout_s) if mode == "sim" else None
    publisher = session.declare_publisher(keys.progress, encoding=JSON)

    def watch(sid: str, on_gone: Any) -> Any:
        try:
            key = keys.requester(sid)
        except ActiveTouchError:
            return None  # an id that is no key chunk cannot have a token
        if not tokens_left(session, key, timeout=REQUESTER_CHECK_S):
            return None

        def confirm() -> None:
            if not tokens_left(session, key):
                on_gone()

        check = Coalesced(confirm, "activetouch-requester")

        def on_sample(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.DELETE:
                check.request()  # confirm off Zenoh's thread: a spoofed drop changes nothing

        return session.liveliness().declare_subscriber(key, direct(on_sample))

    return ServiceLinks(
        hand=hand,
        arm=arm,
        place=sim.place if sim is not None else None,
        alive=alive,
        health=health.get,
        confirm_alive=lambda node: tokens_left(session, keys.alive(node), timeout=0.5),
        publish=publisher.put,
        watch_requester=watch,
        closers=[
            alive.close,
            health.close,
            hand.close,
            arm.close,
            *([sim.close] if sim else []),
            lambda: undeclare_quietly(publisher),
        ],
    )


class LocalArm(WristMotion):
    """A device's wrist motion plus its arm's stops, as the service uses them."""

    def __init__(self, devices: Any) -> None:
        self.devices = devices

    def move_to(self, pose: Pose) -> None:
        self.devices.wrist.set_placement(self.devices.placement())
        self.devices.wrist.move_to(pose)

    @property  # type: ignore[override]
    def robot_seconds(self) -> float:
        return self.devices.wrist.robot_seconds

    @property  # type: ignore[override]
    def planning_seconds(self) -> float:
        return self.devices.wrist.planning_seconds

    def stop(self) -> None:
        self.devices.arm.stop()

    def estop(self) -> None:
        self.devices.arm.estop()

    def clear_stop(self) -> None:
        self.devices.arm.clear_stop()


def local_links(devices: Any) -> ServiceLinks:
    """The devices of `make_devices` called directly (no Zenoh): for tests and tools."""
    place = None
    if devices.simulated and devices.ctx.place is not None:

        def place(obj: str, seed: int | None) -> Any:
            return devices.ctx.place(obj, seed)

    return ServiceLinks(hand=devices.hand, arm=LocalArm(devices), place=place)
