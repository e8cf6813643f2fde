"""`SimHand`: the twin's ReFlex hand with 38 tactile sensors and the guarded enclosure grasp.

Physics approach (chosen for speed with real collision geometry): the fingers are posed
kinematically and every reading runs Bullet's collision detection between the hand's boxes and
the table/object shapes.

Tactile skin. TakkTile barometers sit under an elastomer layer, so a load pressed into the skin
spreads to neighbouring sensors (pitch 7.9 mm). Each penetrating contact point on a
sensor-carrying link carries a normal force of stiffness x penetration depth; a sensor site on
the same link feels that force times a Gaussian of the point-site distance (`spread_sigma_m`,
1 right over the site, so a contact centred on a site reads as its full force); sensors of other
links feel nothing (proximal, distal and palm skins are separate pieces). A sensor reads its
summed force in sensor units plus Gaussian noise; contact = pressure over the threshold. So a
light touch registers on one sensor and a firm one also on its neighbours, never three pitches
away (the Gaussian there is ~1e-5).

Why not dynamic, position-controlled joints: a stable finger/object contact needs ~1 ms steps
and several steps per spool increment, i.e. thousands of solver steps per grasp (a few grasps
per second), while the objects are fixed and the ReFlex stops each finger right after its first
contact. Kinematic stepping + collision queries gives the stopping angles and contact sites at
> 20 grasps per second.

Guarded close, as the ReFlex does it: each finger's spool advances 0.05 rad per step (one
reading of the hand); a free finger bends its proximal joint by spool / (1 + k) and its distal
joint by k times that (the flexure coupling). When a step first makes a finger touch anything,
that step is re-run in `substeps` parts (readings in between are finer than the real hand's).

After the first sensed contact. The ReFlex Beta driver's guarded_move (reflex-ros-pkg
reflex_base.py; "close until a sensor of the finger is in contact", as the paper describes its
guarded enclosure) sends each finger, at every reading without contact, the command "measured
spool + 0.05 rad", and at the first reading with contact stops sending commands: the servo still
runs on to the command it already has. So a finger does not freeze where it first touched: its
tendon travels on to (spool at the last contact-free reading) + `post_contact_travel_rad`
(default one step; 0 freezes the finger at its first sensed contact). Where that travel goes
follows the finger's mechanics: the distal bend is passive (tendon against a flexure), and the
skin is far stiffer than the flexure, so a proximal link in contact holds its angle and the
distal wraps on (tendon tension rising) until the travel is used or the distal is pressed into
something; a distal link in contact is pressed on into its skin. No link is pressed deeper than
`skin_depth_m`: the finger settles just short of it (the servo stalls against the compressed
skin; the last substep is halved `PRESS_HALVINGS` times to find where). The remaining travel is
at most one step (< 0.05 rad), so this adds neighbouring sensors and firmer readings, not new
contact regions. Closing on until both links touch (reflex_base's separate `solid_contact`
primitive) is not what the paper's guarded enclosure does, so it is not modelled.

Before any sensed contact, a link pushed `stall_depth_m` deep (an unsensed part, e.g. a link's
side or back) is blocked: a blocked proximal link holds and the distal joint takes the rest of
the tendon travel (the passive flexure wraps around the object); a blocked distal link stalls
the finger. A finger also stops at the spool limit.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from activetouch.config import SimConfig
from activetouch.interfaces import (
    N_FINGER_SENSORS,
    N_FINGERS,
    N_SENSORS,
    SENSORS_PER_FINGER,
    Grasp,
    Hand,
    HandState,
    StopLatch,
)
from activetouch.models.reflex import (
    N_PROXIMAL_SENSORS,
    coupled_joints,
    finger_sensor_positions,
    palm_site_positions,
)
from activetouch.recognition.faults import SensorFaults
from activetouch.sim.faulty import FaultyReadings
from activetouch.sim.nudge import nudge_step, shrink_until_clear
from activetouch.sim.world import HandContacts, SimWorld

STOP_CONTACT = "contact"
STOP_LIMIT = "limit"
STOP_STALL = "stall"
# A finger pressing into its skin past a sensed contact halves its substep this many times
# before it settles short of `skin_depth_m` (resolution: substep / 8, ~0.1 mm at the tip).
PRESS_HALVINGS = 3


def spread_kernel(distance: np.ndarray, sigma: float) -> np.ndarray:
    """Share of a contact's load a site feels at `distance` (metres) through the skin: a
    Gaussian, 1 right over the site."""
    return np.exp(-0.5 * (np.asarray(distance) / sigma) ** 2)


def site_forces(
    contact_link: np.ndarray,
    contact_xyz: np.ndarray,
    contact_depth: np.ndarray,
    site_link: np.ndarray,
    site_xyz: np.ndarray,
    sigma: float,
    stiffness: float,
) -> np.ndarray:
    """(n_sites,) load on each sensor, newtons: every contact point's force (stiffness x
    penetration) spread over the sites on its own link by `spread_kernel` of the point-site
    distance; the skin of one link does not carry load to another's."""
    if len(contact_link) == 0:
        return np.zeros(len(site_link))
    d2 = np.sum((contact_xyz[:, None, :] - site_xyz[None, :, :]) ** 2, axis=2)
    weight = np.exp(d2 * (-0.5 / (sigma * sigma)))
    weight[contact_link[:, None] != site_link[None, :]] = 0.0
    return (stiffness * contact_depth) @ weight


