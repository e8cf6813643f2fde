"""``hand.type = "barrett-bh8"`` with ``hand.emulate = "twin"``: the real BH8 driver against its
byte-level emulator on a python-can ``virtual`` bus of its own, in this process, backed by the
twin world the arm moves in (the shared `TwinRig`, made with the BH8 because the hand's family
is the BH8's: the object `sim/place` put there, the wrist where the arm posed it).

Nothing is short-circuited: the driver sends and parses CAN frames with its own codec (property
gets and sets, MODE, the HI, full tactile frames), the emulator parses and packs them with its
own code; the emulated fingers are the twin's BH8 in contact with the placed object
(`BH8TwinFingers`). The emulated hand is initialised at connect (its HI drives the emulated
fingers open, where the twin's are): an emulator has no one to hurt.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

from activetouch.drivers.barrett.bh8 import BarrettBH8Config, BarrettBH8Hand
from activetouch.emulators.barrett_bh8 import BH8Emulator, BH8EmulatorConfig, Faults
from activetouch.errors import ConfigError
from activetouch.interfaces import Grasp, Hand
from activetouch.rigs.gated import LiveDuringCommands
from activetouch.sim.devices import twin_rig

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext
    from activetouch.rigs.bh8_twin_fingers import BH8TwinFingers

_CHANNELS = itertools.count()


class TwinEmulatedBH8(LiveDuringCommands, BarrettBH8Hand):
    """The BH8 driver, unchanged, plus the emulator it talks to and the gate that lets the
    emulator read the shared world only during this hand's commands."""

    def __init__(
        self, cfg: BarrettBH8Config, emulator: BH8Emulator, fingers: BH8TwinFingers
    ) -> None:
        super().__init__(cfg)
        self.emulator, self.fingers = emulator, fingers

    def connect(self) -> None:
        with self.fingers.live():
            super().connect()

    def guarded_close(self) -> Grasp:
        with self.fingers.live():
            # A tactile set read before the gate opened (while the arm moved) must not decide:
            # the base close re-tares nothing, so wait for a reading made inside.
            self.wait_fresh_reading()
            return super().guarded_close()


@dataclass
class BarrettBH8RigConfig(BarrettBH8Config):
    """``hand.type = "barrett-bh8"``: the driver, or with ``hand.emulate = "twin"`` the driver
    on its emulator backed by the BH8 twin (the registry names this class, so the driver floor
    never imports the rig)."""

    # "twin": the emulator on a virtual CAN bus, backed by the shared twin world. Empty: a real
    # hand on `can_interface` / `can_channel`.
    emulate: str = ""
    emulate_loss: float = 0.0  # emulate = "twin": fraction of the pucks' frames lost

    @property
    def simulated(self) -> bool:  # type: ignore[override]
        return self.emulate == "twin"

    def check(self) -> None:
        super().check()
        if self.emulate not in ("", "twin"):
            raise ConfigError(f"hand.emulate: {self.emulate!r} is not one of '', 'twin'")
        if not 0.0 <= self.emulate_loss < 1.0:
            raise ConfigError("hand.emulate_loss: must be in [0, 1)")

    def make(self, ctx: DeviceContext) -> Hand:
        if self.emulate != "twin":
            return super().make(ctx)
        # deferred: loads pybullet
        from activetouch.rigs.bh8_twin_fingers import BH8TwinFingers

        rig = twin_rig(ctx)
        fingers = BH8TwinFingers(rig.world, rig.hand, gated=True)
        channel = f"bh8-twin-{os.getpid()}-{next(_CHANNELS)}"
        emu = BH8Emulator(
            BH8EmulatorConfig(
                channel=channel,
                interface="virtual",
                seed=ctx.cfg.sim.seed,
                start_counts=[0.0, 0.0, 0.0, 0.0],  # the twin's hand is open: so are these
                tact_baseline=0.35,
                tact_noise=0.0,  # the twin's cells have their own noise
                faults=Faults(loss=self.emulate_loss),
            ),
            fingers,
        ).start()
        ctx.on_close(emu.stop)  # registered after the rig's close: runs before it
        driver_cfg = dataclasses.replace(
            self,
            can_interface="virtual",
            can_channel=channel,
            initialize_on_connect=True,
            wake_settle_s=0.01,
            emulate="",
        )
        return TwinEmulatedBH8(driver_cfg, emu, fingers)
