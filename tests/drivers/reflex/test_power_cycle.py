"""A ReFlex TakkTile hand power-cycled under the daemon's link (issue 23, devices that come and
go): connected, lost when its stream stops for longer than `lost_after_s`, reconnected when it
comes back, and never moved by the reconnection."""

from __future__ import annotations

import threading
import time

from activetouch.daemon.supervision import DeviceLink, LinkSettings, hand_probe
from activetouch.drivers.reflex.takktile import ReflexTakktileHand
from activetouch.emulators.reflex_takktile import EmulatorConfig, KinematicFingers, TakktileEmulator
from tests.drivers.reflex.conftest import ENCODER_ZERO, GROUP, MOTOR_ZERO, driver_config

BASELINES = [300.0 + 10 * i for i in range(38)]
WAIT_S = 60.0


def board(state_port: int, command_port: int) -> TakktileEmulator:
    return TakktileEmulator(
        EmulatorConfig(
            state_to=f"127.0.0.1:{state_port}",
            command_listen=f"{GROUP}:{command_port}",
            motor_zero_rad=tuple(MOTOR_ZERO),
            encoder_zero_rad=tuple(ENCODER_ZERO),
            baselines=BASELINES,
            noise_std=1.0,
        ),
        KinematicFingers(contact_spool=[1.0, 1.5, float("inf")]),
    ).start()


def wait_state(link: DeviceLink, state: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while link.health().state != state:
        assert time.monotonic() < deadline, f"{state} not reached: {link.health()}"
        time.sleep(0.02)


def test_a_power_cycled_hand_is_lost_then_reconnected_without_moving(ports) -> None:
    hand = ReflexTakktileHand(driver_config(*ports, zero_offsets=list(BASELINES)))
    link = DeviceLink(
        "hand",
        "reflex-takktile",
        hand,
        hand_probe,
        threading.Lock(),
        LinkSettings(retry_s=0.1, check_s=0.05, lost_after_s=0.3),
    )
    emu = board(*ports)
    link.start()
    try:
        wait_state(link, "connected")
        emu.stop()  # power off: the stream stops
        wait_state(link, "lost")
        assert "stream" in link.health().detail or "Stream" in link.health().detail
        emu = board(*ports)  # power on: a board that comes back in IDLE
        wait_state(link, "connected")
        assert not hand.state().stale
        # Re-armed once, on the board that came back (its thread may take the command late).
        deadline = time.monotonic() + WAIT_S
        while emu.position_switches() < 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.2)  # a second, wrong switch would arrive meanwhile
        assert emu.position_switches() == 1
        spool, preshape = emu.joint_state()
        time.sleep(0.2)  # the reconnection commanded no motion: the fingers stay where they are
        after, preshape_after = emu.joint_state()
        assert (after == spool).all() and preshape_after == preshape
    finally:
        link.close()
        hand.disconnect()
        emu.stop()
