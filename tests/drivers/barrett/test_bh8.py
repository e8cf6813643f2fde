"""The BH8 driver on its emulator over python-can's virtual bus (no real interface)."""

from __future__ import annotations

import itertools
import math
import random
import threading

import can
import numpy as np
import pytest

from activetouch.device_types import device_config
from activetouch.drivers.barrett import codec
from activetouch.drivers.barrett.bh8 import (
    BarrettBH8Config,
    BarrettBH8Hand,
    NotInitializedError,
    PuckFaultError,
)
from activetouch.drivers.reflex.common import StreamLostError
from activetouch.emulators.barrett_bh8 import (
    PROPS,
    BH8Emulator,
    BH8EmulatorConfig,
    Faults,
    FingerObject,
)
from activetouch.errors import ConfigError, StoppedError
from tests.waiting import wait_for as wait_until

_n = itertools.count()


def wait_for(cond, timeout: float = 20.0) -> bool:
    return wait_until(cond, timeout)


class Rig:
    def __init__(self, emu_kw: dict | None = None, **drv_kw) -> None:
        self.channel = f"bh8-test-{next(_n)}"
        self.emu = BH8Emulator(BH8EmulatorConfig(channel=self.channel, **(emu_kw or {})))
        drv_kw.setdefault("wake_settle_s", 0.01)
        # No test here is about these bounds: generous, so a loaded machine's late reply is
        # not taken for a silent puck (a test that wants a puck silent makes it so).
        drv_kw.setdefault("stream_timeout_s", 2.0)
        drv_kw.setdefault("reply_timeout_s", 2.0)
        drv_kw.setdefault("connect_timeout_s", 10.0)
        self.cfg = BarrettBH8Config(
            type="barrett-bh8", can_interface="virtual", can_channel=self.channel, **drv_kw
        )
        self.cfg.check()
        self.hand = BarrettBH8Hand(self.cfg)

    def __enter__(self) -> Rig:
        self.emu.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.hand.disconnect()
        self.emu.stop()


def test_registered_and_settings():
    cfg = device_config("hand", {"type": "barrett-bh8"})
    assert isinstance(cfg, BarrettBH8Config)
    assert (cfg.can_interface, cfg.can_channel, cfg.bitrate) == ("socketcan", "can0", 1000000)
    assert cfg.initialize_on_connect is False


def test_connect_moves_nothing_and_refuses_before_init():
    with Rig() as rig:
        before = rig.emu.joints()
        rig.hand.connect()
        assert rig.emu.counts["wakes"] == 4
        assert rig.emu.counts["hi"] == 0 and rig.emu.counts["motion_before_init"] == 0
        assert not rig.hand.initialized
        for call in (rig.hand.guarded_close, rig.hand.open, lambda: rig.hand.preshape(0.5)):
            with pytest.raises(NotInitializedError, match=r"hand\.initialize_on_connect"):
                call()
        assert rig.emu.joints() == before
        assert rig.emu.counts["motion_before_init"] == 0
        s = rig.hand.state()
        assert s.pressures.shape == (96,) and not s.stale


def test_initialize_only_with_the_setting():
    with Rig(initialize_on_connect=True) as rig:
        assert rig.emu.joints()["inner"][0] > 0.3  # power-up pose: partly closed
        rig.hand.connect()
        assert rig.hand.initialized and rig.emu.counts["hi"] == 4
        j = rig.emu.joints()
        assert max(j["inner"]) < 1e-3 and j["spread"][0] < 1e-3
        assert rig.emu.counts["motion_before_init"] == 0


