"""The twin as device types: hand ``twin`` and arm ``twin-floating`` (activetouch.devices).

Both live in one PyBullet world (`TwinRig`, made once per `DeviceContext` and shared, with
one lock), which also answers ``sim/place``: put a library object on the table and reseed the
hand, so a recognition repeats an in-process run exactly. This module is light to import;
PyBullet loads when a device is made.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from activetouch import paths
from activetouch.device_types import ArmConfig, HandConfig
from activetouch.devices import DeviceContext
from activetouch.errors import ConfigError
from activetouch.interfaces import (
    Arm,
    ArmWrapper,
    Grasp,
    Hand,
    HandWrapper,
    JointTrajectory,
    Placed,
    Pose,
    StopLatch,
    extents_of,
)
from activetouch.models.bh8 import DEFAULT_SETTINGS
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.motion.base import Placement
from activetouch.sim import PATHS

if TYPE_CHECKING:
    from activetouch.config import Config

log = logging.getLogger(__name__)

TWIN = "twin"  # the shared resource's name (and its lock's)
# How the floating wrist gets from point to point of a trajectory (see `SimArm`).


@dataclass
class TwinHandConfig(HandConfig):
    """The twin's ReFlex hand; its physics settings are the ``[sim]`` section."""

    simulated: ClassVar[bool] = True

    def make(self, ctx: DeviceContext) -> Hand:
        rig = twin_rig(ctx)
        return PacedHand(rig.hand, ctx.cfg.service.sim_motion_delay_s)


@dataclass
class TwinBH8HandConfig(HandConfig):
    """The twin's BarrettHand BH8-280/282 (`activetouch.sim.bh8`); the world's settings
    (seed, noise stream, errors, wrist tolerance) stay in ``[sim]``. The timing follows the
    driver's defaults (`barrett-bh8`); the cell model is in the driver's units (raw / 256)."""

    simulated: ClassVar[bool] = True
    family: ClassVar[str] = "bh8"

    contact_threshold: float = 0.5  # the driver's `contact_threshold`
    noise_std: float = 0.03  # cell units
    contact_stiffness_n_per_m: float = 2000.0
    pressure_per_newton: float = 3.3  # a 5 x 6 mm cell: N over its 0.3 cm^2
    spread_sigma_m: float = 0.004  # load spreading in the pad's foam (cell pitch 5-6 mm)
    breakaway_depth_m: float = 0.001  # the inner link this deep in something: TorqueSwitch
    strain_depth_m: float = 0.003  # the outer link this deep off its pad: the strain stop
    pad_depth_m: float = 0.002  # deepest press into a pad's foam before the finger stalls
    substeps: int = 5
    control_period_s: float = 0.02  # the driver's poll: one reading per step
    close_velocity: float = 100.0  # counts per ms (the driver's)
    cts: int = 4096  # encoder counts per motor revolution
    finger_limit_counts: float = 190000.0
    spread_limit_rad: float = 3.14
    spread_speed_rad_s: float = 2.0

    def check(self) -> None:
        positive = (
            "contact_threshold",
            "contact_stiffness_n_per_m",
            "pressure_per_newton",
            "spread_sigma_m",
            "breakaway_depth_m",
            "strain_depth_m",
            "pad_depth_m",
            "control_period_s",
            "close_velocity",
            "finger_limit_counts",
            "spread_speed_rad_s",
        )
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and np.isfinite(v) and v > 0):
                raise ConfigError(f"hand.{name} must be > 0, got {v!r}")
        if self.noise_std < 0 or self.substeps < 1 or self.cts < 1:
            raise ConfigError("hand.noise_std must be >= 0, hand.substeps and hand.cts >= 1")
        if not 0 < self.spread_limit_rad <= np.pi + 1e-6:
            raise ConfigError(
                f"hand.spread_limit_rad must be in (0, pi], got {self.spread_limit_rad}"
            )

    def make(self, ctx: DeviceContext) -> Hand:
        rig = twin_rig(ctx)
        return PacedHand(rig.hand, ctx.cfg.service.sim_motion_delay_s)

    def default_settings(self) -> dict[str, dict[str, Any]] | None:
        return {k: dict(v) for k, v in DEFAULT_SETTINGS.items()}


@dataclass
class TwinFloatingArmConfig(ArmConfig):
    """The twin's floating wrist (six joints: the hand pose in the base frame)."""

    simulated: ClassVar[bool] = True

    # "teleport": jump between trajectory points, checking each (the paper's simulation; fast
    # training of large libraries); "straight": check every few mm along the way.
    path: str = "teleport"

    def check(self) -> None:
        if self.path not in PATHS:
            raise ConfigError(f"arm.path: {self.path!r} is not one of {', '.join(PATHS)}")

    def make(self, ctx: DeviceContext) -> Arm:
        rig = twin_rig(ctx)
        rig.arm.path = self.path
        return PacedArm(rig.arm, ctx.cfg.service.sim_motion_delay_s)


def reset_twin(world: Any, hand: Any, spec: Any, seed: int, sim: Any = None) -> None:
    """Put `spec` on the table of a used twin and bring it back to the state of a fresh one
    (`open_twin(spec, cfg, seed)`), so a recognition repeats the in-process run exactly: with
    `sim`'s placement error for `seed` (sim/errors.py), a faulty hand's faults redrawn."""
    # deferred: loads pybullet (sim.errors imports sim.world)
    from activetouch.sim.errors import place_displaced, placement_error

    hand.clear_stop()
    world.set_hand(0.0, np.zeros(3), np.zeros(3))
    world.open_fingers()
    world.set_wrist(Pose(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0])))
    if sim is None:
        world.place(spec)
    else:
        place_displaced(world, spec, placement_error(sim, seed))
    hand.reseed(seed)


