"""`SimHand`: the twin's ReFlex hand with 38 tactile sensors and the guarded enclosure grasp.

Physics approach (chosen for speed with real collision geometry): the fingers are posed
kinematically and every reading runs Bullet's collision detection between the hand's boxes and
the table/object shapes. A sensor is a compliant patch: each penetrating contact point on a
sensor-carrying link is assigned to the nearest sensor site on that link within a patch radius,
its normal force is stiffness x penetration depth, and the sensor reads that force scaled to
sensor units plus Gaussian noise. Contact = pressure over the threshold.

Why not dynamic, position-controlled joints: a stable finger/object contact needs ~1 ms steps
and several steps per spool increment, i.e. thousands of solver steps per grasp (a few grasps
per second), while the objects are fixed and the ReFlex stops each finger at its first contact
anyway, so the contact dynamics after touch never matter. Kinematic stepping + collision
queries gives the same stopping angles and contact sites at > 20 grasps per second.

Guarded close, as the ReFlex does it: each finger's spool advances 0.05 rad per step; a free
finger bends its proximal joint by spool / (1 + k) and its distal joint by k times that (the
flexure coupling); a finger stops at its first sensed contact (a sensor on that finger over
threshold), at the spool limit, or when stalled. When a step first makes a finger touch
anything, that step is re-run in `substeps` parts, which is where a continuously moving finger
would have stopped. A link pushed `stall_depth_m` deep without a sensed contact is blocked:
a blocked proximal link holds and the distal joint takes the rest of the tendon travel (the
passive flexure wraps around the object); a blocked distal link stalls the finger.
"""

from __future__ import annotations

import hashlib
import time
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
)
from activetouch.sim.reflex_urdf import (
    coupled_joints,
    finger_sensor_positions,
    palm_site_positions,
)
from activetouch.sim.world import HandContacts, SimWorld

STOP_CONTACT = "contact"
STOP_LIMIT = "limit"
STOP_STALL = "stall"


def site_forces(
    contact_link: np.ndarray,
    contact_xyz: np.ndarray,
    contact_depth: np.ndarray,
    site_link: np.ndarray,
    site_xyz: np.ndarray,
    site_radius: np.ndarray,
    stiffness: float,
) -> np.ndarray:
    """(n_sites,) normal force on each sensor patch, newtons. Each contact point goes to the
    nearest site on its own link within that site's radius (others are not sensed)."""
    force = np.zeros(len(site_link))
    if len(contact_link) == 0:
        return force
    d = np.linalg.norm(contact_xyz[:, None, :] - site_xyz[None, :, :], axis=2)
    d[contact_link[:, None] != site_link[None, :]] = np.inf
    nearest = np.argmin(d, axis=1)
    ok = d[np.arange(len(nearest)), nearest] <= site_radius[nearest]
    np.add.at(force, nearest[ok], stiffness * contact_depth[ok])
    return force


@dataclass(frozen=True)
class CloseResult:
    """Diagnostics of the last guarded close."""

    stop_reasons: tuple[str, ...]  # per finger: contact | limit | stall
    spool: np.ndarray  # (3,) final spool angles
    proximal: np.ndarray
    distal: np.ndarray
    queries: int  # collision queries made


