"""The twin as one piece: a world with an object on the table, the hand and the arm on it."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from activetouch.config import SimConfig, WorkcellConfig
from activetouch.planning.motion.base import Placement
from activetouch.planning.motion.floating import FloatingWristMotion
from activetouch.sim.hand import SimHand
from activetouch.sim.objects import ObjectSpec
from activetouch.sim.world import SimArm, SimWorld


@dataclass
class Twin:
    world: SimWorld
    hand: SimHand
    arm: SimArm
    wrist: FloatingWristMotion  # wrist poses in the object frame -> the arm's joints

    @property
    def support_z(self) -> float:
        """The table plane in the object frame (from the workcell)."""
        return self.world.support_z

    def place(self, spec: ObjectSpec, seed: int) -> None:
        """Put `spec` on the table and bring the twin back to the state of a fresh one
        (`open_twin(spec, cfg, seed)`), so a recognition repeats an in-process run exactly."""
        from activetouch.sim.devices import reset_twin

        reset_twin(self.world, self.hand, spec, seed)


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
) -> Iterator[Twin]:
    """A headless twin with `spec` placed on the table (none: an empty table)."""
    world = SimWorld(cfg, workcell=workcell)
    try:
        if spec is not None:
            world.place(spec)
        arm = SimArm(world)
        yield Twin(world, SimHand(world, cfg, seed=seed), arm, TwinWrist(arm))
    finally:
        world.close()
