"""The TakkTile driver on loopback UDP: against hand-built packets and against the emulator."""

from __future__ import annotations

import math
import random
import socket
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest

from activetouch.device_types import config_class, device_config
from activetouch.drivers.reflex import kinematics
from activetouch.drivers.reflex.common import StreamLostError
from activetouch.drivers.reflex.takktile import ReflexTakktileConfig, ReflexTakktileHand
from activetouch.errors import ConfigError, StoppedError
from tests.waiting import started_catching, wait_for

from .conftest import GROUP, MOTOR_ZERO, driver_config, free_udp_port
from .packets import state_packet

TICK = 4 * 2 * math.pi / 4095
EMULATOR_OFFSETS = [300.0 + 10 * i for i in range(38)]  # the emulator fixture's baselines


class Board:
    """The test as the hand's board: a socket that sends hand-built packets and hears
    commands."""

    def __init__(self) -> None:
        self.state_port = free_udp_port()
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cmd.bind((GROUP, 0))
        self.cmd.settimeout(1.0)
        self.tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.systime = 0

    @property
    def command_port(self) -> int:
        return self.cmd.getsockname()[1]

    def send(self, data: bytes) -> None:
        self.tx.sendto(data, ("127.0.0.1", self.state_port))

    def packet(self, **kw) -> bytes:
        self.systime += 25_000
        return state_packet(systime=self.systime, **kw)

    def close(self) -> None:
        self.cmd.close()
        self.tx.close()


@pytest.fixture
def board():
    b = Board()
    yield b
    b.close()


def at_rest_positions() -> tuple[int, int, int, int]:
    # Raw servo positions of spool 0 by hand: raw = (inv * 0 + zero) * gear / tick.
    gear = (1.42, 1.42, 1.42, 1.5)
    return tuple(round(z * g / TICK) for z, g in zip(MOTOR_ZERO, gear, strict=True))


def targets_bytes(raw) -> bytes:
    """A set-targets command (0x02, four big-endian u16), built by hand."""
    return b"\x02" + b"".join(int(v).to_bytes(2, "big") for v in raw)


def feed(board: Board, stop: threading.Event, **kw) -> threading.Thread:
    def run() -> None:
        while not stop.is_set():
            board.send(board.packet(**kw))
            time.sleep(0.025)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_independent_packets_and_open_command_bytes(board):
    """Packets built from the published layout decode to the expected pressures and
    contacts; open() sends the expected bytes to the command address."""
    pressures = [500] * 38
    pressures[4] = 500 + 21  # pointer sensor 4: over the threshold (20) above its offset
    pressures[18] = 500 + 20  # thumb sensor 0: exactly at the threshold: not a contact
    pressures[30] = 500 + 100  # a palm sensor
    stop = threading.Event()
    feed(board, stop, pressures_by_id=pressures, positions=at_rest_positions())
    cfg = driver_config(board.state_port, board.command_port, zero_offsets=[500.0] * 38)
    hand = ReflexTakktileHand(cfg)
    try:
        hand.connect()
        s = hand.state()
        assert not s.stale
        assert s.pressures[4] == 21 and s.pressures[18] == 20 and s.pressures[30] == 100
        assert np.flatnonzero(s.contact).tolist() == [4, 30]
        assert np.allclose(s.motor, 0.0, atol=TICK)
        raw = at_rest_positions()
        hold = targets_bytes(raw)
        # connect (upstream's start): goals where the servos are, VELOCITY, speeds, POSITION.
        assert board.cmd.recv(64) == hold
        assert board.cmd.recv(64) == bytes([1, 1, 1, 1, 1])
        # 3.0 rad/s * 1.42 / 0.01194 = 356, 2.0 * 1.5 / 0.01194 = 251; +1024 when inverted.
        speeds = (356, 356 + 1024, 356, 251 + 1024)
        assert board.cmd.recv(64) == b"\x02" + b"".join(v.to_bytes(2, "big") for v in speeds)
        assert board.cmd.recv(64) == bytes([1, 2, 2, 2, 2])
        hand.open()  # no mode switch before a command
        assert board.cmd.recv(64) == targets_bytes(raw)
    finally:
        stop.set()
        hand.disconnect()


