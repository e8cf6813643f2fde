"""The object nudged by a grasp, an error of the real robot the twin can add
(`sim.nudge_max_m`, docs/benchmark.md): the paper fixed its objects to the table; a lab's
objects stand free, and a finger that meets one alone pushes it.

The twin's hand is posed kinematically, so the push is modelled, not integrated: when the
hand opens after a grasp, each contact the closed hand made with the object pushes it along
the contact normal, weighted by how far the skin pressed in (a compliant contact's force is
proportional to it). A grip whose pushes cancel holds the object where it is; a lone finger
slides it the full `nudge_max_m`: the slide is `nudge_max_m` times the net horizontal push
over the sum of the pushes' horizontal sizes (between 0 and 1), along the net push. The
object only slides (no turn, no tip-over), and never into the opened hand."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def nudge_step(pushes: np.ndarray, max_m: float) -> np.ndarray:
    """(2,) the object's slide on the table (metres, world x and y) from `pushes`, (n, 3)
    the contacts' pushes on it (direction times depth, any scale)."""
    h = np.asarray(pushes, dtype=np.float64).reshape(-1, 3)[:, :2]
    total = float(np.linalg.norm(h, axis=1).sum())
    if max_m <= 0 or total <= 0.0:
        return np.zeros(2)
    return float(max_m) * h.sum(axis=0) / total


def shrink_until_clear(
    step: np.ndarray, clear: Callable[[np.ndarray], bool], halvings: int = 4
) -> np.ndarray:
    """The largest of `step`, `step`/2, ... (`halvings` times), else zeros, for which
    `clear(candidate)` holds."""
    s = np.asarray(step, dtype=np.float64).reshape(2)
    for _ in range(halvings + 1):
        if clear(s):
            return s
        s = s / 2
    return np.zeros(2)
