"""The SF driver (dynamixel-sdk) against the emulated servos on a pty pair, and the emulator's
Protocol 1.0 parser against hand-built packets.

The emulator is written from the facts (multi-turn servos at reflex-ros-pkg's zero points,
inversion by servo id [+1, -1, +1, -1]) and imports no driver code, so these tests play the SF
as upstream describes it with the driver's default settings."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from activetouch.device_types import device_config
from activetouch.drivers.reflex.common import ServoFaultError, StreamLostError
from activetouch.drivers.reflex.sf import ReflexSFConfig, ReflexSFHand, upstream_load
from activetouch.emulators.reflex_sf import (
    GOAL,
    INST_SYNC_WRITE,
    FixedStops,
    SFEmulator,
    SFEmulatorConfig,
)
from activetouch.errors import ConfigError, StoppedError
from activetouch.models.reflex import DEFAULT_GEOMETRY, sensor_positions
from tests.waiting import started_catching, wait_for

# Not the 0.2 s default: a busy 2-core machine can hold the pty emulator's thread longer than
# that, and no test here is about how soon a silent bus counts as lost (only that it does).
STREAM_TIMEOUT_S = 5.0


@pytest.fixture
def emu():
    e = SFEmulator(fingers=FixedStops([1.0, 1.3, math.inf])).start()
    yield e
    e.stop()


@pytest.fixture
def hand(emu):
    h = ReflexSFHand(ReflexSFConfig(port=emu.port, stream_timeout_s=STREAM_TIMEOUT_S))
    h.connect()
    yield h
    h.disconnect()


def test_hand_built_instruction_packets():
    e = SFEmulator()  # not started: feed the parser directly
    try:
        # PING id 1: checksum ~(1 + 2 + 1) = 0xFB.
        e._buf.extend(bytes.fromhex("FFFF010201FB"))
        assert e._parse() == [bytes.fromhex("FFFF010200FC")]
        # READ id 1, present position (0x24), 2 bytes: checksum ~(1+4+2+0x24+2) = 0xD2.
        e._buf.extend(bytes.fromhex("FFFF01040224 02D2".replace(" ", "")))
        (reply,) = e._parse()
        assert reply[:5] == bytes.fromhex("FFFF010400")
        assert reply[5] | reply[6] << 8 == round(25.21 / (2 * math.pi / 4096))  # its zero: 16434
        assert reply[7] == (~sum(reply[2:7])) & 0xFF
        # Bad checksum addressed to servo 2: a checksum-error status (bit 4).
        e._buf.extend(bytes.fromhex("FFFF02020100"))
        assert e._parse() == [bytes.fromhex("FFFF020210EB")]
        assert e.counts["checksum_errors"] == 1
        # SYNC_WRITE goal position (0x1E), 2 bytes, ids 1 and 3: no reply, tables updated.
        body = bytes([0xFE, 10, 0x83, 0x1E, 2, 1, 0x10, 0x02, 3, 0x20, 0x03])
        e._buf.extend(b"\xff\xff" + body + bytes([(~sum(body)) & 0xFF]))
        assert e._parse() == []
        assert e.tables[1][30:32] == b"\x10\x02" and e.tables[3][30:32] == b"\x20\x03"
    finally:
        e.stop()


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_fuzz_servo_parser(data):
    e = SFEmulator()
    try:
        e._buf.extend(data)
        for reply in e._parse():
            assert reply[:2] == b"\xff\xff" and reply[-1] == (~sum(reply[2:-1])) & 0xFF
    finally:
        e.stop()


def test_guarded_close_reports_stalled_fingers(hand, emu):
    g = hand.guarded_close()
    assert hand.last_close_reasons == ("contact", "contact", "limit")
    assert g.sensor_ids.tolist() == [6, 15]  # one per stalled finger, its distal site
    sites = sensor_positions(DEFAULT_GEOMETRY, g.preshape, g.finger_angles, g.finger_angles * 0.25)
    assert np.allclose(g.xyz, sites[[6, 15]], atol=1e-9)
    assert np.all(g.pressures > 0)
    s = hand.state()
    assert not s.stale and not s.contact.any()  # no tactile sensors on the SF
    # No finger beyond its travel; the free one stopped at the spool limit (3.5 < 3.75 rad).
    assert np.all(emu.spool()[:3] <= 3.75 + 1e-6)
    hand.open()
    assert np.all(np.abs(hand.state().motor[:3]) < 0.06)
    assert np.all(np.abs(emu.spool()[:3]) < 0.06)  # back at the zero points, in the servos too


def test_connecting_moves_nothing(emu):
    # Upstream zero points, default inversion: the old driver sent goals of 4095 to servos at
    # ~16,400 here (three turns). Now connect reads, sets speeds, and writes no goal or torque.
    h = ReflexSFHand(ReflexSFConfig(port=emu.port, stream_timeout_s=STREAM_TIMEOUT_S))
    h.connect()
    try:
        seq = h.state().stamp
        assert wait_for(lambda: h.state().stamp != seq, 30.0)  # the poll thread reads on
        assert all(n == 0 for n in emu.goal_writes.values())
        assert emu.torque_writes == []
        assert np.all(emu.moved_rad == 0.0)
        np.testing.assert_allclose(h.state().motor, 0.0, atol=2e-3)  # open, at the zero points
    finally:
        h.disconnect()
    assert emu.torque_writes == []  # never armed: nothing to turn off


def test_a_servo_a_turn_off_its_zero_point_is_refused_at_connect():
    # Servo 2 one turn (2π motor rad) from where hand.motor_zero_points says the open hand is.
    e = SFEmulator(SFEmulatorConfig(start_offset_rad=(0.0, 2 * math.pi, 0.0, 0.0))).start()
    try:
        with pytest.raises(ServoFaultError, match=r"servo 2 .*motor_zero_points"):
            ReflexSFHand(ReflexSFConfig(port=e.port)).connect()
        assert all(n == 0 for n in e.goal_writes.values()) and e.torque_writes == []
    finally:
        e.stop()


def test_an_alarm_bit_stops_the_hand_naming_the_servo(hand, emu):
    hand.preshape(0.2)  # armed: torque on
    emu.faults.alarm = {3: 0x04}  # overheating
    with pytest.raises(ServoFaultError, match=r"servo 3 .*overheating"):
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            hand.preshape(0.2)
    # The poll thread turns the torque off, every servo.
    off = {(i, 0) for i in (1, 2, 3, 4)}
    assert wait_for(lambda: off <= set(emu.torque_writes), 30.0), emu.torque_writes


def test_goals_outside_the_travel_are_refused_before_anything_is_sent(hand, emu):
    before = dict(emu.goal_writes)
    with pytest.raises(ValueError, match=r"servo 1 .*travel"):
        hand._write_goals(hand._goals(np.array([5.0, 0.0, 0.0, 0.0])))
    with pytest.raises(ValueError, match=r"outside 0\.\.28672"):
        hand._write_goals(np.array([30000, 0, 0, 0]))
    assert emu.goal_writes == before


def test_load_as_upstream_from_hand_built_register_values():
    inv = np.array([1, -1, 1, -1])
    # 0x600: bit 10 set, magnitude 512 (0.5): dynamixel_io reads -0.5; non-inverted negate it.
    # 0x100: bit 10 clear, 256 (0.25): +0.25; non-inverted -0.25, inverted +0.25.
    raw = np.array([0x600, 0x600, 0x100, 0x100])
    np.testing.assert_allclose(upstream_load(raw, inv), [0.5, -0.5, -0.25, 0.25])


def goal_syncs(emu: SFEmulator) -> list[list[int]]:
    """Goal positions (ids 1-4) of every SYNC_WRITE to the goal register the servos got."""
    out = []
    for _, inst, params in list(emu.instructions):
        if inst == INST_SYNC_WRITE and params[0] == GOAL and params[1] == 2:
            out.append([params[j + 1] | params[j + 2] << 8 for j in range(2, len(params), 3)])
    return out


def test_preshape_and_stop(hand, emu, monkeypatch):
    hand.preshape(0.8)
    assert hand.state().preshape == pytest.approx(0.8, abs=0.06)
    emu.set_object([math.inf] * 3)
    n_before = len(goal_syncs(emu))  # the preshape arrived: its goals were taken
    # Every goal write that goes out, (motion, raw goals); the close is held after its third
    # step until stop() has returned, so it cannot reach its limit first however slow this is.
    writes: list[tuple[bool, list[int]]] = []
    write = hand._write_goals
    under_way, stopped = threading.Event(), threading.Event()

    def recording_write(raw, motion: bool = True) -> None:
        write(raw, motion)
        writes.append((motion, [int(v) for v in raw]))
        if motion and sum(m for m, _ in writes) == 3:
            under_way.set()
            stopped.wait(30.0)

    monkeypatch.setattr(hand, "_write_goals", recording_write)
    t, result = started_catching(hand.guarded_close, StoppedError)
    try:
        assert under_way.wait(30.0)
        hand.stop()
    finally:
        stopped.set()
    t.join(30.0)
    assert not t.is_alive() and isinstance(result.get("err"), StoppedError)
    # The close took no step after the stop; the hold (stop()'s goals at the positions read)
    # is the last goal the servos got, and they go there and stay.
    assert sum(m for m, _ in writes) == 3
    (hold,) = [g for m, g in writes if not m]
    assert wait_for(lambda: len(goal_syncs(emu)) >= n_before + len(writes), 30.0)
    assert goal_syncs(emu)[n_before:] == [g for _, g in writes]
    assert wait_for(lambda: emu.raw_positions() == hold, 30.0), (emu.raw_positions(), hold)
    hand.open()  # allowed while stopped
    hand.clear_stop()


def test_mute_servo_is_stream_loss(hand, emu):
    emu.faults.mute = [3]
    with pytest.raises(StreamLostError):
        hand.guarded_close()  # an error, not a hang (that would meet pytest's timeout)
    # Stale (a read begun before the mute may still land once: wait for the poll to see it).
    assert wait_for(lambda: hand.state().stale, 30.0)
    emu.faults.mute = []
    assert wait_for(lambda: not hand.state().stale, 30.0)


def test_no_servos_at_connect():
    e = SFEmulator()
    e.faults.mute = [1, 2, 3, 4]
    e.start()
    try:
        with pytest.raises(StreamLostError):
            ReflexSFHand(ReflexSFConfig(port=e.port)).connect()
    finally:
        e.stop()


def test_config_checks():
    cfg = device_config("hand", {"type": "reflex-sf", "port": "/dev/ttyUSB1"})
    assert isinstance(cfg, ReflexSFConfig)
    assert cfg.motor_inverted == [1, -1, 1, -1]  # by servo id, as reflex_sf.yaml
    with pytest.raises(ConfigError, match="motor_zero_points"):
        device_config("hand", {"type": "reflex-sf", "motor_zero_rad": [0.0] * 4})
    with pytest.raises(ConfigError, match="motor radians"):  # joint-side zeros by mistake
        device_config("hand", {"type": "reflex-sf", "motor_zero_points": [0.0] * 4})
    with pytest.raises(ConfigError, match="baud"):
        device_config("hand", {"type": "reflex-sf", "baud": 57142})
    with pytest.raises(ConfigError):
        device_config("hand", {"type": "reflex-sf", "motor_ids": [1, 1, 2, 3]})
    with pytest.raises(ConfigError):
        ReflexSFHand(ReflexSFConfig(port="/nonexistent/tty")).connect()
