"""Devices made from configuration: the hand and arm registries.

As LeRobot does it: a config section names a device ``type`` and carries that type's own typed
settings; the type's config class knows how to make the device. Types are registered here by
name with the dotted path of their config class and imported only when used, so a config
naming the fake hand never imports PyBullet and a driver's serial or UDP code is not loaded
for the twin.

Adding a device type is one module plus one line here:

1. In the device's module, a dataclass subclassing `HandConfig` (or `ArmConfig`) with the
   type's settings and a ``make(self, ctx) -> Hand`` (or ``Arm``) that imports what it needs
   (keep the module itself light: heavy imports inside ``make``).
2. One entry in `HAND_TYPES` (or `ARM_TYPES`): ``"my-hand": "pkg.module:MyHandConfig"``.

Devices that share something (the twin's hand and arm share one PyBullet world; the fake
hand reads the fake arm's pose) get it from `DeviceContext.shared`, keyed by name, made once.
A simulated resource also says how to put an object on its table (`DeviceContext.add_place`):
the service serves that as the ``sim/place`` node.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

from activetouch.errors import ConfigError

if TYPE_CHECKING:
    from activetouch.config import Config
    from activetouch.interfaces import Arm, Hand
    from activetouch.planning.motion.base import WristMotion

HAND_TYPES: dict[str, str] = {
    "twin": "activetouch.sim.devices:TwinHandConfig",
    "fake": "activetouch.testing:FakeHandConfig",
    "reflex-takktile": "activetouch.drivers.reflex.takktile:ReflexTakktileConfig",
    "reflex-sf": "activetouch.drivers.reflex.sf:ReflexSFConfig",
}
ARM_TYPES: dict[str, str] = {
    "twin-floating": "activetouch.sim.devices:TwinFloatingArmConfig",
    "twin-baxter": "activetouch.sim.baxter:TwinBaxterArmConfig",
    "fake": "activetouch.testing:FakeArmConfig",
    "baxter": "activetouch.drivers.baxter.arm:BaxterArmConfig",
}
DEFAULT_HAND = "twin"
DEFAULT_ARM = "twin-floating"


@dataclass
class DeviceConfig:
    """Base of every device type's settings."""

    # True for devices that stand in for the robot (twin, fake): recognitions on them place
    # the object through a served ``sim/place`` node instead of feeling what is on the table.
    simulated: ClassVar[bool] = False

    type: str = ""


@dataclass
class HandConfig(DeviceConfig):
    def make(self, ctx: DeviceContext) -> Hand:
        raise NotImplementedError


@dataclass
class ArmConfig(DeviceConfig):
    def make(self, ctx: DeviceContext) -> Arm:
        raise NotImplementedError

    def default_workcell(self) -> dict[str, Any] | None:
        """`[workcell]` values this arm type uses when the configuration leaves the workcell at
        its defaults (a table at the base frame's origin, which only a floating wrist reaches);
        None: the defaults suit it."""
        return None

    def make_wrist(self, arm: Arm, ctx: DeviceContext) -> WristMotion:
        """The motion layer that brings this arm's hand to object-frame wrist poses. By
        default a floating wrist's (its joints are the hand pose); arm types with real
        kinematics return theirs (IK, collision-checked paths, timing)."""
        from activetouch.planning.motion.floating import WRIST_JOINTS, FloatingWristMotion

        if tuple(arm.joint_names) != WRIST_JOINTS:
            raise ConfigError(f"arm type {self.type!r} has no motion layer for wrist poses")
        return FloatingWristMotion(arm)


def _registry(kind: str) -> dict[str, str]:
    return HAND_TYPES if kind == "hand" else ARM_TYPES


def config_class(kind: str, type_name: str) -> type[DeviceConfig]:
    """The config class of device type `type_name` (`kind` "hand" or "arm"), imported now."""
    table = _registry(kind)
    if type_name not in table:
        raise ConfigError(
            f"{kind}.type: unknown {kind} type {type_name!r} (known: {', '.join(sorted(table))})"
        )
    module, _, name = table[type_name].partition(":")
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as e:
        raise ConfigError(
            f"{kind}.type: {kind} type {type_name!r} is not available in this build ({e})"
        ) from None
    return cls


def device_config(kind: str, data: dict[str, Any]) -> DeviceConfig:
    """A typed device config from a raw section (``type`` plus that type's settings)."""
    from activetouch.config import apply_section

    default = DEFAULT_HAND if kind == "hand" else DEFAULT_ARM
    type_name = data.get("type", default)
    if not isinstance(type_name, str):
        raise ConfigError(f"{kind}.type: expected a string, got {type_name!r}")
    cfg = config_class(kind, type_name)()
    cfg.type = type_name
    rest = {k: v for k, v in data.items() if k != "type"}
    apply_section(cfg, rest, f"{kind}.", what=f"{kind} type {type_name!r}")
    check = getattr(cfg, "check", None)
    if check is not None:
        check()
    return cfg


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
        """`place(SimPlaceRequest) -> SimPlaceResult`: how a simulated robot puts an object on
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
                import logging

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
        from activetouch.planning.motion.base import workcell_placement

        return workcell_placement(self.ctx.cfg.workcell)

    def close(self) -> None:
        for dev in (self.hand, self.arm):
            try:
                dev.disconnect()
            except Exception:
                import logging

                logging.getLogger(__name__).debug("disconnect failed", exc_info=True)
        self.ctx.close()


def make_devices(cfg: Config, data: Any = None) -> Devices:
    """Make and connect the hand and the arm of `cfg` (``[hand]``, ``[arm]``); `data` is the
    data directory (object library, datasets) for the simulated devices."""
    ctx = DeviceContext(cfg, data)
    try:
        hand = cfg.hand.make(ctx)
        arm = cfg.arm.make(ctx)
        wrist = cfg.arm.make_wrist(arm, ctx)
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
