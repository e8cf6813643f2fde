"""The gate both twin-backed emulated hands share: the emulator reads the shared twin world only
while one of the hand's commands runs (the arm, which also poses that world, is still then)."""

from __future__ import annotations

from typing import Any


class LiveDuringCommands:
    """Mixed in before a driver's hand class: `open` and `preshape` run with the emulated
    fingers' gate open (`self.fingers.live()`); the guarded close opens it itself."""

    fingers: Any

    def open(self) -> None:
        with self.fingers.live():
            super().open()  # type: ignore[misc]

    def preshape(self, angle: float) -> None:
        with self.fingers.live():
            super().preshape(angle)  # type: ignore[misc]
