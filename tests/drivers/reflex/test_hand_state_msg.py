"""`hand/state` carries the ReFlex driver's wall-clock stamp and stale flag; old messages
(without them) still decode."""

from __future__ import annotations

import dataclasses
import itertools
import time
import types

import numpy as np

from activetouch.drivers.reflex.common import ReflexHandState
from activetouch.interfaces import HandState
from activetouch.transport.messages import (
    HandStateMsg,
    decode,
    encode,
    hand_state_from_msg,
    hand_state_to_msg,
)


def _state(cls=HandState, **kw):
    return cls(
        pressures=np.arange(38.0),
        contact=np.arange(38) % 2 == 0,
        finger_angles=np.array([0.1, 0.2, 0.3]),
        preshape=0.4,
        stamp=time.monotonic(),
        **kw,
    )


def test_driver_state_keeps_its_wall_stamp_and_stale_flag():
    s = _state(ReflexHandState, stale=True, wall_stamp=1_700_000_000.25)
    msg = decode(encode(hand_state_to_msg(s)), HandStateMsg)
    assert msg.stale is True and msg.wall_stamp == 1_700_000_000.25
    assert msg.stamp == s.stamp
    back = hand_state_from_msg(msg)
    assert np.array_equal(back.pressures, s.pressures) and back.preshape == 0.4


def test_a_state_without_wall_stamp_gets_its_instant_on_the_wall_clock(monkeypatch):
    # The process's clocks, frozen: the state was stamped 2.5 s (monotonic) before now, so it
    # is placed 2.5 s before the wall clock's now.
    from activetouch.transport import messages

    clocks = types.SimpleNamespace(time=lambda: 1_700_000_010.0, monotonic=lambda: 102.5)
    monkeypatch.setattr(messages, "time", clocks)
    s = dataclasses.replace(_state(), stamp=100.0)
    msg = hand_state_to_msg(s)
    assert msg.stale is False
    assert msg.wall_stamp == 1_700_000_007.5


def test_messages_without_the_new_fields_still_decode():
    old = (
        b'{"v":1,"pressures":['
        + b",".join([b"0.0"] * 38)
        + b'],"contact":['
        + b",".join([b"false"] * 38)
        + b'],"finger_angles":[0.0,0.0,0.0],"preshape":0.0,"stamp":12.5}'
    )
    msg = decode(old, HandStateMsg)
    assert msg.wall_stamp == 0.0 and msg.stale is False and msg.stamp == 12.5


def test_state_listener_runs_at_the_packet_rate_and_sees_the_stream_go_stale(emulator, ports):
    """The hook a hand node can publish `hand/state` from: every accepted packet (40 Hz),
    each with a wall-clock and a monotonic stamp, and once more when the stream stops."""
    from activetouch.drivers.reflex.takktile import ReflexTakktileHand

    from .conftest import driver_config

    hand = ReflexTakktileHand(
        driver_config(*ports, zero_offsets=[300.0 + 10 * i for i in range(38)])
    )
    seen: list[ReflexHandState] = []
    hand.add_state_listener(seen.append)
    hand.connect()
    try:
        deadline = time.monotonic() + 30.0
        while len(seen) < 12 and time.monotonic() < deadline:
            time.sleep(0.01)
        before = hand.stats()["accepted"]
        fresh = [s for s in seen if not s.stale]
        after = hand.stats()["accepted"]
        # One call per accepted packet (the newest may be counted, its call on the way).
        assert before - 1 <= len(fresh) <= after and len(fresh) >= 12
        assert all(
            b.stamp > a.stamp and b.wall_stamp > a.wall_stamp for a, b in itertools.pairwise(fresh)
        )
        emulator.faults.stalled = True
        deadline = time.monotonic() + 30.0
        while not (seen and seen[-1].stale) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert seen[-1].stale and hand_state_to_msg(seen[-1]).stale
        n = len(seen)
        time.sleep(0.2)
        assert len(seen) == n  # nothing more while stale
    finally:
        hand.disconnect()
