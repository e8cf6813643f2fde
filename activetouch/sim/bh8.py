"""The twin's BarrettHand BH8-280/282: `BH8World` (the table, the object and the BH8 in
PyBullet) and `SimBH8Hand`, its 96 tactile cells and its guarded close.

The hand is `models.bh8` (the BH8-series manual's D-H model, modelled boxes and pads). As the
ReFlex twin (`sim.hand`), the fingers are posed kinematically and every reading is one Bullet
collision query: the objects are fixed and a BH8 finger stops when its fingertip pad feels
the object, so stepping a dynamic finger would cost thousands of solver steps for the same
stopping angles.

Guarded close, as the driver (`drivers/barrett/bh8.py`) runs the real hand: every finger's
motor turns `close_velocity` counts per millisecond for one `control_period_s` per reading.
While the TorqueSwitch holds, inner = motor / 125 and outer = inner / 3. When the inner link
is blocked (pushed `breakaway_depth_m` into something: it carries no cells, so only its load
says so) or reaches its stop, the switch breaks away: the inner link stays and the whole
motor travel goes to the outer link, which curls on until its pad feels the object. A finger
stops (as the driver idles it) on the reading that sees a cell of its own pad over the
threshold, i.e. at the end of the control step in which the pad first touched, or earlier if
the pad is pressed `pad_depth_m` into its foam (`contact`); where its outer link is pushed
`strain_depth_m` deep without a pad contact (the strain gauge's load, e.g. on the
fingertip's back: `strain`); or at its limits (`limit`). The step in which a finger first
meets something is re-run in `substeps` parts. The palm's cells stop no finger (the palm pad
belongs to the spread puck).

Cells: each contact point on an outer link or the palm loads the cells of that pad with
stiffness x penetration spread by a Gaussian of the point-cell distance (`spread_sigma_m`);
a cell reads its load x `pressure_per_newton` plus noise, in the driver's units (raw / 256).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from activetouch.config import SimConfig, WorkcellConfig
from activetouch.interfaces import Grasp
from activetouch.models import bh8
from activetouch.sim.faulty import FaultyReadings
from activetouch.sim.hand import TwinHand, site_forces
from activetouch.sim.world import HandContacts, HandLinks, SimWorld

if TYPE_CHECKING:
    from activetouch.recognition.faults import SensorFaults
    from activetouch.sim.devices import TwinBH8HandConfig

STOP_CONTACT, STOP_STRAIN, STOP_LIMIT = "contact", "strain", "limit"


class BH8World(SimWorld):
    """A twin world whose hand is the BH8: preshape = spread, proximal = inner links,
    distal = outer links (`set_hand(spread, inner, outer)`)."""

    def __init__(self, cfg: SimConfig | None = None, workcell: WorkcellConfig | None = None):
        super().__init__(cfg, workcell=workcell)

    def _hand_urdf(self, cache: Path | None) -> Path:
        return bh8.urdf_file(cache)

    def _spread_signs(self) -> list[list[float]]:
        return [[1.0], [1.0]]  # the URDF's axes carry F1's and F2's opposite turns

    def _index_links(self) -> HandLinks:
        by_joint, by_link, collision = self._hand_indices()
        site_link = np.full(bh8.N_CELLS, -1, dtype=np.int64)  # the palm is the base (-1)
        for f in range(3):
            site_link[24 * f : 24 * f + 24] = by_link[bh8.OUTER_LINKS[f]]
        return HandLinks(
            preshape=(by_joint[bh8.SPREAD_JOINTS[0]], by_joint[bh8.SPREAD_JOINTS[1]]),
            proximal=tuple(by_joint[n] for n in bh8.INNER_JOINTS),  # type: ignore[arg-type]
            distal=tuple(by_joint[n] for n in bh8.OUTER_JOINTS),  # type: ignore[arg-type]
            pad=-1,
            collision_links=tuple(sorted(collision)),
            site_link=site_link,
        )

    def open_fingers(self) -> None:
        """Open every finger fully (the HI position: inner = outer = 0), spread kept."""
        self.set_hand(self._preshape, np.zeros(3), np.zeros(3))

    def sensor_sites_hand(self, proximal: np.ndarray | None = None) -> np.ndarray:
        """(96, 3) cell positions in the hand frame at the current joint angles (or with the
        inner joints at `proximal`)."""
        inner = self._proximal if proximal is None else proximal
        return bh8.cell_positions(self._preshape, inner, self._distal)


class SimBH8Hand(TwinHand):
    """The twin's BH8 on the hand body of a `BH8World`."""

    def __init__(
        self,
        world: BH8World,
        hcfg: TwinBH8HandConfig,
        cfg: SimConfig | None = None,
        seed: int | None = None,
    ) -> None:
        hcfg.check()
        self.hcfg = hcfg
        self._init_twin(world, cfg or world.cfg, seed, bh8.N_CELLS, hcfg.contact_threshold)
        self.preshape_limit_rad = hcfg.spread_limit_rad
        self.preshape_speed_rad_s = hcfg.spread_speed_rad_s
        links = world.links
        self._finger_col = {int(links.proximal[f]): (f, 0) for f in range(3)}
        self._finger_col.update({int(links.distal[f]): (f, 1) for f in range(3)})
        self._sensing_links = {int(links.distal[f]) for f in range(3)} | {-1}
        self.last_close_reasons: tuple[str, ...] = ()

    @property
    def motor_step(self) -> float:
        """Motor radians per reading while closing."""
        h = self.hcfg
        counts = h.close_velocity * h.control_period_s * 1000.0
        return counts * 2 * math.pi / h.cts

    @property
    def motor_limit(self) -> float:
        return self.hcfg.finger_limit_counts * 2 * math.pi / self.hcfg.cts

    # -- Hand interface -------------------------------------------------------------------

    def open(self) -> None:
        w = self.world
        travel = float(np.max(bh8.motor_of(w.proximal, w.distal))) if w.proximal.size else 0.0
        self._open_fingers()
        self._robot_seconds += travel / self.motor_step * self.hcfg.control_period_s

    def guarded_close(self) -> Grasp:
        """Close every finger until its pad feels contact, its strain gauge a load, or its
        limits (module notes); report the cells over threshold at the end. A `stop()` ends
        it at the next reading with `StoppedError`."""
        self.stop_latch.check("guarded close")
        h, w = self.hcfg, self.world
        rng = self._grasp_rng()
        live = ~self.masked
        thr = self.thresholds
        step, fine_step = self.motor_step, self.motor_step / h.substeps
        inner, outer = w.proximal, w.distal
        motor = bh8.motor_of(inner, outer)
        motor0 = motor.copy()
        broken = outer > bh8.coupled_outer(inner) + 1e-9
        active = np.ones(3, dtype=bool)
        fine = np.zeros(3, dtype=bool)
        sub = np.zeros(3, dtype=np.int64)  # fine substeps since the last reading
        touching = np.zeros(3, dtype=bool)  # its pad felt the object: runs out its step
        reasons = [""] * 3

        def pads_sensed(p: np.ndarray) -> np.ndarray:
            over = (p > thr) & live
            return over[: bh8.N_FINGER_CELLS].reshape(3, bh8.CELLS_PER_PAD).any(axis=1)

        w.flush_contacts()
        pressures, _ = self._sense(w.hand_contacts(), rng)
        for f in np.flatnonzero(pads_sensed(pressures)).tolist():
            active[f], reasons[f] = False, STOP_CONTACT  # a finger already touching stays
        while active.any():
            self.stop_latch.check("guarded close")  # one control step: a stop acts here
            new_motor = np.where(active, motor + np.where(fine, fine_step, step), motor)
            new_motor = np.minimum(new_motor, self.motor_limit)
            new_inner = np.where(
                broken, inner, np.minimum(new_motor / bh8.INNER_RATIO, bh8.INNER_LIMIT)
            )
            new_outer = np.where(
                broken, bh8.outer_from_motor(new_motor, inner), bh8.coupled_outer(new_inner)
            )
            new_outer = np.minimum(new_outer, bh8.OUTER_LIMIT)
            w.set_hand(
                w.preshape_angle,
                np.where(active, new_inner, inner),
                np.where(active, new_outer, outer),
            )
            pressures, depth = self._sense(w.hand_contacts(), rng)
            sensed = pads_sensed(pressures)
            for f in np.flatnonzero(active).tolist():
                d_inner, d_outer = depth[f]
                if not fine[f] and (sensed[f] or d_inner > 0.0 or d_outer > 0.0):
                    fine[f] = True  # re-run this step finely from where the finger was
                    continue
                if touching[f] and d_outer > h.pad_depth_m:
                    active[f], reasons[f] = False, STOP_CONTACT  # pressed into its foam
                    continue
                if not touching[f] and d_outer > h.strain_depth_m:
                    active[f], reasons[f] = False, STOP_STRAIN  # loaded off its pad
                    continue
                if not touching[f] and not broken[f] and d_inner > h.breakaway_depth_m:
                    broken[f] = True  # the inner link stays where it was; the outer curls on
                    continue
                motor[f], inner[f], outer[f] = new_motor[f], new_inner[f], new_outer[f]
                sub[f] = (sub[f] + 1) % h.substeps if fine[f] else 0
                touching[f] |= bool(sensed[f])
                if touching[f] and sub[f] == 0:
                    # The driver sees the contact at the end of this control step and idles
                    # the finger there.
                    active[f], reasons[f] = False, STOP_CONTACT
                elif not broken[f] and inner[f] >= bh8.INNER_LIMIT - 1e-12:
                    broken[f] = True
                if active[f] and (
                    motor[f] >= self.motor_limit - 1e-12 or outer[f] >= bh8.OUTER_LIMIT - 1e-12
                ):
                    active[f], reasons[f] = False, STOP_CONTACT if touching[f] else STOP_LIMIT
        w.set_hand(w.preshape_angle, inner, outer)
        pressures, _ = self._sense(w.hand_contacts(), rng)
        self.last_close_reasons = tuple(reasons)
        steps = int(np.ceil(float((motor - motor0).max()) / step - 1e-9))
        self._robot_seconds += (max(steps, 0) + 1) * h.control_period_s
        ids = np.flatnonzero((pressures > thr) & live)
        return Grasp(
            sensor_ids=ids,
            xyz=w.sensor_sites_hand()[ids],
            pressures=pressures[ids],
            finger_angles=inner.copy(),
            preshape=w.preshape_angle,
        )

    # -- sensing --------------------------------------------------------------------------

    def sense(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At the hand's current pose: (96,) cell readings (noise from the state stream),
        (3, 2) the deepest penetration of each finger's inner and outer links, and (3,) the
        load on each outer link, newtons (what its strain gauge feels: stiffness x its
        deepest penetration, so a fingertip pushed `strain_depth_m` deep reads the load the
        twin's close stops on)."""
        w = self.world
        w.flush_contacts()
        contacts = w.hand_contacts()
        pressures, depth = self._sense(contacts, self._state_rng)
        load = self.hcfg.contact_stiffness_n_per_m * depth[:, 1]
        return pressures, depth, load

    def _sense(
        self, contacts: HandContacts, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """(96,) cell readings with noise, and (3, 2) the deepest penetration of each
        finger's inner and outer links."""
        h, w = self.hcfg, self.world
        depth = np.zeros((3, 2))
        sensing = np.zeros(len(contacts), dtype=bool)
        for i, (link, dep) in enumerate(
            zip(contacts.link.tolist(), contacts.depth.tolist(), strict=True)
        ):
            fc = self._finger_col.get(link)
            if fc is not None:
                depth[fc] = max(depth[fc], dep)
            sensing[i] = link in self._sensing_links
        force = np.zeros(bh8.N_CELLS)
        if sensing.any():
            force = site_forces(
                contacts.link[sensing],
                w.world_to_hand(contacts.position[sensing]),
                contacts.depth[sensing],
                w.links.site_link,
                w.sensor_sites_hand(),
                h.spread_sigma_m,
                h.contact_stiffness_n_per_m,
            )
        pressures = force * h.pressure_per_newton
        if h.noise_std > 0:
            pressures = pressures + rng.normal(0.0, h.noise_std, bh8.N_CELLS)
        return pressures, depth


class FaultySimBH8Hand(FaultyReadings, SimBH8Hand):
    """The twin's BH8 read through faulty cells; the extra noise scaled from the ReFlex's
    units by the ratio of the contact thresholds (0.5 / 20: noise +5 is +0.125 cell units)."""

    def __init__(
        self,
        world: BH8World,
        hcfg: TwinBH8HandConfig,
        cfg: SimConfig,
        faults: SensorFaults,
        seed: int | None = None,
    ) -> None:
        self.faults = faults
        self.noise_scale = hcfg.contact_threshold / cfg.contact_threshold
        super().__init__(world, hcfg, cfg, seed)

    def _fault_threshold(self) -> float:
        return float(self.hcfg.contact_threshold)