def test_guarded_close_on_emulator(hand, emulator):
    g = hand.guarded_close()
    assert hand.last_close_reasons == ("contact", "contact", "limit")
    # Each finger stops at its first reading over threshold: with noise, one or both of its
    # two pressed pads are over it then.
    ids = set(g.sensor_ids.tolist())
    assert ids & {2, 3} and ids & {11, 12} and ids <= {2, 3, 11, 12}
    assert not (set(g.sensor_ids.tolist()) & set(range(18, 27)))  # the thumb touched nothing
    assert g.xyz.shape == (g.n_contacts, 3)
    assert np.all(g.pressures > 20)
    # The sites the hand tells (for contacts decided again on later readings) are the grasp's.
    np.testing.assert_allclose(hand.sensor_sites()[g.sensor_ids], g.xyz, atol=1e-3)
    np.testing.assert_array_equal(hand.own_contact_thresholds(), np.full(38, 20.0))
    # Proximal angles follow the emulated fingers: held where each met the object.
    assert g.finger_angles[0] == pytest.approx(1.0 / 1.25, abs=0.02)
    assert g.finger_angles[1] == pytest.approx(1.5 / 1.25, abs=0.02)
    s = hand.state()
    assert s.distal[2] == pytest.approx(s.motor[2] - s.finger_angles[2], abs=1e-9)
    hand.open()
    spool, _ = emulator.joint_state()
    assert np.all(np.abs(spool) < 0.06)


def test_preshape(hand, emulator):
    hand.preshape(0.8)
    assert hand.state().preshape == pytest.approx(0.8, abs=0.06)
    with pytest.raises(ValueError):
        hand.preshape(2.0)


def recorded_hand(
    ports: tuple[int, int],
    monkeypatch: pytest.MonkeyPatch,
    after_motion: Callable[[int], None] | None = None,
    **kw,
) -> tuple[ReflexTakktileHand, list[tuple[bool, bytes]]]:
    """A driver for the emulator fixture (not yet connected) and the list of every command it
    sends from connect on, (motion, bytes), each once it has gone out. `after_motion(k)` runs
    on the sending thread after the k-th motion command."""
    hand = ReflexTakktileHand(driver_config(*ports, zero_offsets=EMULATOR_OFFSETS, **kw))
    sent: list[tuple[bool, bytes]] = []
    send = hand._send

    def recording_send(data: bytes, motion: bool = True) -> None:
        send(data, motion)
        sent.append((motion, data))
        if motion and after_motion is not None:
            after_motion(sum(m for m, _ in sent))

    monkeypatch.setattr(hand, "_send", recording_send)
    return hand, sent


