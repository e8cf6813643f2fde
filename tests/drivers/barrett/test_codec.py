"""The BH8 codec against frames written by hand from protocol facts C, and fuzzed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from activetouch.drivers.barrett import codec


def test_ids_from_group_and_node_ids():
    # Host (0) to F1 (11): from bits 9-5 = 0, to bits 4-0 = 11 -> 0x00B.
    assert codec.node_id(11) == 0x00B
    # Host to the hand group: group flag 0x400 | group 5 -> 0x405.
    assert codec.node_id(codec.GROUP_HAND) == 0x405
    # F1 (11 = 0b01011) to property group 6: 0x400 | 11 << 5 (0x160) | 6 -> 0x566.
    assert codec.reply_id(11, codec.FGRP_PROPERTY) == 0x566
    # Spread (14 << 5 = 0x1C0) to position group 3 -> 0x5C3; F3 (13 << 5 = 0x1A0) tact 9 -> 0x5A9.
    assert codec.reply_id(14, codec.FGRP_POSITION) == 0x5C3
    assert codec.reply_id(13, codec.FGRP_TACT_FULL) == 0x5A9
    b = codec.decode_bus_id(0x589)  # F2 (12 << 5 = 0x180) to group 9
    assert (b.src, b.dst, b.group) == (12, 9, True)
    with pytest.raises(codec.FrameError):
        codec.decode_bus_id(0x800)
    with pytest.raises(ValueError):
        codec.encode_bus_id(32, 1)


def test_get_and_set_frames():
    # GET STAT (5): one byte, bit 7 clear.
    assert codec.encode_get(5) == bytes.fromhex("05")
    # SET STAT = 2: 0x80 | 5 = 0x85, 0x00, then 2 as 32-bit little-endian.
    assert codec.encode_set(5, 2) == bytes.fromhex("850002000000")
    # SET CMD (29 = 0x1d) = HI (13 = 0x0d): 0x9d 00 0d 00 00 00.
    assert codec.encode_set(29, 13) == bytes.fromhex("9d000d000000")
    # SET E (52 = 0x34) = 195000 = 0x0002F9B8 -> b8 f9 02 00.
    assert codec.encode_set(52, 195000) == bytes.fromhex("b400b8f90200")
    # SET V (44 = 0x2c) = -1 -> ff ff ff ff (two's complement).
    assert codec.encode_set(44, -1) == bytes.fromhex("ac00ffffffff")
    with pytest.raises(ValueError):
        codec.encode_set(128, 0)
    with pytest.raises(ValueError):
        codec.encode_set(5, 2**32)


def test_property_replies():
    # VERS (0) = 175 = 0xaf in a 6-byte reply: 0x80, 0x00, af 00 00 00.
    assert codec.decode_property(bytes.fromhex("8000af000000")) == (0, 175)
    # ROLE (1) = 0x1805 (tact 0x1000 | strain 0x0800 | BHAND 5), 4-byte reply: 81 00 05 18.
    assert codec.decode_property(bytes.fromhex("81000518")) == (1, 0x1805)
    # SG (25 = 0x19) = -300: 4-byte reply, 16-bit two's complement 0xfed4 -> d4 fe, sign bit set.
    assert codec.decode_property(bytes.fromhex("9900d4fe")) == (25, -300)
    # MODE (8) = 5, six bytes: 88 00 05 00 00 00.
    assert codec.decode_property(bytes.fromhex("880005000000")) == (8, 5)
    for bad, reason in [
        ("05", "length"),
        ("0500020000", "length"),
        ("05000200", "not_set"),
        ("85010200", "byte1"),
    ]:
        with pytest.raises(codec.FrameError) as e:
            codec.decode_property(bytes.fromhex(bad))
        assert e.value.reason == reason


def test_position_replies():
    # 22-bit two's complement, [00MMMMMM][m][L]: 100000 = 0x0186A0 -> 01 86 a0.
    assert codec.decode_position(bytes.fromhex("0186a0")) == (100000, None)
    # -1 = 0x3FFFFF -> 3f ff ff; the top two bits of the first byte are ignored (ff ff ff).
    assert codec.decode_position(bytes.fromhex("3fffff")) == (-1, None)
    assert codec.decode_position(bytes.fromhex("ffffff")) == (-1, None)
    # Primary 195000 = 0x02F9B8, secondary 1200 = 0x0004B0.
    assert codec.decode_position(bytes.fromhex("02f9b80004b0")) == (195000, 1200)
    # Most negative: 0x200000 -> -2**21.
    assert codec.decode_position(bytes.fromhex("200000")) == (-(2**21), None)
    with pytest.raises(codec.FrameError):
        codec.decode_position(bytes.fromhex("0186"))


def test_full_tactile_frame():
    # seq 1 (d0 high nibble) -> cells 5..9. Cells 0x123, 0x456, 0x789, 0xABC, 0xFFF:
    # d0 = 1 << 4 | 0x1 = 0x11, d1 = 0x23 (c0 = (d0 & 0x0F) << 8 | d1 = 0x123);
    # d2 = 0x45, d3 = 0x67 (c1 = d2 << 4 | d3 >> 4 = 0x456; c2 = (d3 & 0x0F) << 8 | d4 = 0x789);
    # d4 = 0x89; d5 = 0xAB, d6 = 0xCF (c3 = 0xABC; c4 = (d6 & 0x0F) << 8 | d7 = 0xFFF); d7 = 0xFF.
    seq, cells = codec.decode_tactile(bytes.fromhex("1123456789abcfff"))
    assert seq == 1
    assert cells.tolist() == [0x123, 0x456, 0x789, 0xABC, 0xFFF]
    with pytest.raises(codec.FrameError) as e:
        codec.decode_tactile(bytes.fromhex("5000000000000000"))  # seq 5 does not exist
    assert e.value.reason == "seq"


def _frame(seq: int, cells: list[int]) -> bytes:
    c = cells
    return bytes(
        [
            (seq << 4) | (c[0] >> 8),
            c[0] & 0xFF,
            c[1] >> 4,
            ((c[1] & 0x0F) << 4) | (c[2] >> 8),
            c[2] & 0xFF,
            c[3] >> 4,
            ((c[3] & 0x0F) << 4) | (c[4] >> 8),
            c[4] & 0xFF,
        ]
    )


def test_full_tactile_set_scaled():
    # Cell k reads raw 256 * (k % 16) -> value k % 16 after the / 256 scaling; a 25th value is
    # sent in seq 4's last slot and dropped (only 24 cells).
    raw = [256 * (k % 16) for k in range(25)]
    asm = codec.TactileAssembler()
    out = None
    for s in range(5):
        out = asm.add(_frame(s, raw[5 * s : 5 * s + 5]))
        if s < 4:
            assert out is None
    assert out is not None and len(out) == 24
    assert out.tolist() == [float(k % 16) for k in range(24)]
    # A hand-written frame for the same seq 0: cells 0, 256, 512, 768, 1024 ->
    # 00 00 | 10 0 | 2 00 | 30 0 | 4 00 -> "00 00 10 02 00 30 04 00".
    assert _frame(0, raw[:5]) == bytes.fromhex("0000100200300400")
    # A lost frame: the set is abandoned and counted; the next full set is complete again.
    asm.add(_frame(0, raw[:5]))
    asm.add(_frame(0, raw[:5]))
    assert asm.incomplete == 1


def test_property_ids_by_firmware():
    new = codec.property_ids(175)
    assert (new.CMD, new.MODE, new.P, new.SG, new.TACT, new.TACTID, new.HOLD) == (
        29,
        8,
        48,
        25,
        106,
        107,
        77,
    )
    assert codec.property_ids(120).HOLD == 94 and codec.property_ids(120).TACT == -1
    assert codec.property_ids(115).V == 106
    assert codec.property_ids(143).TACT == 106 and codec.property_ids(143).TACTID == -1
    assert codec.property_ids(62).CTS == 65
    with pytest.raises(codec.FirmwareError):
        codec.property_ids(40)


def test_finger_conversions():
    cpr = codec.counts_per_rad(4096)
    assert cpr == pytest.approx(4096 / (2 * math.pi))
    # Before breakaway: inner = primary / cpr / 125, outer = inner / 3.
    inner, outer = codec.finger_joints(codec.finger_counts(1.0, cpr), None, cpr)
    assert inner == pytest.approx(1.0, abs=1e-5) and outer == pytest.approx(1 / 3, abs=1e-5)
    # After breakaway: the inner link from the secondary encoder (x50).
    sec = round(0.8 * 50 * cpr)
    inner, outer = codec.finger_joints(round(300 * cpr), sec, cpr)
    assert inner == pytest.approx(0.8, abs=1e-4)
    assert outer == pytest.approx(300 * (1 / 125 + 1 / 375) - 0.8, abs=1e-4)


frames = st.binary(min_size=0, max_size=8)


@settings(max_examples=400, deadline=None)
@given(frames)
def test_fuzz_decode_property(data):
    try:
        prop, value = codec.decode_property(data)
    except codec.FrameError:
        return
    assert 0 <= prop <= 127 and -(2**31) <= value < 2**31


@settings(max_examples=400, deadline=None)
@given(frames)
def test_fuzz_decode_position(data):
    try:
        p, s = codec.decode_position(data)
    except codec.FrameError:
        return
    assert -(2**21) <= p < 2**21 and (s is None or -(2**21) <= s < 2**21)


@settings(max_examples=400, deadline=None)
@given(frames)
def test_fuzz_decode_tactile(data):
    try:
        seq, cells = codec.decode_tactile(data)
    except codec.FrameError:
        return
    assert 0 <= seq <= 4 and np.all((cells >= 0) & (cells <= 4095))


@settings(max_examples=300, deadline=None)
@given(st.lists(frames, max_size=12))
def test_fuzz_tactile_assembler(seq):
    asm = codec.TactileAssembler()
    for data in seq:
        try:
            out = asm.add(data)
        except codec.FrameError:
            continue
        if out is not None:
            assert out.shape == (24,) and np.all((out >= 0) & (out <= codec.TACT_MAX))


@settings(max_examples=400, deadline=None)
@given(st.integers(min_value=-(2**16), max_value=2**16))
def test_fuzz_decode_bus_id(arb):
    try:
        b = codec.decode_bus_id(arb)
    except codec.FrameError:
        return
    assert 0 <= b.src <= 31 and 0 <= b.dst <= 31
