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


def reset_twin(world: Any, hand: Any, spec: Any, seed: int) -> None:
    """Put `spec` on the table of a used twin and bring it back to the state of a fresh one
    (`open_twin(spec, cfg, seed)`), so a recognition repeats the in-process run exactly."""
    hand.clear_stop()
    world.set_hand(0.0, np.zeros(3), np.zeros(3))
    world.open_fingers()
    world.set_wrist(Pose(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0])))
    world.place(spec)
    hand.reseed(seed)


class TwinRig:
    """One twin world with its hand and floating arm, and the object library it places from."""

    def __init__(self, cfg: Config, data: Any) -> None:
        # deferred: loads pybullet
        from activetouch.sim.hand import SimHand

        # deferred: loads pybullet
        from activetouch.sim.world import SimArm, SimWorld

        self.world = SimWorld(cfg.sim, workcell=cfg.workcell)
        self.hand = SimHand(self.world, cfg.sim)
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
        reset_twin(self.world, self.hand, spec, noise_seed)
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