def pose_keyed_rng(world: SimWorld, seed: int) -> np.random.Generator:
    """A noise stream seeded from what defines a grasp (seed, object, wrist pose, hand joint
    angles), so a grasp does not depend on earlier grasps (``noise_mode = "pose"``)."""
    w = world
    obj = w.object
    pose = w.wrist_pose.as_array()
    if pose[6] < 0 or (pose[6] == 0 and pose[3:6][np.flatnonzero(pose[3:6])[:1]].sum() < 0):
        pose[3:] = -pose[3:]  # q and -q are one rotation: one noise stream
    key = np.concatenate([pose, [w.preshape_angle], w.proximal, w.distal])
    text = f"{seed}|{obj.name if obj else ''}|" + ",".join(
        f"{v:.6f}" for v in np.round(key, 6) + 0.0
    )
    digest = hashlib.sha256(text.encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:16], "little"))


@dataclass(frozen=True)
class CloseResult:
    """Diagnostics of the last guarded close."""

    stop_reasons: tuple[str, ...]  # per finger: contact | limit | stall
    spool: np.ndarray  # (3,) final spool angles
    proximal: np.ndarray
    distal: np.ndarray
    queries: int  # collision queries made


class TwinHand(Hand):
    """What both twin hands share (the ReFlex's `SimHand`, the BH8's `sim.bh8.SimBH8Hand`):
    the world they sit in, their noise streams, the stop latch, the recognition's sensor mask
    and per-sensor thresholds, the robot time, the spread / preshape move and a state read.
    A subclass sets `preshape_limit_rad` and `preshape_speed_rad_s` and reads its sensors in
    `_sense(contacts, rng) -> (pressures, depth)`."""

    preshape_limit_rad: float
    preshape_speed_rad_s: float

    def _init_twin(
        self, world: SimWorld, cfg: SimConfig, seed: int | None, n_sensors: int, threshold: float
    ) -> None:
        self.world = world
        self.cfg = cfg
        self._n_sensors = int(n_sensors)
        self._threshold = float(threshold)
        self.seed = cfg.seed if seed is None else int(seed)
        self.reseed(self.seed)  # after the sensor count: a faulty hand draws its faults here
        self.stop_latch = StopLatch()
        self.masked = np.zeros(n_sensors, dtype=bool)  # `mask_sensors`: ignored sensors
        # Per-sensor contact thresholds (`set_contact_thresholds`), never under the configured.
        self.thresholds = np.full(n_sensors, self._threshold)
        self._robot_seconds = 0.0

    def _sense(
        self, contacts: HandContacts, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    @property
    def robot_seconds(self) -> float:
        """Robot time of the hand's commands so far (the twin closes in milliseconds)."""
        return self._robot_seconds

    @property
    def n_sensors(self) -> int:
        return self._n_sensors

    def connect(self) -> None:
        pass  # the world owns the client

    def disconnect(self) -> None:
        pass

    def reseed(self, seed: int) -> None:
        """Restart the noise streams from `seed`."""
        self.seed = int(seed)
        self._stream = np.random.default_rng(self.seed)
        self._state_rng = np.random.default_rng([self.seed, 1])

    def mask_sensors(self, sensor_ids: Sequence[int]) -> bool:
        n = self._n_sensors
        ids = np.asarray(list(sensor_ids), dtype=np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= n):
            raise ValueError(f"sensor ids must be 0..{n - 1}, got {ids.tolist()}")
        self.masked = np.zeros(n, dtype=bool)
        self.masked[ids] = True
        return True

    def set_contact_thresholds(self, thresholds: Sequence[float]) -> bool:
        t = np.asarray(list(thresholds), dtype=np.float64)
        if t.shape != (self._n_sensors,) or not np.all(np.isfinite(t)):
            raise ValueError(f"contact thresholds must be {self._n_sensors} finite values")
        self.thresholds = np.maximum(t, self._threshold)
        return True

    def own_contact_thresholds(self) -> np.ndarray | None:
        if self.cfg.sensing == "stall":  # the ReFlex SF: no pressures to threshold
            return None
        return np.full(self._n_sensors, self._threshold)

    def sensor_sites(self) -> np.ndarray:
        return self.world.sensor_sites_hand()

    def stop(self) -> None:
        """Halt the fingers: a running guarded close ends at its next step (it raises), and
        closing or preshaping is refused until `clear_stop()`."""
        self.stop_latch.set()

    def clear_stop(self) -> None:
        self.stop_latch.clear()

    def preshape(self, angle: float) -> None:
        self.stop_latch.check("preshape")
        a = float(angle)
        if not (0.0 <= a <= self.preshape_limit_rad):
            raise ValueError(f"preshape {a} rad is outside 0..{self.preshape_limit_rad}")
        w = self.world
        self._robot_seconds += abs(a - w.preshape_angle) / self.preshape_speed_rad_s
        w.set_hand(a, w.proximal, w.distal)

    def state(self) -> HandState:
        w = self.world
        w.flush_contacts()
        pressures, _ = self._sense(w.hand_contacts(), self._state_rng)
        return HandState(
            pressures=pressures,
            contact=pressures > self.thresholds,
            finger_angles=w.proximal,
            preshape=w.preshape_angle,
            stamp=time.monotonic(),
        )

    def _open_fingers(self) -> None:
        """Open the fingers; with `sim.nudge_max_m` the grasp's unbalanced push first slides
        the object (sim/nudge.py), never into the opened hand."""
        w = self.world
        step = np.zeros(2)
        if self.cfg.nudge_max_m > 0:
            step = nudge_step(w.object_pushes(), self.cfg.nudge_max_m)
        w.open_fingers()
        if step.any():
            tol = self.cfg.wrist_penetration_tol_m

            def clear(s: np.ndarray) -> bool:
                w.shift_object(s)
                ok = w.object_clear_of_hand(tol)
                if not ok:
                    w.shift_object(-s)
                return ok

            shrink_until_clear(step, clear)

    def _grasp_rng(self) -> np.random.Generator:
        if self.cfg.noise_mode == "stream":
            return self._stream
        return pose_keyed_rng(self.world, self.seed)


class SimHand(TwinHand):
    """The twin's ReFlex hand, on the hand body of `world`."""

    def __init__(self, world: SimWorld, cfg: SimConfig | None = None, seed: int | None = None):
        cfg = cfg or world.cfg
        self.cfg = cfg
        if self.cfg.noise_mode not in ("pose", "stream"):
            raise ValueError(f"noise_mode must be 'pose' or 'stream', not {self.cfg.noise_mode!r}")
        if self.cfg.substeps < 1 or self.cfg.spool_step_rad <= 0:
            raise ValueError("substeps must be >= 1 and spool_step_rad > 0")
        if self.cfg.spread_sigma_m <= 0 or self.cfg.post_contact_travel_rad < 0:
            raise ValueError("spread_sigma_m must be > 0 and post_contact_travel_rad >= 0")
        self._init_twin(world, cfg, seed, N_SENSORS, cfg.contact_threshold)
        self.preshape_limit_rad = cfg.preshape_limit_rad
        self.preshape_speed_rad_s = cfg.finger_speed_rad_s
        g = world.geometry
        self._proximal_limit = g.proximal_limit
        self._distal_limit = g.distal_limit
        links = world.links
        self._finger_of_link = {int(links.proximal[f]): f for f in range(N_FINGERS)}
        self._finger_of_link.update({int(links.distal[f]): f for f in range(N_FINGERS)})
        self._is_distal = {int(links.distal[f]) for f in range(N_FINGERS)}
        self._pad = int(links.pad)
        self._far_sites = np.full((N_SENSORS, 3), 1.0e3)
        self._far_sites[N_FINGER_SENSORS:] = palm_site_positions(world.geometry)
        if not 5 <= self.cfg.stall_contact_site <= 8:
            raise ValueError("stall_contact_site must be a distal sensor index, 5..8")
        if self.cfg.hand_period_s <= 0 or self.cfg.finger_speed_rad_s <= 0:
            raise ValueError("hand_period_s and finger_speed_rad_s must be > 0")
        self.last_close: CloseResult | None = None

    def _spool(self) -> np.ndarray:
        return self.world.proximal + self.world.distal

    # -- Hand interface -------------------------------------------------------------------

    def open(self) -> None:
        before = self._spool()
        self._open_fingers()
        travel = float(np.abs(before - self._spool()).max())
        self._robot_seconds += travel / self.cfg.finger_speed_rad_s

    def guarded_close(self) -> Grasp:
        """Close every finger in spool steps until it senses contact, stalls or reaches its
        limit; report the sensors over threshold at the end. A `stop()` from another thread
        ends it at the next spool step with `StoppedError`, the fingers where they were."""
        self.stop_latch.check("guarded close")
        cfg, w = self.cfg, self.world
        rng = self._grasp_rng()
        thr = self.thresholds
        step, fine_step = cfg.spool_step_rad, cfg.spool_step_rad / cfg.substeps
        limit = cfg.spool_limit_rad
        stall = cfg.stall_depth_m
        prox, dist = w.proximal, w.distal
        spool = prox + dist  # the tendon wraps both joints
        spool0 = spool.copy()
        blocked = np.zeros(N_FINGERS, dtype=bool)
        active = np.ones(N_FINGERS, dtype=bool)
        fine = np.zeros(N_FINGERS, dtype=bool)
        fine_inc = np.full(N_FINGERS, fine_step)
        # Tendon command once contact is sensed (NaN before): the servo runs on to it.
        target = np.full(N_FINGERS, np.nan)
        reading = spool.copy()  # spool at the last (coarse-step) reading
        substep = np.zeros(N_FINGERS, dtype=np.int64)
        reasons = [""] * N_FINGERS

        live = ~self.masked  # masked sensors stop no finger and are not reported

        def links_sensed(p: np.ndarray) -> np.ndarray:
            """(3, 2) bool: each finger's proximal / distal sensors read over threshold."""
            over = (p > thr) & live
            over = over[:N_FINGER_SENSORS].reshape(N_FINGERS, SENSORS_PER_FINGER)
            return np.column_stack(
                [over[:, :N_PROXIMAL_SENSORS].any(axis=1), over[:, N_PROXIMAL_SENSORS:].any(axis=1)]
            )

        w.flush_contacts()
        pressures, depth = self._sense(w.hand_contacts(), rng)
        queries = 1
        link_sensed = links_sensed(pressures)
        for f in range(N_FINGERS):  # a finger already touching does not move
            if link_sensed[f].any():
                active[f], reasons[f] = False, STOP_CONTACT
            elif spool[f] >= limit - 1e-12:
                active[f], reasons[f] = False, STOP_LIMIT

        while active.any():
            self.stop_latch.check("guarded close")  # one control step: a stop acts here
            cap = np.where(np.isnan(target), limit, target)
            new_spool = np.where(
                active, np.minimum(spool + np.where(fine, fine_inc, step), cap), spool
            )
            new_prox, new_dist = coupled_joints(
                new_spool,
                prox,
                blocked,
                cfg.flexure_coupling,
                self._proximal_limit,
                self._distal_limit,
            )
            new_prox = np.where(active, new_prox, prox)
            new_dist = np.where(active, new_dist, dist)
            w.set_hand(w.preshape_angle, new_prox, new_dist)
            pressures, depth = self._sense(w.hand_contacts(), rng)
            queries += 1
            link_sensed = links_sensed(pressures).tolist()
            for f in np.flatnonzero(active).tolist():
                sensed_prox, sensed_dist = link_sensed[f]
                sensed = sensed_prox or sensed_dist
                touching = not np.isnan(target[f])
                d_prox, d_dist = depth[f]
                # A held proximal link may rest on something: only moving links count here.
                d_moving = d_dist if blocked[f] else max(d_prox, d_dist)
                if not fine[f] and (sensed or d_moving > 0.0):
                    fine[f] = True  # re-run this step finely from where the finger was
                    reading[f], substep[f] = spool[f], 0
                    continue
                # Past its sensed contact a finger presses only as deep as the skin gives.
                deepest = cfg.skin_depth_m if touching else stall
                too_deep = d_dist > deepest or (blocked[f] and d_prox > deepest)
                if touching and too_deep and fine_inc[f] > fine_step / 2**PRESS_HALVINGS:
                    fine_inc[f] /= 2  # retry a shorter press
                    continue
                if d_dist > deepest:  # the distal can go no deeper: stay at the last pose
                    active[f], reasons[f] = False, STOP_CONTACT if touching else STOP_STALL
                    continue
                if d_prox > deepest:
                    if blocked[f]:
                        active[f], reasons[f] = False, STOP_CONTACT if touching else STOP_STALL
                    else:
                        # Hold the proximal where it was; the distal wraps on (coarsely until
                        # it meets something, unless the finger is already in contact).
                        blocked[f], fine[f] = True, touching
                    continue
                spool[f], prox[f], dist[f] = new_spool[f], new_prox[f], new_dist[f]
                if fine[f]:
                    substep[f] += 1
                    if substep[f] == cfg.substeps:  # a reading interval has passed
                        reading[f], substep[f] = spool[f], 0
                if sensed and not touching:
                    touching = True
                    target[f] = min(limit, reading[f] + cfg.post_contact_travel_rad)
                if touching and not blocked[f] and (sensed_prox or d_prox > 0.0):
                    blocked[f] = True  # the skin is far stiffer than the flexure
                if touching and spool[f] >= target[f] - 1e-12:
                    active[f], reasons[f] = False, STOP_CONTACT
                elif spool[f] >= limit - 1e-12 or (
                    blocked[f] and dist[f] >= self._distal_limit - 1e-12
                ):
                    active[f], reasons[f] = False, STOP_CONTACT if touching else STOP_LIMIT

        # Read the sensors at the final pose (as the real hand reports after the close).
        w.set_hand(w.preshape_angle, prox, dist)
        pressures, _ = self._sense(w.hand_contacts(), rng)
        queries += 1
        self.last_close = CloseResult(
            tuple(reasons), spool.copy(), prox.copy(), dist.copy(), queries
        )
        # One spool step per control period, then the reading at the final pose.
        steps = int(np.ceil(float((spool - spool0).max()) / step - 1e-9))
        self._robot_seconds += (max(steps, 0) + 1) * cfg.hand_period_s
        if cfg.sensing == "stall":
            return self._stall_grasp(reasons, pressures)
        ids = np.flatnonzero((pressures > thr) & live)
        return Grasp(
            sensor_ids=ids,
            xyz=w.sensor_sites_hand()[ids],
            pressures=pressures[ids],
            finger_angles=prox.copy(),
            preshape=w.preshape_angle,
        )

    def _stall_grasp(self, reasons: list[str], pressures: np.ndarray) -> Grasp:
        """The ReFlex SF's grasp: no tactile sensors, so each finger that stopped against the
        object (a stall under load) reports one contact at its distal sensor site."""
        w = self.world
        stopped = [f for f in range(N_FINGERS) if reasons[f] in (STOP_CONTACT, STOP_STALL)]
        ids = np.array(
            [f * SENSORS_PER_FINGER + self.cfg.stall_contact_site for f in stopped], dtype=int
        )
        finger = pressures[:N_FINGER_SENSORS].reshape(N_FINGERS, SENSORS_PER_FINGER)
        load = finger[stopped].clip(0).sum(axis=1)
        return Grasp(
            sensor_ids=ids,
            xyz=w.sensor_sites_hand()[ids].reshape(-1, 3),
            pressures=load,  # the finger's summed pressure stands in for the servo load
            finger_angles=w.proximal.copy(),
            preshape=w.preshape_angle,
        )

    # -- sensing --------------------------------------------------------------------------

    def _sense(
        self, contacts: HandContacts, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """(38,) pressures with noise, and (3, 2) deepest penetration of each finger's proximal
        and distal links."""
        cfg, w = self.cfg, self.world
        depth = np.zeros((N_FINGERS, 2))
        sensing = np.zeros(len(contacts), dtype=bool)
        fingers: set[int] = set()
        for i, (link, dep) in enumerate(
            zip(contacts.link.tolist(), contacts.depth.tolist(), strict=True)
        ):
            f = self._finger_of_link.get(link)
            if f is not None:
                col = 1 if link in self._is_distal else 0
                depth[f, col] = max(depth[f, col], dep)
                sensing[i] = True
                fingers.add(f)
            elif link == self._pad:
                sensing[i] = True
        force = np.zeros(N_SENSORS)
        if sensing.any():
            # Sites of fingers without contacts stay far away: only touched links need them.
            sites = self._far_sites.copy()
            for f in fingers:
                sites[f * SENSORS_PER_FINGER : (f + 1) * SENSORS_PER_FINGER] = (
                    finger_sensor_positions(
                        w.geometry, f, w.preshape_angle, w.proximal[f], w.distal[f]
                    )
                )
            force = site_forces(
                contacts.link[sensing],
                w.world_to_hand(contacts.position[sensing]),
                contacts.depth[sensing],
                w.links.site_link,
                sites,
                cfg.spread_sigma_m,
                cfg.contact_stiffness_n_per_m,
            )
        pressures = force * cfg.pressure_per_newton
        if cfg.noise_std > 0:
            pressures = pressures + rng.normal(0.0, cfg.noise_std, N_SENSORS)
        return pressures, depth


class FaultySimHand(FaultyReadings, SimHand):
    """The twin's ReFlex read through faulty sensors."""

    def __init__(
        self, world: SimWorld, cfg: SimConfig, faults: SensorFaults, seed: int | None = None
    ) -> None:
        self.faults = faults
        super().__init__(world, cfg, seed=seed)  # calls reseed(), which draws the faults