def test_guarded_close_stops_each_finger_on_its_own_contact():
    # F1 meets the object at inner 0.6 rad, F2 at 1.0 rad (no pad cells there: its strain
    # gauge stops it), F3 at nothing (closes to the limit).
    obj = FingerObject(
        contact_angle=[0.6, 1.0, math.inf], pad_cells=[[10, 13, 16], [], [10, 13, 16]]
    )
    with Rig({"obj": obj}, initialize_on_connect=True) as rig:
        rig.hand.connect()
        g = rig.hand.guarded_close()
        assert rig.hand.last_close_reasons == ("contact", "strain", "limit")
        assert g.sensor_ids.tolist() == [10, 13, 16]
        # TorqueSwitch: the inner links held at the object, the outer closed on.
        assert g.finger_angles[0] == pytest.approx(0.6, abs=0.01)
        assert g.finger_angles[1] == pytest.approx(1.0, abs=0.01)
        assert g.finger_angles[2] > 2.2
        st = rig.hand.state()
        assert st.outer[0] > 0.6 / 3 + 0.2 - 0.01
        # Reported at the pad's cells on F1's outer link (hand frame, within the hand's reach).
        assert np.all(np.isfinite(g.xyz)) and np.all(np.linalg.norm(g.xyz, axis=1) < 0.25)
        np.testing.assert_allclose(rig.hand.sensor_sites()[g.sensor_ids], g.xyz, atol=1e-3)
        assert rig.hand.own_contact_thresholds().shape == (96,)
        assert np.all(g.pressures >= rig.cfg.contact_threshold)
        # None pressed through to a stall: the fingers stopped on contact.
        j = rig.emu.joints()
        assert j["outer"][0] < 0.6 / 3 + 0.2 + obj.press_limit
        rig.hand.open()
        assert max(rig.emu.joints()["inner"]) < 0.01


def test_stop_within_one_control_step():
    with Rig(initialize_on_connect=True) as rig:
        rig.hand.connect()
        out: dict[str, BaseException] = {}

        def close() -> None:
            try:
                rig.hand.guarded_close()
            except BaseException as e:
                out["e"] = e

        # The true pose when the emulator takes the stop's idle frame: the fingers move on
        # until then for as long as the emulator thread waits to run, which measures the
        # machine's load, not the driver. What counts is what they do after it.
        idle = (codec.node_id(codec.GROUP_HAND), codec.encode_set(rig.hand.pucks[11].ids.MODE, 0))
        stopping = threading.Event()
        at_stop: list[float] = []
        handle = rig.emu._handle

        def handle_and_note(arb: int, data: bytes) -> None:  # runs under the emulator's lock
            handle(arb, data)
            if stopping.is_set() and not at_stop and (arb, data) == idle:
                at_stop.extend(rig.emu._joints(rig.emu.pucks[n])[0] for n in (11, 12, 13))

        rig.emu._handle = handle_and_note  # type: ignore[method-assign]
        t = threading.Thread(target=close)
        t.start()
        assert wait_for(lambda: rig.emu.joints()["inner"][0] > 0.3)
        stopping.set()
        rig.hand.stop()
        t.join(timeout=20)
        assert isinstance(out.get("e"), StoppedError)
        assert wait_for(lambda: not rig.emu.moving())
        after = rig.emu.joints()["inner"]
        assert len(at_stop) == 3, "the stop's idle frame never reached the hand"
        # One control step at 100 counts/ms for 20 ms = 2000 counts = 0.025 rad inner.
        step = rig.cfg.close_velocity * rig.cfg.control_period_s * 1000 / rig.hand.pucks[11].cpr
        assert max(a - b for a, b in zip(after, at_stop, strict=True)) <= step / 125 + 0.02
        with pytest.raises(StoppedError):
            rig.hand.guarded_close()
        rig.hand.open()  # allowed while stopped
        rig.hand.clear_stop()


def test_stream_loss_is_an_error_within_the_timeout():
    with Rig(initialize_on_connect=True) as rig:
        rig.hand.connect()
        rig.emu.faults.bus_off = True
        with pytest.raises(StreamLostError, match="F1"):
            rig.hand.guarded_close()
        assert wait_for(lambda: rig.hand.state().stale)
        rig.emu.faults.bus_off = False
        assert wait_for(lambda: not rig.hand.state().stale)


def test_silent_puck():
    with (
        Rig({"faults": Faults(silent=[13])}, reply_retries=0) as rig,  # asked once: it is mute
        pytest.raises(StreamLostError, match=r"F3 \(puck 13\)"),
    ):
        rig.hand.connect()
    with Rig(initialize_on_connect=True) as rig:
        rig.hand.connect()
        rig.emu.faults.silent.append(12)
        with pytest.raises(StreamLostError, match=r"F2 \(puck 12\)"):
            rig.hand.guarded_close()