def test_stop_interrupts_close_within_one_step(ports, emulator, monkeypatch):
    """stop() while a guarded close waits for its next packet: the close raises without one,
    the hold is the last command the board gets (`_send` and stop() share a lock, so no target
    can follow it), and the motors end there."""
    under_way = threading.Event()

    def stall(k: int) -> None:
        if k == 3:
            emulator.faults.stalled = True  # no packet after the close's third step
            under_way.set()

    # The stream stops mid-close so that only stop() can end the close; a stream timeout as
    # long as the test's hang bound keeps that from being a stream loss (not under test here).
    hand, sent = recorded_hand(ports, monkeypatch, stall, stream_timeout_s=30.0)
    hand.connect()
    try:
        n_connect = len(sent)
        emulator.set_object([math.inf] * 3)
        t, result = started_catching(hand.guarded_close, StoppedError)
        assert under_way.wait(30.0)
        hand.stop()
        t.join(30.0)
        assert not t.is_alive() and isinstance(result.get("err"), StoppedError)
        (hold,) = [d for m, d in sent[n_connect:] if not m]  # stop()'s, nothing else
        # Every command reached the board (one socket to one socket: in order); the hold last.
        assert wait_for(lambda: len(emulator.raw_commands) >= len(sent), 30.0)
        assert len(emulator.raw_commands) == len(sent)
        assert emulator.raw_commands[-1] == hold
        # The motors go to the hold and stay there: nothing is commanded after it.
        (kind, raw) = emulator.commands[-1]
        assert kind == "targets"
        held = kinematics.motor_angle(np.array(raw), hand.gear, hand.inverted, hand.motor_zero)
        held = np.maximum(held[:3], 0.0)  # the emulated spools stop at 0
        assert wait_for(lambda: np.allclose(emulator.joint_state()[0], held, atol=1e-6), 30.0), (
            emulator.joint_state(),
            held,
        )
        n = len(sent)
        with pytest.raises(StoppedError):
            hand.guarded_close()
        with pytest.raises(StoppedError):
            hand.preshape(0.5)
        assert len(sent) == n  # refused before anything was sent
        emulator.faults.stalled = False
        hand.open()  # releasing is allowed while stopped
        hand.clear_stop()
        hand.preshape(0.2)
    finally:
        emulator.faults.stalled = False
        hand.disconnect()


def test_stream_loss_is_an_error_and_stale(ports, emulator, monkeypatch):
    def stall(k: int) -> None:
        if k == 3:
            emulator.faults.stalled = True  # the stream stops after the close's third step

    hand, sent = recorded_hand(ports, monkeypatch, stall)
    hand.connect()
    try:
        n_connect = len(sent)
        emulator.set_object([math.inf] * 3)
        t, result = started_catching(hand.guarded_close, StreamLostError)
        t.join(timeout=30.0)  # an error, not a hang
        assert not t.is_alive() and "err" in result
        # The receive thread marks the loss (the close's own wait may run out first).
        assert wait_for(lambda: hand.stats().get("stream_lost", 0) >= 1, 30.0)
        assert hand.state().stale
        assert hand.stats()["stream_lost"] == 1
        # It then commands a hold where the motors last were, and the board gets it.
        last = hand.state().motor
        hold = targets_bytes(kinematics.motor_raw(last, hand.gear, hand.inverted, hand.motor_zero))
        assert wait_for(lambda: (False, hold) in sent, 30.0)
        assert [d for m, d in sent[n_connect:] if not m] == [hold]
        assert wait_for(lambda: len(emulator.raw_commands) >= len(sent), 30.0)
        with pytest.raises(StreamLostError):
            hand.guarded_close()
        emulator.faults.stalled = False  # the stream comes back: so does the hand
        assert wait_for(lambda: not hand.state().stale, 30.0)
        hand.open()
    finally:
        emulator.faults.stalled = False
        hand.disconnect()


