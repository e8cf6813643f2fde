"""ROS 1 byte vectors built by hand in the tests, from the message definitions alone
(independent of both the driver's rosbags codec and the emulator's packer)."""

from __future__ import annotations

import struct

import numpy as np


def ros_string(s: str) -> bytes:
    b = s.encode()
    return len(b).to_bytes(4, "little") + b


def joint_state(
    names: list[str],
    pos: list[float],
    vel: list[float],
    seq: int = 7,
    stamp_ns: int = 1_700_000_000_500_000_000,
) -> bytes:
    # Header: uint32 seq, time (uint32 sec, uint32 nsec), string frame_id
    sec, nsec = divmod(stamp_ns, 10**9)
    out = struct.pack("<III", seq, sec, nsec) + ros_string("base")
    out += len(names).to_bytes(4, "little") + b"".join(ros_string(n) for n in names)
    for arr in (pos, vel, [0.0] * len(names)):
        out += len(arr).to_bytes(4, "little") + b"".join(struct.pack("<d", x) for x in arr)
    return out


def assembly_state(ready=1, enabled=1, stopped=0, error=0, button=0, source=0) -> bytes:
    return bytes([ready, enabled, stopped, error, button, source])


def joint_command(mode: int, command: list[float], names: list[str]) -> bytes:
    out = struct.pack("<i", mode) + len(command).to_bytes(4, "little")
    out += b"".join(struct.pack("<d", x) for x in command)
    return out + len(names).to_bytes(4, "little") + b"".join(ros_string(n) for n in names)


def parse_joint_command(raw: bytes) -> tuple[int, np.ndarray, list[str]]:
    """The test's own JointCommand parser (strict: no trailing bytes)."""
    mode, n = struct.unpack_from("<iI", raw, 0)
    at = 8
    cmd = np.frombuffer(raw, dtype="<f8", count=n, offset=at)
    at += 8 * n
    (m,) = struct.unpack_from("<I", raw, at)
    at += 4
    names = []
    for _ in range(m):
        (ln,) = struct.unpack_from("<I", raw, at)
        names.append(raw[at + 4 : at + 4 + ln].decode())
        at += 4 + ln
    assert at == len(raw), "trailing bytes"
    return mode, cmd.copy(), names


def bridge_key(ros_type: str, md5: str, topic: str, ns: str | None = "*") -> str:
    parts = [ros_type.encode().hex(), md5] + ([ns] if ns is not None else []) + [topic.lstrip("/")]
    return "/".join(parts)