def test_stuck_cell_is_masked_and_does_not_stop_its_finger():
    obj = FingerObject(contact_angle=[0.6, 0.8, 0.7])
    with Rig({"obj": obj}, initialize_on_connect=True) as rig:
        rig.hand.connect()
        rig.emu.faults.stuck_cells.append((12, 5))  # F2's cell 5 = id 29, after the tare
        assert wait_for(lambda: rig.hand.state().pressures[29] > 10)
        g = rig.hand.guarded_close()
        assert rig.hand.masked[29]
        assert rig.hand.last_close_reasons == ("contact", "contact", "contact")
        assert g.finger_angles[1] == pytest.approx(0.8, abs=0.01)
        assert 29 not in g.sensor_ids.tolist()
        assert sorted(g.sensor_ids.tolist()) == [10, 13, 16, 34, 37, 40, 58, 61, 64]


def test_implausible_position_names_the_puck():
    with Rig(initialize_on_connect=True) as rig:
        rig.hand.connect()
        host = can.Bus(interface="virtual", channel=rig.channel, receive_own_messages=False)
        try:
            # From the spread (14) to group 3: 0x5C3; 22-bit 0x1FFFFF, far beyond 36000.
            msg = can.Message(
                arbitration_id=0x5C3, data=bytes.fromhex("1fffff"), is_extended_id=False
            )
            # Sent until a reading takes it (the spread's real replies overwrite it otherwise).
            assert wait_for(lambda: host.send(msg) or rig.hand.fault is not None)
        finally:
            host.shutdown()
        assert isinstance(rig.hand.fault, PuckFaultError)
        assert "spread (puck 14)" in str(rig.hand.fault)
        with pytest.raises(PuckFaultError):
            rig.hand.guarded_close()


def test_absent_bus_is_a_config_error():
    cfg = BarrettBH8Config(type="barrett-bh8", can_interface="no-such-interface")
    with pytest.raises(ConfigError, match=r"hand\.can_interface"):
        BarrettBH8Hand(cfg).connect()


def _fuzz_frames(n: int, seed: int = 1):
    rng = random.Random(seed)
    for _ in range(n):
        kind = rng.random()
        src = rng.choice([11, 12, 13, 14]) if rng.random() < 0.7 else rng.randint(1, 31)
        dst = rng.choice([3, 6, 9]) if rng.random() < 0.8 else rng.randint(0, 31)
        arb = 0x400 | (src << 5) | dst
        data = bytes(rng.randrange(256) for _ in range(rng.randint(0, 8)))
        if kind < 0.05:
            yield can.Message(arbitration_id=rng.randrange(1 << 29), data=data, is_extended_id=True)
        elif kind < 0.1:
            yield can.Message(arbitration_id=arb & 0x3FF | 0x400, data=data, is_extended_id=False)
        else:
            yield can.Message(arbitration_id=arb, data=data, is_extended_id=False)


def test_ten_thousand_fuzzed_frames_into_the_live_driver():
    n = 10_000
    with Rig(initialize_on_connect=True) as rig:
        rig.hand.connect()
        base = rig.hand.stats()["received"]
        host = can.Bus(interface="virtual", channel=rig.channel, receive_own_messages=False)
        try:
            for msg in _fuzz_frames(n):
                host.send(msg)
        finally:
            host.shutdown()
        assert wait_for(lambda: rig.hand.stats()["received"] >= base + n, timeout=120)
        s = rig.hand.stats()
        print("fuzz:", n, "frames;", s)
        assert s["crashes"] == 0
        assert s["received"] == s["accepted"] + s["ignored"] + s["refused"]
        assert s["refused"] > 0.3 * n  # most random frames are malformed
        assert rig.hand._rx is not None and rig.hand._rx.is_alive()
        assert rig.hand._poll is not None and rig.hand._poll.is_alive()
        # Plausible-looking garbage may latch a named fault; nothing else.
        assert rig.hand.fault is None or isinstance(rig.hand.fault, PuckFaultError)