def test_fuzzed_packets_into_live_driver(board):
    """>= 10,000 random, truncated, oversized and bit-flipped datagrams: all counted, the
    receive thread survives, valid packets still decode afterwards."""
    stop = threading.Event()
    feeder = feed(board, stop, positions=at_rest_positions())
    hand = ReflexTakktileHand(driver_config(board.state_port, board.command_port))
    try:
        hand.connect()
        stop.set()
        feeder.join()
        # One socket to one socket keeps order: once a later packet is read, every packet the
        # feeder sent has been counted and the counts stand still.
        marker = [0] * 38
        marker[9] = 77
        board.send(board.packet(pressures_by_id=marker, positions=at_rest_positions()))
        assert wait_for(lambda: hand.state().pressures[9] == 77, 30.0)
        before = hand.stats()

        def received() -> int:
            return hand.stats()["received"] - before["received"]

        rng = random.Random(1)
        good = board.packet(positions=at_rest_positions())
        n = 0
        for i in range(10_000):
            kind = i % 4
            if kind == 0:
                d = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 400)))
            elif kind == 1:
                d = good[: rng.randrange(0, 202)]
            elif kind == 2:
                d = good + bytes(rng.randrange(1, 300))
            else:
                b = bytearray(good)
                for _ in range(rng.randrange(1, 8)):
                    bit = rng.randrange(202 * 8)
                    b[bit // 8] ^= 1 << (bit % 8)
                d = bytes(b)
            board.send(d)
            n += 1
            if i % 100 == 99:
                # At most 100 datagrams in flight: well within the socket's receive buffer
                # (loopback drops on a full one), however slowly the driver reads.
                assert wait_for(lambda k=n: received() >= k, 30.0), (received(), n)
        assert wait_for(lambda: received() >= n, 30.0), (received(), n)
        after = hand.stats()
        got = after["received"] - before["received"]
        assert got == n
        refused = sum(after.get(k, 0) - before.get(k, 0) for k in after if k.startswith("refused"))
        accepted = after["accepted"] - before["accepted"]
        dup = after["duplicate_or_old"] - before["duplicate_or_old"]
        assert refused + accepted + dup == n  # every datagram counted once
        assert refused > 7000
        assert hand._thread is not None and hand._thread.is_alive()
        # Valid packets still decode after the storm (a later board clock).
        board.systime += 10**9
        pressures = [0] * 38
        pressures[7] = 55
        board.send(board.packet(pressures_by_id=pressures, positions=at_rest_positions()))
        assert wait_for(lambda: hand.state().pressures[7] == 55, 30.0)
    finally:
        stop.set()
        hand.disconnect()


def test_faults_five_percent_loss_and_friends(hand, emulator):
    f = emulator.faults
    f.loss = f.duplicate = f.reorder = f.corrupt = f.truncate = 0.05
    g = hand.guarded_close()
    assert hand.last_close_reasons[:2] == ("contact", "contact")
    ids = set(g.sensor_ids.tolist())
    assert ids & {2, 3} and ids & {11, 12}
    stats = hand.stats()
    assert stats["duplicate_or_old"] > 0
    assert stats.get("refused_length", 0) > 0
    hand.open()


def test_stuck_sensors(hand, emulator):
    emulator.faults.stuck_saturated = [5]
    emulator.faults.stuck_zero = [6]

    def stuck_read() -> bool:
        s = hand.state()
        # A saturated sensor reads as contact (calibration must catch it); a zero one reads
        # zero raw minus its offset. Noise (std 1 count) never does either.
        return bool(s.contact[5]) and s.pressures[6] < -100

    assert wait_for(stuck_read, 30.0), hand.state().pressures[[5, 6]]


def test_connect_without_stream_times_out():
    cfg = driver_config(free_udp_port(), free_udp_port(), connect_timeout_s=0.2)
    hand = ReflexTakktileHand(cfg)
    with pytest.raises(StreamLostError):
        hand.connect()  # an error, not a hang


def test_registry_and_config_checks():
    assert issubclass(config_class("hand", "reflex-takktile"), ReflexTakktileConfig)
    cfg = device_config(
        "hand",
        {
            "type": "reflex-takktile",
            "state_listen": "127.0.0.1:5000",
            "command_to": "127.0.0.1:5001",
            "multicast_group": "",
        },
    )
    assert cfg.state_listen == "127.0.0.1:5000"
    with pytest.raises(ConfigError):
        device_config("hand", {"type": "reflex-takktile", "state_listen": "nonsense"})
    with pytest.raises(ConfigError):
        device_config("hand", {"type": "reflex-takktile", "gear_ratio": [1.0]})
    with pytest.raises(ConfigError):
        device_config("hand", {"type": "reflex-takktile", "motor_inverted": [1, 1, 2, 1]})
