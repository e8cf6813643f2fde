"""PyBullet, imported once with its build banner silenced (`from ...sim.pybullet import pb`)."""

from activetouch.sim import import_pybullet_quietly

import_pybullet_quietly()

import pybullet as pb  # noqa: E402  (after the quiet import, which is what loads it)

__all__ = ["pb"]
