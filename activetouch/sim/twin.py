"""The twin as one piece: a world with an object on the table, the hand and the arm on it."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from activetouch.config import SimConfig
from activetouch.sim.hand import SimHand
from activetouch.sim.objects import ObjectSpec
from activetouch.sim.world import SimArm, SimWorld


@dataclass
class Twin:
    world: SimWorld
    hand: SimHand
    arm: SimArm


@contextmanager
def open_twin(spec: ObjectSpec | None, cfg: SimConfig, seed: int | None = None) -> Iterator[Twin]:
    """A headless twin with `spec` placed on the table (none: an empty table)."""
    world = SimWorld(cfg)
    try:
        if spec is not None:
            world.place(spec)
        yield Twin(world, SimHand(world, cfg, seed=seed), SimArm(world))
    finally:
        world.close()
