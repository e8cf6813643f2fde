import contextlib
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from activetouch.drivers.reflex import codec, kinematics
from activetouch.drivers.reflex.common import close_step

from .packets import state_packet


def test_decode_hand_built_packet_remaps_wire_order():
    pressures = [1000 + i for i in range(38)]  # by sensor id
    data = state_packet(
        systime=0x01020304,
        pressures_by_id=pressures,
        encoders=(1, 16382, 300),
        positions=(13000, 13001, 65535, 0),
        loads=(0x400 | 5, 5, 1023, 0),
    )
    p = codec.decode_state(data)
    assert p.systime_us == 0x01020304
    assert p.pressures.tolist() == pressures
    # Wire 9 is the thumb's first sensor (id 18); wire 18 the middle's first (id 9).
    assert int.from_bytes(data[8 + 2 * 9 : 8 + 2 * 10], "little") == 1018
    assert int.from_bytes(data[8 + 2 * 18 : 8 + 2 * 19], "little") == 1009
    assert p.temperatures[18] == 100 + 9 and p.temperatures[9] == 100 + 18
    assert p.encoders.tolist() == [1, 16382, 300]
    assert p.dxl_position.tolist() == [13000, 13001, 65535, 0]
    assert p.dxl_speed.tolist() == [7] * 4
    assert p.dxl_load.tolist() == [0x405, 5, 1023, 0]
    assert p.dxl_voltage.tolist() == [120, 121, 122, 123]
    assert p.dxl_temperature.tolist() == [30, 31, 32, 33]


def test_wire_map_is_a_permutation():
    assert sorted(codec.ID_OF_WIRE.tolist()) == list(range(38))
    assert codec.ID_OF_WIRE[codec.WIRE_OF_ID].tolist() == list(range(38))


@pytest.mark.parametrize("n", [0, 1, 201, 203, 388])
def test_refuses_other_lengths(n):
    with pytest.raises(codec.PacketError) as e:
        codec.decode_state(bytes([1]) * n)
    assert e.value.reason == "length"


def test_refuses_other_versions():
    with pytest.raises(codec.PacketError) as e:
        codec.decode_state(state_packet(version=2))
    assert e.value.reason == "version"


def test_command_bytes():
    assert codec.encode_set_mode([0, 1, 2, 2]) == bytes.fromhex("0100010202")
    assert codec.encode_set_targets([0x1234, 1, 0xFFFF, 256]) == bytes.fromhex("0212340001ffff0100")
    with pytest.raises(ValueError):
        codec.encode_set_targets([0, 0, 0, 65536])
    with pytest.raises(ValueError):
        codec.encode_set_mode([0, 0, 3, 0])


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=198, max_size=198), st.integers(0, 2**32 - 1))
def test_round_trip(body, systime):
    data = bytes([1, 0, 0, 0]) + body
    data = data[:4] + systime.to_bytes(4, "little") + data[8:]
    assert codec.encode_state(codec.decode_state(data)) == data


@settings(max_examples=2000, deadline=None)
@given(st.binary(max_size=600))
def test_fuzz_decode_never_crashes(data):
    try:
        p = codec.decode_state(data)
    except codec.PacketError:
        assert len(data) != 202 or data[0] != 1
    else:
        assert len(data) == 202 and p.pressures.shape == (38,)


@settings(max_examples=1000, deadline=None)
@given(st.integers(0, 201), st.integers(0, 7), st.integers(0, 201))
def test_fuzz_bitflips_and_truncation(byte, bit, cut):
    good = bytearray(state_packet())
    good[byte] ^= 1 << bit
    for data in (bytes(good), bytes(good[:cut])):
        with contextlib.suppress(codec.PacketError):
            codec.decode_state(data)


def test_is_newer():
    assert codec.is_newer(5, None)
    assert codec.is_newer(6, 5)
    assert not codec.is_newer(5, 5)  # duplicate
    assert not codec.is_newer(4, 5)  # reordered
    assert codec.is_newer(3, 2**32 - 10)  # wrap
    assert codec.is_newer(10, 50_000_000)  # board restarted


def test_motor_conversions_by_hand():
    gear = np.array([1.42, 1.42, 1.42, 1.5])
    inv = np.array([1, -1, 1, -1])
    zero = np.array([56.0, 57.0, 55.5, 53.0])
    tick = 4 * 2 * math.pi / 4095
    raw = kinematics.motor_raw(np.array([1.0, 1.0, 0.0, 0.8]), gear, inv, zero)
    assert raw[0] == round((1.0 + 56.0) * 1.42 / tick)
    assert raw[1] == round((-1.0 + 57.0) * 1.42 / tick)
    assert raw[3] == round((-0.8 + 53.0) * 1.5 / tick)
    back = kinematics.motor_angle(raw, gear, inv, zero)
    assert np.allclose(back, [1.0, 1.0, 0.0, 0.8], atol=tick)


def test_load_speed_and_encoder_unwrap():
    # Upstream's load_raw_to_signed: raw > 1023 -> raw - 1023 (so 1024 + 300 gives 301, not
    # the servo's own bit-10 reading of 300), else -raw; times the inversion.
    raw = np.array([1024 + 300, 300, 1023, 1024])
    assert kinematics.load_from_raw(raw, np.ones(4)).tolist() == [301.0, -300.0, -1023.0, 1.0]
    assert kinematics.load_from_raw(np.array([1024 + 300]), np.array([-1])).tolist() == [-301.0]
    # Speeds: |rad/s| * gear / 0.01194 units, +1024 for the reverse sense, never 0.
    assert kinematics.speed_raw(3.0, 1.42, 1) == int(3.0 * 1.42 / 0.01194)
    assert kinematics.speed_raw(-3.0, 1.42, 1) == int(3.0 * 1.42 / 0.01194) + 1024
    assert kinematics.speed_raw(3.0, 1.42, -1) == int(3.0 * 1.42 / 0.01194) + 1024
    assert kinematics.speed_raw(100.0, 1.5, 1) == 1023
    assert kinematics.speed_raw(0.0, 1.5, 1) == 1
    un = kinematics.EncoderUnwrapper(1)
    assert un(np.array([16380]))[0] == 16380
    assert un(np.array([3]))[0] == 16383 + 3  # forward across the wrap
    assert un(np.array([16370]))[0] == 16370  # and back
    # HEAD sign: proximal = zero - counts * scale.
    assert kinematics.proximal_angle(np.array([1000]), np.array([1.0]))[0] == pytest.approx(
        1.0 - 1000 * 2 * math.pi / 16383
    )


def test_close_step_each_finger_on_its_own():
    motor = np.array([1.0, 2.0, 3.5])
    s = close_step(
        motor,
        np.zeros(3),
        np.ones(3, bool),
        ("", "", ""),
        touching=np.array([True, False, False]),
        overloaded=np.array([False, False, False]),
        stalled=np.zeros(3, bool),
        step=0.05,
        limit=3.5,
        backoff=0.05,
    )
    assert s.active.tolist() == [False, True, False]
    assert s.reasons == ("contact", "", "limit")
    assert s.target.tolist() == pytest.approx([1.0, 2.05, 3.5])
    s2 = close_step(
        motor,
        s.target,
        s.active,
        s.reasons,
        np.zeros(3, bool),
        np.array([False, True, False]),
        np.zeros(3, bool),
        0.05,
        3.5,
        0.05,
    )
    assert s2.reasons == ("contact", "overload", "limit")
    assert s2.target[1] == pytest.approx(1.95)  # backed off
    assert s2.target[0] == pytest.approx(1.0)  # a stopped finger keeps its target
