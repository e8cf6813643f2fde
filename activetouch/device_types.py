"""The hand and arm registries: device types by name, and their typed config classes.

As LeRobot does it: a config section names a device ``type`` and carries that type's own typed
settings; the type's config class knows how to make the device (activetouch.devices makes and
connects them). Types are registered here by name with the dotted path of their config class and
imported only when used, so a config naming the fake hand never imports PyBullet and a driver's
serial or UDP code is not loaded for the twin.

Adding a device type is one module plus one line here:

1. In the device's module, a dataclass subclassing `HandConfig` (or `ArmConfig`) with the
   type's settings and a ``make(self, ctx) -> Hand`` (or ``Arm``) that imports what it needs
   (keep the module itself light: heavy imports inside ``make``).
2. One entry in `HAND_TYPES` (or `ARM_TYPES`): ``"my-hand": "pkg.module:MyHandConfig"``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

from activetouch.errors import ConfigError
from activetouch.settings import apply_section

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext
    from activetouch.interfaces import Arm, Hand
    from activetouch.planning.motion.base import WristMotion

HAND_TYPES: dict[str, str] = {
    "twin": "activetouch.sim.devices:TwinHandConfig",
    "twin-bh8": "activetouch.sim.devices:TwinBH8HandConfig",
    "fake": "activetouch.fakes.replay:FakeHandConfig",
    "reflex-takktile": "activetouch.rigs.reflex_emulated:ReflexTakktileRigConfig",
    "reflex-sf": "activetouch.drivers.reflex.sf:ReflexSFConfig",
    "barrett-bh8": "activetouch.rigs.bh8_emulated:BarrettBH8RigConfig",
}
ARM_TYPES: dict[str, str] = {
    "twin-floating": "activetouch.sim.devices:TwinFloatingArmConfig",
    "twin-baxter": "activetouch.sim.baxter:TwinBaxterArmConfig",
    "fake": "activetouch.fakes.replay:FakeArmConfig",
    "baxter": "activetouch.rigs.baxter_emulated:BaxterRigConfig",
}
# Sensors of each hand family (ids 0 .. n-1): the ReFlex's 38, the BarrettHand's 96 cells.
FAMILY_SENSORS: dict[str, int] = {"reflex": 38, "bh8": 96}
# Each finger's own sensors, ids f*n .. f*n + n - 1 for fingers f = 0, 1, 2 (the palm's after):
# the ReFlex's 9 per finger (5 proximal, 4 distal), the BarrettHand's 24 fingertip-pad cells.
# A finger's guarded close stops on one of these (both hands).
FAMILY_FINGER_SENSORS: dict[str, int] = {"reflex": 9, "bh8": 24}
DEFAULT_HAND = "twin"
DEFAULT_ARM = "twin-floating"


@dataclass
class DeviceConfig:
    """Base of every device type's settings."""

    # True for devices that stand in for the robot (twin, fake): recognitions on them place
    # the object through a served ``sim/place`` node instead of feeling what is on the table.
    simulated: ClassVar[bool] = False
    # The hand a model is trained for (its sensors and geometry): a model trained on one
    # family's grasps cannot classify another's ("reflex" or "bh8").
    family: ClassVar[str] = "reflex"

    type: str = ""


@dataclass
class HandConfig(DeviceConfig):
    def make(self, ctx: DeviceContext) -> Hand:
        raise NotImplementedError

    def default_settings(self) -> dict[str, dict[str, Any]] | None:
        """Section -> values for this hand (`[grid]` for its size, `[recognition]` for its
        sensors), used for the ones the configuration left at their (ReFlex) defaults; None:
        the defaults suit it."""
        return None


@dataclass
class ArmConfig(DeviceConfig):
    def make(self, ctx: DeviceContext) -> Arm:
        raise NotImplementedError

    def default_workcell(self) -> dict[str, Any] | None:
        """`[workcell]` values this arm type uses when the configuration leaves the workcell at
        its defaults (a table at the base frame's origin, which only a floating wrist reaches);
        None: the defaults suit it."""
        return None

    def make_wrist(self, arm: Arm, ctx: DeviceContext) -> WristMotion | None:
        """The motion layer that brings this arm's hand to object-frame wrist poses; arm types
        with real kinematics return theirs (IK, collision-checked paths, timing). None: a
        floating wrist's (its joints are the hand pose), which `make_devices` supplies."""
        return None


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