def test_lost_frames_are_counted_and_the_grasp_still_completes():
    obj = FingerObject(contact_angle=[0.6, 0.8, 0.7])
    with Rig(
        {"obj": obj, "faults": Faults(loss=0.05), "seed": 3}, initialize_on_connect=True
    ) as rig:
        rig.hand.connect()
        g = rig.hand.guarded_close()
        # Pad and strain gauge load together: with a tactile set lost, the strain may be first.
        assert set(rig.hand.last_close_reasons) <= {"contact", "strain"}
        assert set(g.sensor_ids.tolist()) <= {10, 13, 16, 34, 37, 40, 58, 61, 64}
        assert rig.emu.counts["lost"] > 0
        assert rig.hand.stats()["tactile_incomplete"] > 0


def test_preshape_and_reconnect():
    with Rig(initialize_on_connect=True) as rig:
        rig.hand.connect()
        rig.hand.preshape(0.5)
        assert rig.emu.joints()["spread"][0] == pytest.approx(0.5, abs=0.01)
        assert rig.hand.state().preshape == pytest.approx(0.5, abs=0.01)
        with pytest.raises(ValueError):
            rig.hand.preshape(4.0)
        # The device may go and come back: a new connection finds the pucks awake and moves
        # nothing (no second HI without the setting).
        rig.hand.disconnect()
        again = BarrettBH8Hand(
            BarrettBH8Config(**{**vars(rig.cfg), "initialize_on_connect": False})
        )
        again.connect()
        try:
            assert rig.emu.counts["hi"] == 4 and rig.emu.counts["wakes"] == 4
            assert not again.state().stale
        finally:
            again.disconnect()


def test_property_ids_follow_the_firmware_version():
    # Firmware 143 has TACT but no TACTID (libbarrett's table): a driver asking for TACTID
    # anyway would wait for a reply that never comes and fail the connect.
    old = {k: v for k, v in PROPS.items() if k != "TACTID"}
    with Rig({"firmware": 143, "property_ids": old}) as rig:
        rig.hand.connect()
        assert all(p.ids.TACTID == -1 and p.tact for p in rig.hand.pucks.values())
        assert not rig.hand.state().stale


def test_a_power_cycle_loses_the_initialisation():
    obj = FingerObject(contact_angle=[0.6, 0.8, 0.7])
    with Rig({"obj": obj}, initialize_on_connect=True) as rig:
        rig.hand.connect()
        rig.hand.guarded_close()
        rig.emu.power_cycle()  # the fingers stay closed; the pucks sleep and count from here
        with pytest.raises(StreamLostError):
            rig.hand.open()  # asleep pucks answer no GET P (nor MODE): the stream is lost
        rig.hand.disconnect()
        rig.hand.cfg.initialize_on_connect = False
        rig.hand.connect()  # the daemon's reconnect: wakes them, moves nothing
        assert not rig.hand.initialized
        with pytest.raises(NotInitializedError, match=r"hand\.initialize_on_connect"):
            rig.hand.open()
        assert rig.emu.counts["hi"] == 4 and rig.emu.counts["motion_before_init"] == 0


def test_the_emulate_runner():
    # `activetouch emulate barrett-bh8 ...` in-process on a virtual channel (across processes
    # it needs the kernel's vcan, which tests do not use).
    from activetouch.emulators import barrett_bh8

    ch = f"bh8-runner-{next(_n)}"
    done = threading.Event()
    argv = ["--interface", "virtual", "--channel", ch, "--contact-angle", "0.6", "0.8", "0.7"]
    t = threading.Thread(target=barrett_bh8.main, args=(argv, done))
    t.start()
    hand = BarrettBH8Hand(
        BarrettBH8Config(
            type="barrett-bh8",
            can_interface="virtual",
            can_channel=ch,
            wake_settle_s=0.01,
            initialize_on_connect=True,
            connect_timeout_s=10.0,
        )
    )
    try:
        assert wait_for(lambda: _answers(hand))
        g = hand.guarded_close()
        assert sorted(g.sensor_ids.tolist()) == [10, 13, 16, 34, 37, 40, 58, 61, 64]
    finally:
        hand.disconnect()
        done.set()
        t.join(timeout=10)
    assert not t.is_alive()


def _answers(hand: BarrettBH8Hand) -> bool:
    try:
        hand.connect()
    except StreamLostError:
        return False
    return True
