"""The twin as one piece: a world with an object on the table, the hand and the arm on it.

With the real robot's errors set in `SimConfig` (`placement_error_m`, `placement_error_deg`,
`fault_*`; docs/benchmark.md) a twin made for a seed misplaces the object by a draw from that
seed, which only the physics sees (the wrist, the support plane and whoever reads the object
frame believe the nominal placement), and its hand reads through faulty sensors."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from activetouch.config import SimConfig, WorkcellConfig
from activetouch.device_types import HandConfig
from activetouch.errors import ConfigError
from activetouch.interfaces import Hand
from activetouch.objects.library import ObjectSpec
from activetouch.planning.motion.base import Placement
from activetouch.planning.motion.floating import FloatingWristMotion
from activetouch.recognition.faults import (
    SensorFaults,
)
from activetouch.sim.bh8 import FaultySimBH8Hand
from activetouch.sim.devices import (
    TwinBH8HandConfig,
    make_twin_hand,
    make_twin_world,
    reset_twin,
)
from activetouch.sim.faulty import FaultyReadings
from activetouch.sim.hand import SimHand
from activetouch.sim.world import SimArm, SimWorld

_PLACEMENT_TAG = 0x91ACE  # keeps the placement draw apart from the hand's noise streams


@dataclass(frozen=True)
class PlacementError:
    """Where the object really stands, relative to where the workcell says it does."""

    dx: float = 0.0  # metres
    dy: float = 0.0
    yaw_rad: float = 0.0  # about the vertical through the object's centre


def placement_error(cfg: SimConfig, seed: int) -> PlacementError:
    """The seed's placement error: uniform within +-`placement_error_m` in x and y and
    +-`placement_error_deg` about z (zero without those settings)."""
    m, deg = float(cfg.placement_error_m), float(cfg.placement_error_deg)
    if not (np.isfinite(m) and np.isfinite(deg) and m >= 0 and deg >= 0):
        raise ConfigError(
            f"sim.placement_error_m and sim.placement_error_deg must be >= 0, got {m}, {deg}"
        )
    nudge = float(cfg.nudge_max_m)
    if not (np.isfinite(nudge) and 0 <= nudge <= 0.05):
        raise ConfigError(f"sim.nudge_max_m must be in 0..0.05 m, got {nudge}")
    if m == 0 and deg == 0:
        return PlacementError()
    u = np.random.default_rng([int(seed), _PLACEMENT_TAG]).uniform(-1.0, 1.0, 3)
    return PlacementError(float(u[0] * m), float(u[1] * m), float(np.radians(u[2] * deg)))


def sensor_faults(cfg: SimConfig) -> SensorFaults:
    """The `fault_*` settings as a `SensorFaults`; ConfigError naming them if out of range."""
    try:
        return SensorFaults(
            noise_std=float(cfg.fault_noise_std),
            dead=int(cfg.fault_dead),
            stuck=int(cfg.fault_stuck),
            spurious=float(cfg.fault_spurious),
            drift=float(cfg.fault_sensor_drift),
            finger_offset_rad=float(cfg.fault_finger_offset_rad),
        )
    except ValueError as e:
        raise ConfigError(f"sim.fault_*: {e}") from None


class FaultySimHand(FaultyReadings, SimHand):
    """The twin's ReFlex read through faulty sensors."""

    def __init__(
        self, world: SimWorld, cfg: SimConfig, faults: SensorFaults, seed: int | None = None
    ) -> None:
        self.faults = faults
        super().__init__(world, cfg, seed=seed)  # calls reseed(), which draws the faults


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

        reset_twin(self.world, self.hand, spec, seed)  # also redraws a faulty hand's sensors
        err = placement_error(self.cfg, seed) if self.cfg is not None else PlacementError()
        if err != PlacementError():
            place_displaced(self.world, spec, err)


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
    faults = sensor_faults(cfg)
    world = make_twin_world(hand, cfg, workcell)
    try:
        if spec is not None:
            place_displaced(world, spec, err)
        arm = SimArm(world)
        if faults.active and isinstance(hand, TwinBH8HandConfig):
            hand_: Hand = FaultySimBH8Hand(world, hand, cfg, faults, seed)
        elif faults.active:
            hand_ = FaultySimHand(world, cfg, faults, seed)
        else:
            hand_ = make_twin_hand(hand, world, cfg, seed)
        yield Twin(world, hand_, arm, TwinWrist(arm), cfg)
    finally:
        world.close()


def place_displaced(world: SimWorld, spec: ObjectSpec, err: PlacementError) -> None:
    """Stand `spec` on the table off its nominal placement by `err`; the object frame, which
    the wrist (`TwinWrist`) and the support plane read, stays nominal."""
    world.place(spec, offset_xy=(err.dx, err.dy), yaw_rad=err.yaw_rad)
