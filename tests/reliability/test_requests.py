"""Admission limits of `decode` (issue 16, findings 2 and 8): bounded numbers, payload size,
string lengths, nesting depth, duplicate keys, and one short line per error."""

from __future__ import annotations

import json

import pytest

from activetouch.errors import MessageError
from activetouch.transport.messages import (
    MAX_DEPTH,
    MAX_ERROR_TEXT,
    MAX_HORIZON,
    MAX_MOVES,
    MAX_PAYLOAD,
    MAX_SEED,
    MAX_SIMULATIONS,
    EStopRequest,
    ExecuteRequest,
    RecognizeRequest,
    Reply,
    Status,
    decode,
    encode,
)

BASE = {"v": 1, "policy": "tree", "max_moves": 2, "seed": 3, "object": "cup"}
# Longest text an error may have: a prefix, a field path and a clipped value.
MAX_LINE = 2 * MAX_ERROR_TEXT + 200


def req(**fields: object) -> bytes:
    return json.dumps({**BASE, **fields}).encode()


def refused(data: bytes, type_: object = RecognizeRequest) -> MessageError:
    with pytest.raises(MessageError) as info:
        decode(data, type_)
    text = str(info.value)
    assert "\n" not in text and len(text) <= MAX_LINE, text[:500]
    return info.value


def test_config_defaults_are_within_bounds() -> None:
    # planner.simulations 200, planner.horizon 5, session.max_moves 20: far inside
    assert MAX_SIMULATIONS >= 100 * 200 and MAX_HORIZON >= 10 * 5 and MAX_MOVES >= 50 * 20
    ok = decode(
        req(simulations=MAX_SIMULATIONS, horizon=MAX_HORIZON, max_moves=MAX_MOVES, seed=MAX_SEED),
        RecognizeRequest,
    )
    assert (ok.simulations, ok.horizon, ok.max_moves, ok.seed) == (
        MAX_SIMULATIONS,
        MAX_HORIZON,
        MAX_MOVES,
        MAX_SEED,
    )


@pytest.mark.parametrize(
    ("field", "value", "bound"),
    [
        ("simulations", 3_000_000, str(MAX_SIMULATIONS)),  # froze the daemon for a minute
        ("simulations", 10**10, str(MAX_SIMULATIONS)),  # 74.5 GiB allocation after a grasp
        ("simulations", MAX_SIMULATIONS + 1, str(MAX_SIMULATIONS)),
        ("horizon", 2**63, str(MAX_HORIZON)),
        ("horizon", MAX_HORIZON + 1, str(MAX_HORIZON)),
        ("max_moves", 2**64, str(MAX_MOVES)),
        ("max_moves", MAX_MOVES + 1, str(MAX_MOVES)),
        ("seed", 2**64, str(MAX_SEED)),
        ("seed", 2**63, str(MAX_SEED)),
    ],
)
def test_over_bound_numbers_are_refused(field: str, value: int, bound: str) -> None:
    e = refused(req(**{field: value}))
    assert e.field == field
    assert f"`{field}`" in str(e) and bound in str(e)


def test_payload_size_is_capped() -> None:
    big = req(session_id="a" * 100) + b" " * MAX_PAYLOAD  # valid JSON, only too large
    assert "exceeds" in str(refused(big))


def test_trajectories_may_be_larger() -> None:
    n = 1500  # 15 s at 100 Hz, 7 joints, positions and velocities: well over 64 KiB
    traj = {
        "names": [f"j{i}" for i in range(7)],
        "times": [i * 0.01 for i in range(n)],
        "positions": [[0.123456789] * 7] * n,
        "velocities": [[0.123456789] * 7] * n,
    }
    data = json.dumps({"v": 1, "trajectory": traj}).encode()
    assert len(data) > MAX_PAYLOAD
    assert len(decode(data, ExecuteRequest).trajectory.times) == n


