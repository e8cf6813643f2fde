"""ROS 1 wire format, md5 sums and bridge keys, against hand-built bytes and known values."""

from __future__ import annotations

import contextlib
import hashlib
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from activetouch.drivers.baxter import ros1
from activetouch.emulators import baxter_bridge as emu
from activetouch.errors import ConfigError, MessageError
from tests.drivers.baxter import handbuilt as hb

# The texts genmsg hashes (shared/protocol-facts.md A.1), hashed here with hashlib.
HASHED = {
    ros1.JOINT_COMMAND: "int32 POSITION_MODE=1\nint32 VELOCITY_MODE=2\nint32 TORQUE_MODE=3\n"
    "int32 RAW_POSITION_MODE=4\nint32 mode\nfloat64[] command\nstring[] names",
    ros1.JOINT_STATE: "2176decaecbce78abc3b96ef049fabed header\nstring[] name\n"
    "float64[] position\nfloat64[] velocity\nfloat64[] effort",
    ros1.ASSEMBLY_STATE: "uint8 ESTOP_BUTTON_UNPRESSED=0\nuint8 ESTOP_BUTTON_PRESSED=1\n"
    "uint8 ESTOP_BUTTON_UNKNOWN=2\nuint8 ESTOP_BUTTON_RELEASED=3\nuint8 ESTOP_SOURCE_NONE=0\n"
    "uint8 ESTOP_SOURCE_USER=1\nuint8 ESTOP_SOURCE_UNKNOWN=2\nuint8 ESTOP_SOURCE_FAULT=3\n"
    "uint8 ESTOP_SOURCE_BRAIN=4\nbool ready\nbool enabled\nbool stopped\nbool error\n"
    "uint8 estop_button\nuint8 estop_source",
    ros1.BOOL: "bool data",
    ros1.EMPTY: "",
    ros1.FLOAT64: "float64 data",
}
FACTS_MD5 = {
    ros1.JOINT_COMMAND: "19bfec8434dd568ab3c633d187c36f2e",
    ros1.JOINT_STATE: "3066dcd76a6cfaef579bd0f34173e9fd",
    ros1.ASSEMBLY_STATE: "356d9dd237ce73b2667da9235f541933",
    ros1.BOOL: "8b94c1b53db61fb6aed406028ad6332a",
    ros1.EMPTY: "d41d8cd98f00b204e9800998ecf8427e",
    ros1.FLOAT64: "fdb28210bfa9d7c91146260178d9a584",
}


@pytest.fixture(scope="module")
def codec() -> ros1.Ros1Codec:
    return ros1.Ros1Codec()  # raises if rosbags derives another md5 from the .msg texts


def test_md5_sums_match_the_facts_and_genmsg_texts() -> None:
    for t, text in HASHED.items():
        assert hashlib.md5(text.encode()).hexdigest() == FACTS_MD5[t] == ros1.MD5[t], t
    assert {t: md5 for t, (_, md5) in ((v[0], v) for v in emu._TYPES.values())} == {
        t: ros1.MD5[t] for t in ros1.MD5
    }


