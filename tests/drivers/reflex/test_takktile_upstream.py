"""The TakkTile driver against upstream behaviour (issue 23, findings 3, 6, 7): real tactile
baselines, the start sequence, mode switches, IDLE at disconnect, load and overload, readings
that cannot be true. The emulator plays a board at a real hand's baselines."""

from __future__ import annotations

import ast
import math
import pathlib
import threading
import time

import numpy as np
import pytest

from activetouch.drivers.reflex.takktile import (
    ReflexTakktileHand,
    ServoFaultError,
    TactileCalibrationError,
)
from activetouch.emulators.reflex_takktile import (
    UPSTREAM_BASELINES,
    EmulatorConfig,
    KinematicFingers,
    TakktileEmulator,
)
from tests.waiting import wait_for as wait_until

from .conftest import GROUP, MOTOR_ZERO, driver_config, free_udp_port
from .packets import state_packet

TICK = 4 * 2 * math.pi / 4095
ROOT = pathlib.Path(__file__).resolve().parents[3] / "activetouch"


def wait_for(cond, timeout: float = 5.0) -> bool:
    return wait_until(cond, timeout)


@pytest.fixture
def board_at_baselines():
    """An emulated board at upstream's unloaded readings (56-306 counts), nothing touching."""
    sp, cp = free_udp_port(), free_udp_port()
    emu = TakktileEmulator(
        EmulatorConfig(
            state_to=f"127.0.0.1:{sp}",
            command_listen=f"{GROUP}:{cp}",
            motor_zero_rad=tuple(MOTOR_ZERO),
            encoder_zero_rad=(0.0, 0.0, 0.0),
            noise_std=1.5,
            servo_answer_delay_s=0.2,
        ),
        KinematicFingers(contact_spool=[math.inf] * 3),
    ).start()
    yield emu, sp, cp
    emu.stop()


def connect(sp: int, cp: int, **kw) -> ReflexTakktileHand:
    kw.setdefault("encoder_zero_rad", [0.0] * 3)
    hand = ReflexTakktileHand(driver_config(sp, cp, **kw))
    hand.connect()
    return hand


def test_emulator_sits_at_upstream_baselines():
    assert min(UPSTREAM_BASELINES[:27]) == 56 and max(UPSTREAM_BASELINES[:27]) == 306


def test_no_calibration_no_contacts_at_rest_and_close_refused(board_at_baselines):
    emu, sp, cp = board_at_baselines
    hand = connect(sp, cp)
    try:
        s = hand.state()
        assert s.pressures.min() > 20  # raw baselines: every sensor above the threshold
        assert not s.contact.any()  # ... yet none is reported as contact
        n = len(emu.commands)
        with pytest.raises(TactileCalibrationError, match="activetouch calibrate tactile"):
            hand.guarded_close()
        assert len(emu.commands) == n  # nothing sent
    finally:
        hand.disconnect()


def test_zero_on_connect_then_close_on_nothing_reports_no_contact(board_at_baselines):
    _emu, sp, cp = board_at_baselines
    hand = connect(sp, cp, zero_on_connect=True)
    try:
        assert hand.tactile_calibrated
        assert not hand.state().contact.any()
        g = hand.guarded_close()
        assert g.n_contacts == 0
        assert "contact" not in hand.last_close_reasons
        hand.open()
    finally:
        hand.disconnect()


def test_sensor_in_contact_with_the_hand_open_is_masked(board_at_baselines):
    _emu, sp, cp = board_at_baselines
    zero = list(UPSTREAM_BASELINES)
    zero[5] -= 100  # a stale calibration: sensor 5 now reads 100 over its zero at rest
    hand = connect(sp, cp, zero_offsets=zero)
    try:
        assert hand.masked[5] and hand.masked.sum() == 1
        assert not hand.state().contact.any()
    finally:
        hand.disconnect()


def test_start_sequence_mode_switches_and_idle_at_disconnect(board_at_baselines):
    emu, sp, cp = board_at_baselines
    hand = connect(sp, cp, zero_on_connect=True)
    try:
        kinds = [c for c in emu.commands]
        # hold goals, VELOCITY, speed targets (3.0 / 2.0 rad/s in MX-28 units), POSITION.
        assert kinds[0][0] == "targets"
        assert kinds[1] == ("mode", [1, 1, 1, 1])
        assert kinds[2] == ("targets", [356, 356 + 1024, 356, 251 + 1024])
        assert kinds[3] == ("mode", [2, 2, 2, 2])
        assert emu.position_switches() == 1 and emu.angle_limit_writes == [1, 1, 1, 1]
        hand.open()
        hand.preshape(0.3)
        hand.guarded_close()
        hand.open()
        assert emu.position_switches() == 1  # none per command
        # A board restart: back in IDLE, zero-initialised; the driver re-arms once.
        emu.restart()
        assert wait_for(lambda: emu.position_switches() == 2)
        assert hand.stats()["board_restarts"] == 1
        time.sleep(0.2)
        assert emu.position_switches() == 2
        hand.open()
        assert emu.position_switches() == 2
    finally:
        hand.disconnect()
    assert wait_for(lambda: emu.commands[-1] == ("mode", [0, 0, 0, 0]))


