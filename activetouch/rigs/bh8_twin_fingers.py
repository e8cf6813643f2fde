"""A `BH8FingerModel` backed by the PyBullet twin, for the BH8 emulator: the emulated motor
angles pose the twin's BH8 (`BH8World.set_hand`) and the cells are the twin's tactile model
(`SimBH8Hand.sense`, with its noise). Only public calls of the twin and `models.bh8`'s
transmission, so the twin can change underneath.

Mechanics at the emulator's tick (2 ms, ~2.5 mrad of inner link at the driver's close speed):
while the TorqueSwitch holds, inner = motor / 125 and outer = inner / 3; when the inner link is
pushed `breakaway_depth_m` into something (or reaches its stop) the switch breaks away and the
outer link takes the whole motor travel; the motor stalls where the outer link is pressed
`pad_depth_m` into its pad's foam or `strain_depth_m` into anything (as in the twin's close).
Opening back past the coupled angle re-engages the switch.

Gated as the TakkTile rig's fingers: the world is read only inside `live()` (the driver's
commands, when the arm is still); between commands the pads repeat their last reading.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from activetouch.models import bh8
from activetouch.sim.bh8 import BH8World, SimBH8Hand

SETTLE_HALVINGS = 8  # a tick's overshoot bisected to 1/256 of it
K = 1 / bh8.INNER_RATIO + 1 / bh8.OUTER_RATIO  # link radians (inner + outer) per motor radian


class BH8TwinFingers:
    def __init__(
        self,
        world: BH8World,
        hand: SimBH8Hand,
        strain_per_newton: float | None = None,
        gated: bool = False,
    ) -> None:
        self.world, self.hand = world, hand
        self.h = hand.hcfg
        # SG units per newton: the driver's default strain stop (150 units) at the load of a
        # fingertip `strain_depth_m` deep, where the twin's own close stops on strain.
        self.strain_per_newton = (
            150.0 / (self.h.contact_stiffness_n_per_m * self.h.strain_depth_m)
            if strain_per_newton is None
            else strain_per_newton
        )
        self.broken = np.zeros(3, dtype=bool)
        self.inner = np.zeros(3)
        self.outer = np.zeros(3)
        self.stall = np.full(3, math.inf)
        self.motors = np.zeros(3)
        self.spread = 0.0
        self.last = np.zeros(bh8.N_CELLS)
        self.load = np.zeros(3)
        self.lock = threading.Lock()
        self.is_live = not gated
        self.reads = 0

    @contextmanager
    def live(self) -> Iterator[None]:
        """Let the emulator read the world inside this block (the caller keeps the arm still)."""
        with self.lock:
            self.is_live = True
            self._pose()  # the arm opened the world's fingers to check its moves: ours again
        try:
            yield
        finally:
            with self.lock:
                self.is_live = False

    # -- BH8FingerModel -------------------------------------------------------------------

    def joints(self, finger: int, motor: float) -> tuple[float, float, float]:
        return float(self.inner[finger]), float(self.outer[finger]), float(self.load[finger])

    def stall_motor(self, finger: int) -> float:
        return float(self.stall[finger])

    def cells(self, pad: int) -> list[float]:
        return self.last[24 * pad : 24 * pad + 24].tolist()

    def strain(self, finger: int) -> float:
        return float(self.strain_per_newton * self.load[finger])

    def update(self, motors: list[float], spread: float) -> None:
        m = np.asarray(motors, dtype=np.float64)
        with self.lock:
            if not self.is_live:
                return
            if np.array_equal(m, self.motors) and spread == self.spread and self.reads:
                return
            prev_inner, prev_motors = self.inner.copy(), self.motors.copy()
            closing = m > self.motors
            self.motors, self.spread = m.copy(), float(spread)
            for f in range(3):
                if m[f] < self.stall[f] - 1e-9 and not closing[f]:
                    self.stall[f] = math.inf  # backed off: free to close again
            self._links()
            pressures, depth, load = self._pose()
            redo = False
            for f in range(3):
                if not self.broken[f] and (
                    depth[f, 0] > self.h.breakaway_depth_m or self.inner[f] >= bh8.INNER_LIMIT
                ):
                    # The inner link stops where it last was free; the outer takes the rest.
                    self.broken[f], self.inner[f] = True, min(prev_inner[f], self.inner[f])
                    redo = True
            if redo:
                self._links()
                pressures, depth, load = self._pose()
            deep = [f for f in range(3) if closing[f] and depth[f, 1] > self._deepest(pressures, f)]
            if deep:
                # A tick (longer on a loaded machine) carried the fingertip further in than it
                # can go: the motor stalls where it got that deep (bisected), not beyond.
                lo, hi = prev_motors[deep], m[deep]
                for _ in range(SETTLE_HALVINGS):
                    mid = (lo + hi) / 2
                    self.motors[deep] = mid
                    self._links()
                    p_mid, d_mid, _ = self._pose()
                    over = np.array([d_mid[f, 1] > self._deepest(p_mid, f) for f in deep])
                    lo, hi = np.where(over, lo, mid), np.where(over, mid, hi)
                self.motors[deep] = lo
                self.stall[deep] = lo
                self._links()
                pressures, depth, load = self._pose()
            self.last, self.load = pressures, load
            self.reads += 1

    def _deepest(self, pressures: np.ndarray, f: int) -> float:
        """How deep finger f's outer link may go: into its pad's foam once the pad feels
        something, else as far as its strain gauge lets the twin's close go."""
        pad = (pressures[24 * f : 24 * f + 24] > self.h.contact_threshold).any()
        return self.h.pad_depth_m if pad else self.h.strain_depth_m

    # -- the twin -------------------------------------------------------------------------

    def _links(self) -> None:
        """Link angles from the motors and the TorqueSwitch's state."""
        for f in range(3):
            if self.broken[f]:
                outer = self.motors[f] * K - self.inner[f]
                if outer <= bh8.coupled_outer(self.inner[f]) + 1e-9:
                    self.broken[f] = False  # opened back: the switch re-engages
            if not self.broken[f]:
                self.inner[f] = min(self.motors[f] / bh8.INNER_RATIO, bh8.INNER_LIMIT)
                self.outer[f] = float(bh8.coupled_outer(self.inner[f]))
            else:
                self.outer[f] = min(self.motors[f] * K - self.inner[f], bh8.OUTER_LIMIT)

    def _pose(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self.world.set_hand(self.spread, self.inner, self.outer)
        return self.hand.sense()