def make_twin_world(hand: Any, sim: Any, workcell: Any) -> Any:
    """The twin world for hand config `hand`: the BH8's for ``twin-bh8``, else the ReFlex's
    (a fake hand on the twin arm moves the ReFlex's body)."""
    if getattr(hand, "family", "reflex") == "bh8":  # the twin, or the BH8 on its emulator
        from activetouch.sim.bh8 import BH8World  # deferred: loads pybullet

        return BH8World(sim, workcell=workcell)
    from activetouch.sim.world import SimWorld  # deferred: loads pybullet

    return SimWorld(sim, workcell=workcell)


def make_twin_hand(hand: Any, world: Any, sim: Any, seed: int | None = None) -> Any:
    """The twin hand on `world` (`make_twin_world`), read through `sim`'s sensor faults if it
    sets any; the BH8's with the twin's default settings when `hand` is the emulated
    driver's."""
    # deferred: loads pybullet (sim.errors imports sim.world)
    from activetouch.sim.errors import sensor_faults

    faults = sensor_faults(sim)
    if getattr(hand, "family", "reflex") == "bh8":
        from activetouch.sim.bh8 import FaultySimBH8Hand, SimBH8Hand  # deferred: pybullet

        twin = hand if isinstance(hand, TwinBH8HandConfig) else TwinBH8HandConfig()
        if faults.active:
            return FaultySimBH8Hand(world, twin, sim, faults, seed)
        return SimBH8Hand(world, twin, sim, seed)
    from activetouch.sim.hand import FaultySimHand, SimHand  # deferred: loads pybullet

    if faults.active:
        return FaultySimHand(world, sim, faults, seed)
    return SimHand(world, sim, seed)


class TwinRig:
    """One twin world with its hand and floating arm, and the object library it places from."""

    def __init__(self, cfg: Config, data: Any) -> None:
        # deferred: loads pybullet
        from activetouch.sim.world import SimArm

        self.sim = cfg.sim
        self.world = make_twin_world(cfg.hand, cfg.sim, cfg.workcell)
        self.hand = make_twin_hand(cfg.hand, self.world, cfg.sim)
        self.arm = SimArm(self.world)
        self.library_root = paths.objects_dir(paths.data_dir(data))
        # Called at the end of every `place` (e.g. an arm type bringing its arm home, as in a
        # freshly made twin): devices on this rig hook in here instead of wrapping `place`.
        self.after_place: list[Callable[[], None]] = []

    def place(self, obj: str, seed: int | None = None) -> Placed:
        """Put library object `obj` on the table; restart the hand's noise from `seed` (None:
        the configured one), so a recognition repeats exactly for a seed."""

        spec = ObjectLibrary(self.library_root).get(obj)  # DataError names the known
        noise_seed = self.hand.cfg.seed if seed is None else seed
        reset_twin(self.world, self.hand, spec, noise_seed, self.sim)
        for hook in self.after_place:
            hook()
        log.info("object placed", extra={"object": spec.name, "seed": seed})
        return Placed(spec.name, extents_of(spec.extents))

    def placement(self) -> Any:

        return Placement(self.world.object_origin)

    def close(self) -> None:
        self.world.close()


def twin_rig(ctx: DeviceContext) -> TwinRig:
    def make() -> TwinRig:
        rig = TwinRig(ctx.cfg, ctx.data)
        lock = ctx.lock(TWIN)

        def close() -> None:
            # A worker stuck in the world would crash on a closed client: close it when free.
            if lock.acquire(timeout=1.0):
                try:
                    rig.close()
                finally:
                    lock.release()

        ctx.on_close(close)
        ctx.add_place(rig.place, rig.placement)
        return rig

    return ctx.shared(TWIN, make)


class PacedHand(HandWrapper):
    """A simulated hand taking `delay` s per grasp like a real one (0: flat out); a stop cuts
    the wait short."""

    def __init__(self, hand: Hand, delay: float) -> None:
        super().__init__(hand)
        self.delay = float(delay)

    def guarded_close(self) -> Grasp:
        latch: StopLatch | None = getattr(self.inner, "stop_latch", None)
        if self.delay > 0:
            if latch is not None:
                latch.wait(self.delay)
            else:
                time.sleep(self.delay)
        return self.inner.guarded_close()


class PacedArm(ArmWrapper):
    """A simulated arm taking `delay` s per motion; a stop cuts the motion short (it raises,
    as a real arm stopped short of its target would not be where it was sent)."""

    def __init__(self, arm: Arm, delay: float) -> None:
        super().__init__(arm)
        self.delay = float(delay)
        self._stopped = threading.Event()

    def execute(self, trajectory: JointTrajectory) -> None:
        if self.delay > 0 and self._stopped.wait(self.delay):
            pass  # the inner arm is stopped too: it refuses below
        self.inner.execute(trajectory)

    def stop(self) -> None:
        self._stopped.set()
        self.inner.stop()

    def estop(self) -> None:
        self._stopped.set()  # cut the paced wait short, as stop does
        self.inner.estop()

    def clear_stop(self) -> None:
        self._stopped.clear()
        self.inner.clear_stop()