@pytest.mark.parametrize("field", ["policy", "object", "session_id"])
def test_long_strings_are_refused_and_not_echoed(field: str) -> None:
    e = refused(req(**{field: "x" * 60_000}))
    assert str(e).count("x") < MAX_ERROR_TEXT + 50


def test_long_estop_reason_is_refused() -> None:
    assert "1000" in str(refused(json.dumps({"v": 1, "reason": "r" * 5000}).encode(), EStopRequest))


def test_control_characters_are_escaped_in_errors() -> None:
    e = refused(req(policy="\x1b[31m\x00evil"))
    assert "\x1b" not in str(e) and "\x00" not in str(e) and "\\x1b" in str(e)


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 1000, 10_000])
def test_deep_nesting_is_refused_without_recursion_error(depth: int) -> None:
    for data in (b"[" * depth + b"]" * depth, b'{"a":' * depth + b"1" + b"}" * depth):
        assert "nested" in str(refused(data))
    nested = b'{"v":1,"policy":"tree","max_moves":2,"x":' + b"[" * depth + b"]" * depth + b"}"
    assert "nested" in str(refused(nested))


def test_deep_trajectory_meta_is_refused() -> None:
    # `meta` is free-form and the trajectory cap is large: 500,000 levels fit in it.
    deep = b"[" * 500_000 + b"]" * 500_000
    data = b'{"v":1,"trajectory":{"names":["a"],"times":[0],"positions":[[0]],"meta":{"m":'
    assert "nested" in str(refused(data + deep + b"}}}", ExecuteRequest))


def test_brackets_inside_strings_do_not_count_as_nesting() -> None:
    ok = decode(req(session_id="[" * 150 + "{" * 40), RecognizeRequest)
    assert ok.session_id.startswith("[[")


@pytest.mark.parametrize(
    "data",
    [
        b'{"v":2,"v":1,"policy":"tree","max_moves":2}',
        b'{"v":1,"v":2,"policy":"tree","max_moves":2}',
        b'{"v":1,"v":1,"policy":"tree","max_moves":2}',
        b'{"v":1,"policy":"tree","max_moves":2,"max_moves":3}',
    ],
)
def test_duplicate_keys_are_refused_whatever_their_order(data: bytes) -> None:
    assert "duplicate key" in str(refused(data))


def test_duplicate_keys_are_refused_in_nested_objects() -> None:
    st = b'{"v":1,"robot":"r","nodes":{"hand":{"alive":true,"alive":false}},"model_loaded":true}'
    assert "duplicate key `alive`" in str(refused(st, Status))


def test_long_failures_stay_decodable() -> None:
    # A node's own long error text is cut on the way out, so the peer can still read it.
    env = Reply.failure(RuntimeError("y" * 100_000))
    back = decode(encode(env), Reply[Status])
    assert not back.ok and back.error.endswith("(truncated)")


def test_malformed_requests_get_one_short_line() -> None:
    # A small fuzz: every hostile variant gets a bounded one-line MessageError, nothing else.
    values = [
        None,
        True,
        -1,
        0,
        1.5,
        2**70,
        -(2**70),
        1e308,
        "",
        "x" * 70_000,
        [],
        {},
        [1] * 10,
        {"a": 1},
        "\x00\x1b",
        "\ud800",
    ]
    fields = [
        "v",
        "policy",
        "max_moves",
        "seed",
        "object",
        "horizon",
        "simulations",
        "session_id",
        "extra",
    ]
    n = 0
    for f in fields:
        for val in values:
            try:
                data = json.dumps({**BASE, f: val}).encode()
            except ValueError:
                continue
            try:
                decode(data, RecognizeRequest)
            except MessageError as e:
                assert "\n" not in str(e) and len(str(e)) <= MAX_LINE
            n += 1
    for raw in (b"{", b"}", b"[]", b"null", b'"v"', b"\xff\xfe", b'{"v":1,}', b"1" * 100):
        refused(raw)
        n += 1
    assert n >= 100
