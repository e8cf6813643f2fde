"""The twin as one piece: a world with an object on the table, the hand and the arm on it.

With the real robot's errors set in `SimConfig` (`placement_error_m`, `placement_error_deg`,
`fault_*`; docs/benchmark.md) a twin made for a seed misplaces the object by a draw from that
seed, which only the physics sees (the wrist, the support plane and whoever reads the object
frame believe the nominal placement), and its hand reads through faulty sensors."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from activetouch.config import SimConfig, WorkcellConfig
from activetouch.device_types import HandConfig
from activetouch.interfaces import Hand
from activetouch.objects.library import ObjectSpec
from activetouch.planning.motion.base import Placement
from activetouch.planning.motion.floating import FloatingWristMotion
from activetouch.sim.devices import make_twin_hand, make_twin_world, reset_twin
from activetouch.sim.errors import (  # noqa: F401  (the errors' names, as they were here)
    PlacementError,
    place_displaced,
    placement_error,
    sensor_faults,
)
from activetouch.sim.hand import FaultySimHand  # noqa: F401
from activetouch.sim.world import SimArm, SimWorld


@dataclass
class Twin:
    world: SimWorld
    hand: Hand
    arm: SimArm
    wrist: FloatingWristMotion  # wrist poses in the object frame -> the arm's joints
    cfg: SimConfig | None = None  # for the placement error of `place()`

    @property
    def support_z(self) -> float:
        """The table plane in the object frame (from the workcell)."""
        return self.world.support_z

    def place(self, spec: ObjectSpec, seed: int) -> None:
        """Put `spec` on the table and bring the twin back to the state of a fresh one
        (`open_twin(spec, cfg, seed)`), so a recognition repeats an in-process run exactly."""

        reset_twin(self.world, self.hand, spec, seed, self.cfg)  # a faulty hand's faults too


class TwinWrist(FloatingWristMotion):
    """The floating wrist's motion layer in a twin: the object is wherever the world placed it."""

    def __init__(self, arm: SimArm) -> None:
        super().__init__(arm)
        self.world = arm.world

    @property  # type: ignore[override]
    def placement(self) -> Placement:
        return Placement(self.world.object_origin)

    @placement.setter
    def placement(self, value: Placement) -> None:
        pass  # the world knows where it put the object


def twin_wrist(arm: SimArm) -> TwinWrist:
    return TwinWrist(arm)


@contextmanager
def open_twin(
    spec: ObjectSpec | None,
    cfg: SimConfig,
    seed: int | None = None,
    workcell: WorkcellConfig | None = None,
    hand: HandConfig | None = None,
) -> Iterator[Twin]:
    """A headless twin with `spec` placed on the table (none: an empty table), misplaced and
    with faulty sensors if `cfg` asks for the real robot's errors (drawn from `seed`, else
    `cfg.seed`). `hand`: the configured hand (``twin-bh8`` gives the BarrettHand's twin;
    anything else, or None, the ReFlex's)."""
    run_seed = cfg.seed if seed is None else int(seed)
    err = placement_error(cfg, run_seed)
    world = make_twin_world(hand, cfg, workcell)
    try:
        if spec is not None:
            place_displaced(world, spec, err)
        arm = SimArm(world)
        hand_: Hand = make_twin_hand(hand, world, cfg, seed)
        yield Twin(world, hand_, arm, TwinWrist(arm), cfg)
    finally:
        world.close()
