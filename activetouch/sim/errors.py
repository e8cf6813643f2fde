"""The real robot's errors the twin adds for evaluation (`SimConfig`'s `placement_error_*`,
`fault_*`, `nudge_max_m`; docs/benchmark.md): the object stood off its nominal placement by a
draw from the run's seed (which only the physics sees), and the hand read through faulty
sensors. Every twin applies them: `open_twin` in-process and the device registry's twin rig
(the daemon's, the Baxter twin's) alike."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from activetouch.config import SimConfig
from activetouch.errors import ConfigError
from activetouch.objects.library import ObjectSpec
from activetouch.recognition.faults import SensorFaults
from activetouch.sim.world import SimWorld

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


def place_displaced(world: SimWorld, spec: ObjectSpec, err: PlacementError) -> None:
    """Stand `spec` on the table off its nominal placement by `err`; the object frame, which
    the wrist (`TwinWrist`) and the support plane read, stays nominal."""
    world.place(spec, offset_xy=(err.dx, err.dy), yaw_rad=err.yaw_rad)