def test_raw_zero_servo_at_connect_names_it_and_sends_nothing():
    sp, cp = free_udp_port(), free_udp_port()
    cfg = EmulatorConfig(
        state_to=f"127.0.0.1:{sp}", command_listen=f"{GROUP}:{cp}", mute_servos=[2]
    )
    with TakktileEmulator(cfg) as emu:
        hand = ReflexTakktileHand(driver_config(sp, cp, connect_timeout_s=0.5))
        with pytest.raises(ServoFaultError, match=r"finger 2 \(thumb\) servo.*position 0"):
            hand.connect()
        time.sleep(0.1)
        assert emu.raw_commands == []


def test_alarm_while_armed_stops_without_holding_from_it(board_at_baselines):
    emu, sp, cp = board_at_baselines
    hand = connect(sp, cp, zero_on_connect=True)
    try:
        n = len(emu.commands)
        emu.dxl_error[1] = 0x04  # overheating
        assert wait_for(lambda: hand.fault is not None)
        with pytest.raises(ServoFaultError, match=r"finger 1 \(middle\) servo.*overheating"):
            hand.guarded_close()
        hand.stop()
        time.sleep(0.1)
        assert [c for c in emu.commands[n:] if c[0] == "targets"] == []
    finally:
        hand.disconnect()


def test_overload_while_holding_is_loosened(board_at_baselines):
    emu, sp, cp = board_at_baselines
    hand = connect(sp, cp, zero_on_connect=True)
    try:
        hand.command_motors(np.array([1.0, 0.0, 0.0, 0.0]))
        assert wait_for(lambda: hand.state().motor[0] > 0.95)
        n = len(emu.commands)
        emu.extra_load[0] = 600  # something pushes finger 0 while nothing runs
        assert wait_for(lambda: hand.stats()["overload_loosened"] > 0)

        def after() -> list:
            return [c for c in emu.commands[n:] if c[0] == "targets"]

        assert wait_for(lambda: after())
        after = after()
        raw_hold = round((1.0 + MOTOR_ZERO[0]) * 1.42 / TICK)
        assert after[0][1][0] < raw_hold  # finger 0 loosened (inversion +1)
    finally:
        hand.disconnect()


def test_unicast_commands_are_dropped_by_the_board(board_at_baselines):
    emu, sp, _ = board_at_baselines
    host, port = emu.unicast_address.rsplit(":", 1)
    hand = connect(sp, int(port), command_host=host)
    try:
        assert wait_for(lambda: emu.dropped_unicast >= 4)
        assert emu.position_switches() == 0 and emu.commands == []
    finally:
        hand.disconnect()


def test_load_conversion_and_ema_from_hand_built_bytes():
    """raw > 1023 -> raw - 1023, else -raw; times inversion [+1, -1, +1, -1]; EMA 0.25."""
    import socket

    cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    cmd.bind((GROUP, 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sp = free_udp_port()
    gear = (1.42, 1.42, 1.42, 1.5)
    pos = tuple(round(z * g / TICK) for z, g in zip(MOTOR_ZERO, gear, strict=True))
    clock = [0]

    def send(loads=(0, 0, 0, 0)) -> None:
        clock[0] += 25_000
        tx.sendto(state_packet(clock[0], positions=pos, loads=loads), ("127.0.0.1", sp))

    stop = threading.Event()

    def feed() -> None:
        while not stop.is_set():
            send()
            time.sleep(0.02)

    t = threading.Thread(target=feed, daemon=True)
    t.start()
    hand = ReflexTakktileHand(driver_config(sp, cmd.getsockname()[1], stream_timeout_s=2.0))
    try:
        hand.connect()
        stop.set()
        t.join()
        assert np.allclose(hand.state().load, 0.0)
        loads = (1023 + 200, 100, 0, 1023 + 100)  # signed: +200, +100, 0, -100
        for k in range(1, 4):
            before = hand.stats()["accepted"]
            send(loads)
            assert wait_for(lambda before=before: hand.stats()["accepted"] > before)
            expect = np.array([200.0, 100.0, 0.0, -100.0]) * (1 - 0.75**k)
            np.testing.assert_allclose(hand.state().load, expect, atol=1e-9)
    finally:
        stop.set()
        hand.disconnect()
        cmd.close()
        tx.close()


def _imports(path: pathlib.Path) -> set[str]:
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_no_import_cycle_between_drivers_and_calibration():
    for f in (ROOT / "drivers").rglob("*.py"):
        assert "activetouch.calibration.apply" not in _imports(f), f
    for f in (ROOT / "calibration").rglob("*.py"):
        assert not any(m.startswith("activetouch.drivers") for m in _imports(f)), f
    for f in (ROOT / "emulators").rglob("*.py"):
        bad = [m for m in _imports(f) if m.startswith(("activetouch.drivers", "activetouch.rigs"))]
        assert not bad, (f, bad)
