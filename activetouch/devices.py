"""Devices made from configuration: the hand and arm of `Config`, made by their types'
config classes (activetouch.device_types), connected, and given their wrist motion layer.

Devices that share something (the twin's hand and arm share one PyBullet world; the fake
hand reads the fake arm's pose) get it from `DeviceContext.shared`, keyed by name, made once.
A simulated resource also says how to put an object on its table (`DeviceContext.add_place`):
the service serves that as the ``sim/place`` node.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from activetouch.errors import ConfigError
from activetouch.planning.motion.base import workcell_placement
from activetouch.planning.motion.floating import WRIST_JOINTS, FloatingWristMotion

if TYPE_CHECKING:
    from activetouch.config import Config
    from activetouch.interfaces import Arm, Hand
    from activetouch.planning.motion.base import WristMotion


class DeviceContext:
    """What device factories share: the whole configuration and named shared resources."""

    def __init__(self, cfg: Config, data: Any = None) -> None:
        self.cfg = cfg
        self.data = data  # the data directory (--data), None: the default
        self._shared: dict[str, Any] = {}
        self._closers: list[Callable[[], None]] = []
        self.place: Callable[[Any], Any] | None = None
        self.placement_of: Callable[[], Any] | None = None
        self.locks: dict[str, threading.Lock] = {}

    def shared(self, name: str, make: Callable[[], Any]) -> Any:
        """The resource `name`, made by `make()` on first use."""
        if name not in self._shared:
            self._shared[name] = make()
        return self._shared[name]

    def lock(self, name: str) -> threading.Lock:
        """One lock per shared resource: the nodes serving devices on it never overlap."""
        return self.locks.setdefault(name, threading.Lock())

    def on_close(self, fn: Callable[[], None]) -> None:
        self._closers.append(fn)

    def add_place(self, place: Callable[[Any], Any], placement: Callable[[], Any]) -> None:
        """`place(object, seed) -> Placed`: how a simulated robot puts an object on
        its table (served as ``sim/place``); `placement()`: where the placed object now is."""
        if self.place is not None and self.place is not place:
            raise ConfigError(
                "the hand and the arm are simulated by two different devices, and each places "
                "the object: use the twin (or the fake) for both"
            )
        self.place, self.placement_of = place, placement

    def close(self) -> None:
        while self._closers:
            fn = self._closers.pop()
            try:
                fn()
            except Exception:  # closing must go on
                logging.getLogger(__name__).debug("closing a device resource failed", exc_info=True)


@dataclass
class Devices:
    hand: Hand
    arm: Arm
    wrist: WristMotion  # object-frame wrist poses -> motion of `arm`
    ctx: DeviceContext
    lock: threading.Lock  # held by the nodes around every device command

    @property
    def simulated(self) -> bool:
        return bool(self.ctx.cfg.hand.simulated and self.ctx.cfg.arm.simulated)

    def placement(self) -> Any:
        """Where the object is (`planning.motion.base.Placement`): as a simulated robot placed
        it, else as the workcell configures it."""
        if self.ctx.placement_of is not None:
            return self.ctx.placement_of()
        return workcell_placement(self.ctx.cfg.workcell)

    def close(self) -> None:
        for dev in (self.hand, self.arm):
            try:
                dev.disconnect()
            except Exception:
                logging.getLogger(__name__).debug("disconnect failed", exc_info=True)
        self.ctx.close()


def floating_wrist(arm_type: str, arm: Arm) -> WristMotion:
    """The default motion layer: a floating wrist, whose joints are the hand pose."""
    if tuple(arm.joint_names) != WRIST_JOINTS:
        raise ConfigError(f"arm type {arm_type!r} has no motion layer for wrist poses")
    return FloatingWristMotion(arm)


def make_devices(cfg: Config, data: Any = None, connect: bool = True) -> Devices:
    """Make and connect the hand and the arm of `cfg` (``[hand]``, ``[arm]``); `data` is the
    data directory (object library, datasets) for the simulated devices. With
    ``connect=False`` they are made (settings checked) but not connected: the daemon connects
    them in the background, as they appear (activetouch.daemon.supervision)."""
    ctx = DeviceContext(cfg, data)
    try:
        hand = cfg.hand.make(ctx)
        arm = cfg.arm.make(ctx)
        wrist = cfg.arm.make_wrist(arm, ctx) or floating_wrist(cfg.arm.type, arm)
        if connect:
            hand.connect()
            arm.connect()
    except BaseException:
        ctx.close()
        raise
    # Devices on one shared resource serialise through its lock; otherwise one lock for both.
    lock = next(iter(ctx.locks.values()), None) or threading.Lock()
    devices = Devices(hand, arm, wrist, ctx, lock)
    wrist.set_placement(devices.placement())
    return devices
