"""The BH8 emulator answers hand-written frames as protocol facts C say a puck does."""

from __future__ import annotations

import itertools
import math
import time

import can
import pytest

from activetouch.emulators.barrett_bh8 import BH8Emulator, BH8EmulatorConfig, FingerObject
from tests.waiting import wait_for as wait_until

_n = itertools.count()


@pytest.fixture
def rig():
    ch = f"bh8-emu-test-{next(_n)}"
    emu = BH8Emulator(BH8EmulatorConfig(channel=ch, obj=FingerObject(contact_angle=[0.6, 9, 9])))
    emu.start()
    host = can.Bus(interface="virtual", channel=ch, receive_own_messages=False)
    try:
        yield emu, host
    finally:
        host.shutdown()
        emu.stop()


def send(host, arb: int, hexdata: str) -> None:
    host.send(can.Message(arbitration_id=arb, data=bytes.fromhex(hexdata), is_extended_id=False))


HANG_S = 30.0  # a hang bound: waits end as soon as what they wait for arrives


def replies(host, want: int, timeout: float = HANG_S) -> list[can.Message]:
    out, deadline = [], time.monotonic() + timeout
    while len(out) < want and time.monotonic() < deadline:
        m = host.recv(timeout=0.05)
        if m is not None:
            out.append(m)
    return out


VERS_F1 = (0x00B, "00")  # GET VERS to F1: answered asleep or awake
VERS_F1_REPLY = (0x566, bytes.fromhex("8000af000000"))


def replies_before_marker(host, timeout: float = HANG_S) -> list[can.Message]:
    """Every reply to what was sent so far: sends GET VERS to F1 and returns what arrives
    before its answer. The emulator handles frames one at a time, in order, and answers
    each at once, so an answer to an earlier frame cannot come after it."""
    send(host, *VERS_F1)
    out, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = host.recv(timeout=0.05)
        if m is None:
            continue
        if (m.arbitration_id, bytes(m.data)) == VERS_F1_REPLY:
            return out
        out.append(m)
    raise AssertionError(f"F1 did not answer GET VERS within {timeout} s")


def wait_for(cond, timeout: float = HANG_S) -> bool:
    return wait_until(cond, timeout)


def test_asleep_answers_vers_then_wakes(rig):
    _emu, host = rig
    send(host, 0x00B, "00")  # GET VERS (0) to F1 (node 11)
    (m,) = replies(host, 1)
    # Reply from 11 to group 6: 0x400 | 11 << 5 | 6 = 0x566; 0x80 | 0, 0, 175 = 0xaf LE.
    assert m.arbitration_id == 0x566 and bytes(m.data) == bytes.fromhex("8000af000000")
    send(host, 0x00B, "08")  # GET MODE while asleep: not answered
    assert replies_before_marker(host) == []
    send(host, 0x405, "850002000000")  # SET STAT = 2 to the hand group
    send(host, 0x405, "08")  # GET MODE from all four
    got = replies(host, 4)
    assert sorted(m.arbitration_id for m in got) == [0x566, 0x586, 0x5A6, 0x5C6]
    assert all(bytes(m.data) == bytes.fromhex("880000000000") for m in got)


def test_hi_moves_fingers_and_zeroes_the_encoder(rig):
    emu, host = rig
    before = emu.joints()["inner"]
    send(host, 0x405, "850002000000")
    send(host, 0x00C, "30")  # GET P (48 = 0x30) from F2 (12): counts since power-up = 0
    (m,) = replies(host, 1)
    assert m.arbitration_id == 0x583 and bytes(m.data) == bytes.fromhex("000000000000")
    send(host, 0x00C, "9d000d000000")  # SET CMD (29) = HI (13)
    assert wait_for(lambda: emu.pucks[12].initialized)
    assert emu.joints()["inner"][1] < before[1]
    assert emu.counts["motion_before_init"] == 0


def test_close_breaks_away_and_reports_tactile(rig):
    emu, host = rig
    send(host, 0x405, "850002000000")
    send(host, 0x00B, "9d000d000000")  # HI F1
    assert wait_for(lambda: emu.pucks[11].initialized)
    send(host, 0x00B, "ea0003000000")  # SET TACT (106 = 0x6a) = TARE (3)
    send(host, 0x00B, "9d0012000000")  # CMD CLOSE (18)
    assert wait_for(lambda: emu.joints()["inner"][0] > 0.5)
    assert wait_for(lambda: not emu.moving())
    j = emu.joints()
    # F1 met the object at inner 0.6: the inner link held, the outer closed on.
    assert j["inner"][0] == pytest.approx(0.6)
    assert j["outer"][0] > 0.6 / 3 + 0.2
    while host.recv(timeout=0.05) is not None:
        pass
    send(host, 0x00B, "ea0002000000")  # SET TACT = FULL: five frames to group 9 (0x569)
    got = replies(host, 5)
    assert [m.arbitration_id for m in got] == [0x569] * 5
    assert [m.data[0] >> 4 for m in got] == [0, 1, 2, 3, 4]
    d = bytes(got[2].data)  # seq 2 holds cells 10..14; cell 10 is c0, cell 13 is c3
    c0 = ((d[0] & 0x0F) << 8) | d[1]
    c3 = (d[5] << 4) | (d[6] >> 4)
    assert c0 > 256 and c3 > 256  # pressed well above 1.0
    c1 = (d[2] << 4) | (d[3] >> 4)
    assert c1 == 0  # untouched cell, tared
    send(host, 0x00B, "19")  # GET SG (25)
    (m,) = replies(host, 1)
    assert m.arbitration_id == 0x566 and m.data[0] == 0x99
    assert int.from_bytes(bytes(m.data[2:]), "little", signed=True) > 2000 + 100


def test_faults_silent_and_stuck(rig):
    emu, host = rig
    send(host, 0x405, "850002000000")
    emu.faults.silent.append(13)
    send(host, 0x405, "08")  # GET MODE from all four: F3 (13) keeps quiet
    got = replies_before_marker(host)
    assert sorted(m.arbitration_id for m in got) == [0x566, 0x586, 0x5C6]
    emu.faults.stuck_cells.append((11, 0))
    send(host, 0x00B, "ea0002000000")
    got = replies(host, 5)
    d = bytes(got[0].data)
    assert ((d[0] & 0x0F) << 8) | d[1] == 4095
    emu.faults.bus_off = True
    send(host, 0x00B, "00")
    assert replies(host, 1, timeout=0.3) == []
    assert not math.isnan(emu.joints()["spread"][0])