class SimHand(Hand):
    """The twin's ReFlex hand, on the hand body of `world`."""

    def __init__(self, world: SimWorld, cfg: SimConfig | None = None, seed: int | None = None):
        self.world = world
        self.cfg = cfg or world.cfg
        if self.cfg.noise_mode not in ("pose", "stream"):
            raise ValueError(f"noise_mode must be 'pose' or 'stream', not {self.cfg.noise_mode!r}")
        if self.cfg.substeps < 1 or self.cfg.spool_step_rad <= 0:
            raise ValueError("substeps must be >= 1 and spool_step_rad > 0")
        self.seed = self.cfg.seed if seed is None else int(seed)
        self.reseed(self.seed)
        g = world.geometry
        self._proximal_limit = g.proximal_limit
        self._distal_limit = g.distal_limit
        self._site_radius = np.where(
            np.arange(N_SENSORS) < N_FINGER_SENSORS,
            self.cfg.finger_patch_radius_m,
            self.cfg.palm_patch_radius_m,
        )
        links = world.links
        self._finger_of_link = {int(links.proximal[f]): f for f in range(N_FINGERS)}
        self._finger_of_link.update({int(links.distal[f]): f for f in range(N_FINGERS)})
        self._is_distal = {int(links.distal[f]) for f in range(N_FINGERS)}
        self._pad = int(links.pad)
        self._far_sites = np.full((N_SENSORS, 3), 1.0e3)
        self._far_sites[N_FINGER_SENSORS:] = palm_site_positions(world.geometry)
        self.last_close: CloseResult | None = None

    # -- Hand interface -------------------------------------------------------------------

    def connect(self) -> None:
        pass  # the world owns the client

    def disconnect(self) -> None:
        pass

    def reseed(self, seed: int) -> None:
        """Restart the noise streams from `seed`."""
        self.seed = int(seed)
        self._stream = np.random.default_rng(self.seed)
        self._state_rng = np.random.default_rng([self.seed, 1])

    def open(self) -> None:
        self.world.open_fingers()

    def preshape(self, angle: float) -> None:
        a = float(angle)
        if not (0.0 <= a <= self.cfg.preshape_limit_rad):
            raise ValueError(f"preshape {a} rad is outside 0..{self.cfg.preshape_limit_rad}")
        w = self.world
        w.set_hand(a, w.proximal, w.distal)

    def state(self) -> HandState:
        self.world.flush_contacts()
        pressures = self._read(self.world.hand_contacts(), self._state_rng)
        w = self.world
        return HandState(
            pressures=pressures,
            contact=pressures > self.cfg.contact_threshold,
            finger_angles=w.proximal,
            preshape=w.preshape_angle,
            stamp=time.monotonic(),
        )

    def guarded_close(self) -> Grasp:
        """Close every finger in spool steps until it senses contact, stalls or reaches its
        limit; report the sensors over threshold at the end."""
        cfg, w = self.cfg, self.world
        rng = self._grasp_rng()
        thr = cfg.contact_threshold
        step, fine_step = cfg.spool_step_rad, cfg.spool_step_rad / cfg.substeps
        limit = cfg.spool_limit_rad
        prox, dist = w.proximal, w.distal
        spool = prox + dist  # the tendon wraps both joints
        blocked = np.zeros(N_FINGERS, dtype=bool)
        active = np.ones(N_FINGERS, dtype=bool)
        fine = np.zeros(N_FINGERS, dtype=bool)
        reasons = [""] * N_FINGERS

        w.flush_contacts()
        pressures, depth = self._sense(w.hand_contacts(), rng)
        queries = 1
        for f in range(N_FINGERS):  # a finger already touching does not move
            if np.any(pressures[f * SENSORS_PER_FINGER : (f + 1) * SENSORS_PER_FINGER] > thr):
                active[f], reasons[f] = False, STOP_CONTACT
            elif spool[f] >= limit - 1e-12:
                active[f], reasons[f] = False, STOP_LIMIT

        while active.any():
            new_spool = np.where(
                active, np.minimum(spool + np.where(fine, fine_step, step), limit), spool
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
            for f in np.flatnonzero(active):
                sensed = np.any(
                    pressures[f * SENSORS_PER_FINGER : (f + 1) * SENSORS_PER_FINGER] > thr
                )
                d_prox, d_dist = depth[f]
                # A held proximal link may rest on something: only moving links count here.
                d_moving = d_dist if blocked[f] else max(d_prox, d_dist)
                if not fine[f] and (sensed or d_moving > 0.0):
                    fine[f] = True  # re-run this step finely from where the finger was
                    continue
                if not sensed and d_dist > cfg.stall_depth_m:
                    active[f], reasons[f] = False, STOP_STALL  # stays at its last pose
                    continue
                if not sensed and d_prox > cfg.stall_depth_m:
                    if blocked[f]:
                        active[f], reasons[f] = False, STOP_STALL
                    else:
                        # Hold the proximal where it was; the distal wraps on, coarsely
                        # until it meets something.
                        blocked[f], fine[f] = True, False
                    continue
                spool[f], prox[f], dist[f] = new_spool[f], new_prox[f], new_dist[f]
                if sensed:
                    active[f], reasons[f] = False, STOP_CONTACT
                elif spool[f] >= limit - 1e-12 or (
                    blocked[f] and dist[f] >= self._distal_limit - 1e-12
                ):
                    active[f], reasons[f] = False, STOP_LIMIT

        # Read the sensors at the final pose (as the real hand reports after the close).
        w.set_hand(w.preshape_angle, prox, dist)
        pressures, _ = self._sense(w.hand_contacts(), rng)
        queries += 1
        self.last_close = CloseResult(
            tuple(reasons), spool.copy(), prox.copy(), dist.copy(), queries
        )
        ids = np.flatnonzero(pressures > thr)
        return Grasp(
            sensor_ids=ids,
            xyz=w.sensor_sites_hand()[ids],
            pressures=pressures[ids],
            finger_angles=prox.copy(),
            preshape=w.preshape_angle,
        )

    # -- sensing --------------------------------------------------------------------------

    def _grasp_rng(self) -> np.random.Generator:
        if self.cfg.noise_mode == "stream":
            return self._stream
        # Seeded from what defines the grasp, so it does not depend on earlier grasps.
        w = self.world
        obj = w.object
        key = np.concatenate([w.wrist_pose.as_array(), [w.preshape_angle], w.proximal, w.distal])
        text = f"{self.seed}|{obj.name if obj else ''}|" + ",".join(
            f"{v:.6f}" for v in np.round(key, 6) + 0.0
        )
        digest = hashlib.sha256(text.encode()).digest()
        return np.random.default_rng(int.from_bytes(digest[:16], "little"))

    def _read(self, contacts: HandContacts, rng: np.random.Generator) -> np.ndarray:
        return self._sense(contacts, rng)[0]

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
                self._site_radius,
                cfg.contact_stiffness_n_per_m,
            )
        pressures = force * cfg.pressure_per_newton
        if cfg.noise_std > 0:
            pressures = pressures + rng.normal(0.0, cfg.noise_std, N_SENSORS)
        return pressures, depth
