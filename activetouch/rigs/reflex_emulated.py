"""``hand.type = "reflex-takktile"`` with ``hand.emulate = "twin"``: the real TakkTile driver
against its byte-level emulator, in this process, on loopback UDP, backed by the twin world the
arm moves in (the shared `TwinRig`: the object `sim/place` put there, the wrist where the arm
posed it).

Nothing is short-circuited: the driver receives 202-byte state packets on a UDP socket and
decodes them with its own codec; the emulator parses its command packets with its own parser;
the emulated fingers are the twin's hand kinematics in contact with the placed object
(`TwinFingers`) and the pads the twin's tactile model plus per-sensor zero offsets.

The world is single-threaded; the arm also poses it. So the emulator reads it only while a
driver command runs (`TwinEmulatedHand` opens `TwinFingers.live()` around open / preshape /
guarded close), when the arm is still; between commands the pads repeat their last reading.
"""

from __future__ import annotations

import dataclasses
import socket
from dataclasses import dataclass
from typing import TYPE_CHECKING

from activetouch.drivers.reflex.takktile import ReflexTakktileConfig, ReflexTakktileHand
from activetouch.emulators.reflex_takktile import EmulatorConfig, Faults, TakktileEmulator
from activetouch.interfaces import N_SENSORS, Grasp, Hand
from activetouch.rigs.gated import LiveDuringCommands
from activetouch.rigs.twin_fingers import TwinFingers
from activetouch.sim.devices import twin_rig

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext
    from activetouch.emulators.reflex_takktile import TakktileEmulator
    from activetouch.rigs.twin_fingers import TwinFingers

# The emulated hand's calibration when the config leaves it at its defaults (zeros): servo
# zeros near raw 13000 as on a real hand (the emulator's), encoder zeros that keep the counts
# positive, and per-sensor zero offsets so the driver's subtraction is exercised.
EMULATED_MOTOR_ZERO = (56.0, 57.0, 55.5, 53.0)
EMULATED_ENCODER_ZERO = (3.0, 3.0, 3.0)


def emulated_zero_offsets() -> list[float]:
    return [200.0 + 7.0 * i for i in range(N_SENSORS)]


def free_loopback_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
    finally:
        s.close()


class TwinEmulatedHand(LiveDuringCommands, ReflexTakktileHand):
    """The TakkTile driver, unchanged, plus the emulator it talks to (`emulator`) and the gate
    that lets that emulator read the shared world only during this hand's commands."""

    def __init__(
        self, cfg: ReflexTakktileConfig, emulator: TakktileEmulator, fingers: TwinFingers
    ) -> None:
        super().__init__(cfg, device=cfg.serial or cfg.type)
        self.emulator, self.fingers = emulator, fingers

    def guarded_close(self) -> Grasp:
        with self.fingers.live():
            # A packet emitted now may have been read from the world before the gate opened
            # (while the arm moved); the base close then waits for one more, read inside it.
            r = self._latest_or_wait()
            self._wait_reading(r.seq, self.cfg.stream_timeout_s)
            return super().guarded_close()


def make_twin_emulated(cfg: ReflexTakktileConfig, ctx: DeviceContext) -> TwinEmulatedHand:
    """Start the emulator on the shared twin rig and return the driver pointed at it."""

    rig = twin_rig(ctx)
    sim = ctx.cfg.sim
    # The emulated fingers are the twin's: its threshold for "the pads feel it", its tendon
    # travel (the servo cannot turn further), its coupling.
    fingers = TwinFingers(rig.world, rig.hand, spool_limit=sim.spool_limit_rad, gated=True)
    gear = list(cfg.gear_ratio)
    motor_zero = (
        [z / g for z, g in zip(cfg.motor_zero_points, gear, strict=True)]
        if cfg.motor_zero_points
        else list(EMULATED_MOTOR_ZERO)
    )
    encoder_zero = (
        list(cfg.encoder_zero_rad) if any(cfg.encoder_zero_rad) else list(EMULATED_ENCODER_ZERO)
    )
    offsets = list(cfg.zero_offsets) or emulated_zero_offsets()
    state_port = free_loopback_port()
    emu = TakktileEmulator(
        EmulatorConfig(
            state_to=f"127.0.0.1:{state_port}",
            command_listen="127.0.0.2:0",  # "the group": the driver must send here
            seed=sim.seed,
            gear_ratio=tuple(cfg.gear_ratio),
            motor_inverted=tuple(cfg.motor_inverted),
            motor_zero_rad=tuple(motor_zero),
            encoder_zero_rad=tuple(encoder_zero),
            encoder_sign=cfg.encoder_sign,
            baselines=offsets,
            noise_std=0.0,  # the twin's tactile model has its own noise
            faults=Faults(loss=cfg.emulate_loss),
        ),
        fingers,
    ).start()
    ctx.on_close(emu.stop)  # registered after the rig's close: runs before it
    driver_cfg = dataclasses.replace(
        cfg,
        state_listen=f"127.0.0.1:{state_port}",
        command_to=emu.command_address,
        multicast_group="",
        interface="",
        motor_zero_points=[z * g for z, g in zip(motor_zero, gear, strict=True)],
        encoder_zero_rad=encoder_zero,
        zero_offsets=offsets,  # the emulated board's baselines are known: calibrated
        # The emulated servo stops at the twin's travel limit; a driver set further would
        # wait for a stall there instead.
        spool_limit_rad=min(cfg.spool_limit_rad, sim.spool_limit_rad),
        emulate="",
    )
    return TwinEmulatedHand(driver_cfg, emu, fingers)


@dataclass
class ReflexTakktileRigConfig(ReflexTakktileConfig):
    """``hand.type = "reflex-takktile"``: the driver, or with ``hand.emulate = "twin"`` the
    driver on its emulator backed by the twin (the registry names this class, so the driver
    floor never imports the rig)."""

    def make(self, ctx: DeviceContext) -> Hand:
        if self.emulate == "twin":
            self.check()
            return make_twin_emulated(self, ctx)
        return super().make(ctx)