def test_codec_refuses_a_wrong_md5(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(ros1.MD5, ros1.JOINT_COMMAND, "0" * 32)
    with pytest.raises(ConfigError, match="JointCommand"):
        ros1.Ros1Codec()


def test_joint_command_bytes(codec: ros1.Ros1Codec) -> None:
    # vector from shared/protocol-facts.md A.1, and again from the hand-built packer
    facts = bytes.fromhex(
        "01000000 02000000 9a9999999999b93f 9a9999999999c9bf 02000000 07000000 6c6566745f7330 "
        "07000000 6c6566745f7331".replace(" ", "")
    )
    got = codec.joint_command(("left_s0", "left_s1"), np.array([0.1, -0.2]))
    assert got == facts == hb.joint_command(1, [0.1, -0.2], ["left_s0", "left_s1"])
    assert len(got) == 50


def test_scalar_bytes(codec: ros1.Ros1Codec) -> None:
    assert codec.bool(True) == b"\x01" and codec.bool(False) == b"\x00"
    assert codec.empty() == b""
    assert codec.float64(0.2) == struct.pack("<d", 0.2)


def test_parse_joint_state_filters_the_side(codec: ros1.Ros1Codec) -> None:
    names = ["head_pan", *(f"right_{j}" for j in ros1.JOINTS), *(f"left_{j}" for j in ros1.JOINTS)]
    pos = [9.0] + [-float(i) for i in range(7)] + [0.1 * i for i in range(7)]
    vel = [0.0] * 8 + [0.01 * i for i in range(7)]
    msg = codec.parse_joint_state(hb.joint_state(names, pos, vel))
    assert msg.names == tuple(names)
    assert msg.stamp == pytest.approx(1700000000.5)
    q, v = msg.select(ros1.joint_names("left"))
    np.testing.assert_allclose(q, [0.1 * i for i in range(7)])
    np.testing.assert_allclose(v, [0.01 * i for i in range(7)])
    q, _ = msg.select(ros1.joint_names("right"))
    np.testing.assert_allclose(q, [-float(i) for i in range(7)])
    assert msg.select(("left_s0", "nope")) is None


def test_parse_assembly_state(codec: ros1.Ros1Codec) -> None:
    st_ = codec.parse_robot_state(hb.assembly_state())
    assert st_.enabled and st_.ready and not st_.stopped and st_.describe() == "enabled"
    st_ = codec.parse_robot_state(hb.assembly_state(0, 0, 1, 0, 1, 1))
    assert st_.stopped and "user" in st_.describe() and "pressed" in st_.describe()
    assert codec.parse_robot_state(bytes.fromhex("010100000000")).enabled  # facts vector


@pytest.mark.parametrize("cut", [1, 5, 20])
def test_truncated_and_padded_messages_are_errors(codec: ros1.Ros1Codec, cut: int) -> None:
    raw = hb.joint_state(["left_s0"], [0.5], [0.0])
    with pytest.raises(MessageError):
        codec.parse_joint_state(raw[:-cut])
    with pytest.raises(MessageError):
        codec.parse_joint_state(raw + b"\x00" * cut)
    with pytest.raises(MessageError):
        codec.parse_robot_state(hb.assembly_state()[: 6 - min(cut, 6)] if cut < 6 else b"")


def test_bridge_keys() -> None:
    topic = "/robot/limb/left/joint_command"
    facts = (
        "6261787465725f636f72655f6d7367732f4a6f696e74436f6d6d616e64/"
        "19bfec8434dd568ab3c633d187c36f2e/*/robot/limb/left/joint_command"
    )
    assert ros1.bridge_key(ros1.JOINT_COMMAND, topic, "*", "namespaced") == facts
    assert ros1.bridge_key(ros1.JOINT_COMMAND, topic, "lab", "namespaced") == facts.replace(
        "/*/", "/lab/"
    )
    legacy = ros1.bridge_key(ros1.JOINT_COMMAND, topic, "*", "legacy")
    assert legacy == facts.replace("/*/", "/")
    assert emu.key("JointCommand", topic) == facts
    assert emu.key("JointCommand", topic, legacy=True) == legacy
    for bad in ("a/b", "", "a*", "x y", "$x"):
        with pytest.raises(ConfigError):
            ros1.bridge_key(ros1.JOINT_COMMAND, topic, bad, "namespaced")
    with pytest.raises(ConfigError):
        ros1.bridge_key(ros1.JOINT_COMMAND, topic, "*", "v2")
    with pytest.raises(ConfigError):
        ros1.joint_names("middle")


# ----------------------------------------------------------------- cross-checks and fuzzing

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
names_st = st.lists(st.text(max_size=12), max_size=8)


@settings(max_examples=200, deadline=None)
@given(cmd=st.lists(finite, max_size=8), data=st.data())
def test_driver_commands_parse_in_the_emulator(cmd: list[float], data: st.DataObject) -> None:
    names = data.draw(st.lists(st.text(max_size=10), min_size=len(cmd), max_size=len(cmd)))
    raw = _CODEC.joint_command(tuple(names), np.array(cmd))
    mode, command, got_names = emu.parse_joint_command(raw)
    assert mode == 1 and got_names == names and command == cmd
    assert raw == hb.joint_command(1, cmd, names)


@settings(max_examples=200, deadline=None)
@given(n=st.integers(0, 6), data=st.data())
def test_emulator_states_parse_in_the_driver(n: int, data: st.DataObject) -> None:
    names = data.draw(st.lists(st.text(max_size=10), min_size=n, max_size=n))
    pos = data.draw(st.lists(finite, min_size=n, max_size=n))
    stamp = data.draw(st.floats(0, 4e9))
    raw = emu.pack_joint_state(3, stamp, names, pos, pos, pos)
    msg = _CODEC.parse_joint_state(raw)
    assert list(msg.names) == names and list(msg.position) == pos
    assert math.isclose(msg.stamp, stamp, abs_tol=2e-6 * max(1.0, stamp / 1e6))
    flags = data.draw(st.lists(st.integers(0, 1), min_size=4, max_size=4))
    b, s = data.draw(st.integers(0, 3)), data.draw(st.integers(0, 4))
    rs = _CODEC.parse_robot_state(emu.pack_assembly_state(*flags, b, s))
    assert (rs.ready, rs.enabled, rs.stopped, rs.error) == tuple(map(bool, flags))
    assert (rs.estop_button, rs.estop_source) == (b, s)


_CODEC = ros1.Ros1Codec()


@settings(max_examples=400, deadline=None)
@given(raw=st.binary(max_size=200))
def test_driver_decoders_fuzz(raw: bytes) -> None:
    for parse in (_CODEC.parse_joint_state, _CODEC.parse_robot_state, _CODEC.parse_joint_command):
        with contextlib.suppress(MessageError):
            parse(raw)


@settings(max_examples=400, deadline=None)
@given(raw=st.binary(max_size=200))
def test_emulator_decoders_fuzz(raw: bytes) -> None:
    for parse in (
        emu.parse_joint_command,
        lambda r: emu.parse_scalar(r, "<B"),
        lambda r: emu.parse_scalar(r, "<d"),
    ):
        with contextlib.suppress(emu.WireError):
            parse(raw)


@settings(max_examples=200, deadline=None)
@given(
    cmd=st.lists(finite, max_size=5),
    names=st.lists(st.text(max_size=6), max_size=5),
    cut=st.integers(1, 40),
)
def test_corrupted_commands_never_crash_either_side(cmd, names, cut) -> None:
    raw = hb.joint_command(1, cmd, names)
    for bad in (raw[:-cut] if cut <= len(raw) else b"", raw + b"\x01" * cut):
        with pytest.raises(emu.WireError):
            emu.parse_joint_command(bad)
        with pytest.raises(MessageError):
            _CODEC.parse_joint_command(bad)
