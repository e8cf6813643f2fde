"""A `FingerModel` backed by the PyBullet twin, for the TakkTile emulator: the emulated spool
angles pose the twin's hand (`SimWorld.set_hand`), and the pressures are the twin's tactile
model (`SimHand.state()`, with its noise). Thin on purpose: only public SimWorld / SimHand
calls and `models.reflex.coupled_joints`, so the twin can change underneath.

Mechanics kept from the twin at packet resolution (coarser than its own guarded close, which
re-runs a contact step in substeps): a free finger splits its spool proximal = s / (1 + k),
distal = k * proximal; once its proximal pads feel something, the proximal holds and the
distal takes the rest; once its distal pads feel something, the servo stalls `press_rad`
further on.

Sharing the world with an arm (`hand.emulate = "twin"`): the arm also poses the world (and
opens its fingers to check a pose), so the emulator thread must not touch it while the arm
moves. With `gated=True` the world is read only inside `live()` (the driver's commands, during
which the arm is still: the nodes serialise commands, a session is sequential); between
commands the pads repeat their last reading.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

# 0.05 rad / 2**5: the twin's substep (0.01) halved 3 times (its PRESS_HALVINGS) is 1.25 mrad.
SETTLE_HALVINGS = 5


class TwinFingers:
    def __init__(
        self,
        world,
        hand=None,
        coupling: float | None = None,
        threshold: float | None = None,
        press_rad: float = 0.05,
        spool_limit: float = 3.6,
        gated: bool = False,
    ) -> None:
        # deferred: loads pybullet, scipy
        from activetouch.sim.hand import SimHand

        self.world = world
        self.hand = hand or SimHand(world)
        cfg = world.cfg
        self.k = cfg.flexure_coupling if coupling is None else coupling
        self.threshold = cfg.contact_threshold if threshold is None else threshold
        self.press_rad, self.spool_limit = press_rad, spool_limit
        self.blocked = np.zeros(3, dtype=bool)
        self.hold = np.zeros(3)
        self.stall = np.full(3, spool_limit)
        self.touching = np.zeros(3, dtype=bool)
        self.prev_spool = np.zeros(3)
        self.skin_depth, self.stall_depth = cfg.skin_depth_m, cfg.stall_depth_m
        self.lock = threading.Lock()  # one world access at a time; `live` flips under it
        self.is_live = not gated
        self.last = np.zeros(38)
        self.reads = 0  # world readings made (tests: the gate holds)

    @contextmanager
    def live(self) -> Iterator[None]:
        """Let the emulator read the world inside this block (the caller keeps the arm still).
        Taking the lock waits out a reading in progress, so none runs outside the block."""
        with self.lock:
            self.is_live = True
        try:
            yield
        finally:
            with self.lock:
                self.is_live = False

    def joints(self, spool: np.ndarray, preshape: float) -> tuple[np.ndarray, np.ndarray]:
        # deferred: loads scipy
        from activetouch.models.reflex import coupled_joints

        g = self.world.geometry
        spool = np.asarray(spool, dtype=np.float64)
        # Opening past where the proximal was held frees it again.
        self.blocked &= spool > self.hold * (1 + self.k) - 1e-9
        return coupled_joints(
            spool, self.hold, self.blocked, self.k, g.proximal_limit, g.distal_limit
        )

    def forces(self, spool: np.ndarray, preshape: float) -> np.ndarray:
        with self.lock:
            if not self.is_live:
                return self.last.copy()
            self.last = self._read(np.asarray(spool, dtype=np.float64), float(preshape))
            self.reads += 1
            return self.last.copy()

    def _pose(self, spool: np.ndarray, preshape: float) -> tuple[np.ndarray, np.ndarray]:
        """Pose the world's hand at these spools: (38,) pressures, (3, 2) deepest
        penetration of each finger's proximal and distal link."""
        prox, dist = self.joints(spool, preshape)
        self.world.set_hand(preshape, prox, dist)
        p = np.asarray(self.hand.state().pressures, dtype=np.float64)  # flushes, then reads
        c = self.world.hand_contacts()
        links = self.world.links
        depth = np.zeros((3, 2))
        for link, d in zip(c.link.tolist(), c.depth.tolist(), strict=True):
            for f in range(3):
                if link == links.proximal[f]:
                    depth[f, 0] = max(depth[f, 0], d)
                elif link == links.distal[f]:
                    depth[f, 1] = max(depth[f, 1], d)
        return p, depth

    def _settle(
        self,
        spool: np.ndarray,
        preshape: float,
        fingers: list[int],
        past: Callable[[np.ndarray, np.ndarray], np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where, between the last reading's spools and `spool`, `fingers` cross into
        `past(pressures, depth) -> (len(fingers),) bool`: (last spools before, first spools
        past), to within ~1.5 mrad (the resolution at which the twin's own close settles)."""
        lo = np.minimum(self.prev_spool[fingers], spool[fingers])
        hi = spool[fingers].copy()
        for _ in range(SETTLE_HALVINGS):
            mid = (lo + hi) / 2
            trial = spool.copy()
            trial[fingers] = mid
            p, d = self._pose(trial, preshape)
            crossed = past(p, d)
            lo, hi = np.where(crossed, lo, mid), np.where(crossed, mid, hi)
        return lo, hi

    def _read(self, spool: np.ndarray, preshape: float) -> np.ndarray:
        spool = np.minimum(spool, self.stall)
        for f in range(3):  # opened again: the finger is free
            if spool[f] < self.stall[f] - 2 * self.press_rad:
                self.stall[f] = self.spool_limit
            if spool[f] <= self.prev_spool[f] - 0.1 or spool[f] < 0.05:
                self.touching[f] = False
        p, depth = self._pose(spool, preshape)
        over = p[:27].reshape(3, 9) > self.threshold
        # The twin's limits on pressing in: before a sensed contact a link may go
        # `stall_depth_m` into something (an unsensed part), after it only `skin_depth_m`.
        allowed = np.where(self.touching | over.any(axis=1), self.skin_depth, self.stall_depth)
        hit = [
            f
            for f in range(3)
            if not self.blocked[f] and (over[f, :5].any() or depth[f, 0] > allowed[f])
        ]
        if hit:
            # The skin is far stiffer than the flexure: the proximal holds where it first
            # met something during this step (its pads sense, or it is pushed too deep), and
            # the distal takes the rest of the step, as in the twin's close.
            def prox_met(p: np.ndarray, d: np.ndarray) -> np.ndarray:
                sensed = p[:27].reshape(3, 9)[hit, :5] > self.threshold
                return sensed.any(axis=1) | (d[hit, 0] > allowed[hit])

            _, first = self._settle(spool, preshape, hit, prox_met)
            held = spool.copy()
            held[hit] = first
            hold, _ = self.joints(held, preshape)
            self.blocked[hit] = True
            self.hold[hit] = hold[hit]
            p, depth = self._pose(spool, preshape)
        bad = [f for f in range(3) if depth[f, 1] > allowed[f] and spool[f] > self.prev_spool[f]]
        if bad:
            # The distal cannot go that deep: the servo stalls short of it.
            last_ok, _ = self._settle(spool, preshape, bad, lambda p, d: d[bad, 1] > allowed[bad])
            spool[bad] = self.stall[bad] = last_ok
            p, _ = self._pose(spool, preshape)
        if hit or bad:
            over = p[:27].reshape(3, 9) > self.threshold
        for f in range(3):
            if over[f, 5:].any() and self.stall[f] >= self.spool_limit:
                self.stall[f] = min(self.spool_limit, spool[f] + self.press_rad)
        self.touching |= over.any(axis=1)
        self.prev_spool = spool.copy()
        return p  # may dip below 0 with noise: the board adds its zero offsets

    def stall_spool(self) -> np.ndarray:
        return self.stall.copy()
