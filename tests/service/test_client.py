"""A plain eclipse-zenoh client, importing nothing from activetouch, against the daemon.

Raw JSON payloads as docs/api.md describes them: a recognition with progress and a result
equal to the in-process run of the same seed; malformed requests get error replies naming the
problem, and the daemon goes on serving. The daemon is a subprocess on 127.0.0.1 only,
scouting off, stopped by SIGTERM to its own pid."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

ROBOT = "plainbot"
PREFIX = f"activetouch/{ROBOT}"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def open_plain_session(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(conf)


def ask(session: zenoh.Session, key: str, payload: bytes | None, timeout: float = 10.0) -> dict:
    """One query; the daemon's JSON envelope (ok / result / error)."""
    replies = list(session.get(key, payload=payload, timeout=timeout))
    assert len(replies) == 1, f"{len(replies)} replies to {key}"
    r = replies[0]
    sample = r.ok if r.ok is not None else r.err
    return json.loads(sample.payload.to_bytes())


@pytest.fixture(scope="module")
def daemon(trained_home: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    log = tmp_path_factory.mktemp("plain") / "daemon.log"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NOTIFY_", "WATCHDOG_"))}
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "activetouch",
                "serve",
                "--sim",
                "--data",
                str(trained_home),
                "--robot",
                ROBOT,
                "--listen",
                endpoint,
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
        )
        try:
            wait_for_daemon(endpoint, proc, log)
            yield endpoint
            os.kill(proc.pid, signal.SIGTERM)
            assert proc.wait(5.0) == 0, log.read_text()
        finally:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait(10)


def wait_for_daemon(endpoint: str, proc: subprocess.Popen, log: Path) -> None:
    """Until the daemon's liveliness token shows (it is declared once everything serves)."""
    with open_plain_session(endpoint) as s:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()
            if list(s.liveliness().get(f"{PREFIX}/alive/daemon", timeout=1.0)):
                return
            time.sleep(0.2)
    raise AssertionError(f"the daemon did not come up:\n{log.read_text()}")


@pytest.fixture
def session(daemon: str) -> Iterator[zenoh.Session]:
    with open_plain_session(daemon) as s:
        yield s


def recognize(session: zenoh.Session, request: dict[str, Any]) -> tuple[dict, list[dict]]:
    """A recognition with its progress samples (subscribed before asking)."""
    progress: list[dict] = []
    lock = threading.Lock()

    def on_progress(sample: zenoh.Sample) -> None:
        with lock:
            progress.append(json.loads(sample.payload.to_bytes()))

    def mine() -> list[dict]:
        with lock:
            return [p for p in progress if p["session_id"] == request.get("session_id")]

    sub = session.declare_subscriber(f"{PREFIX}/progress", on_progress)
    try:
        # A recognition outlasts Zenoh's default 10 s query timeout: say how long to wait.
        reply = ask(session, f"{PREFIX}/recognize", json.dumps(request).encode(), timeout=120.0)
        # The subscriber's callback runs on its own thread: the last sample, published just
        # before the reply, may still be on its way. The result says how many to expect.
        if reply["ok"]:
            deadline = time.monotonic() + 5.0
            while len(mine()) < reply["result"]["moves"] and time.monotonic() < deadline:
                time.sleep(0.01)
    finally:
        sub.undeclare()
    return reply, mine()


def in_process(home: Path, obj: str, seed: int, policy: str) -> dict:
    """`activetouch recognize --json` in its own process (nothing imported here)."""
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "activetouch",
            "recognize",
            "--data",
            str(home),
            "--object",
            obj,
            "--seed",
            str(seed),
            "--policy",
            policy,
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return json.loads(out.stdout)


def test_plain_client_gets_progress_and_the_in_process_result(
    session: zenoh.Session, trained_home: Path
) -> None:
    request = {
        "v": 1,
        "policy": "tree",
        "max_moves": 10,
        "seed": 4,
        "object": "sphere",
        "session_id": "plain-1",
    }
    reply, progress = recognize(session, request)
    assert reply["ok"], reply
    res = reply["result"]
    assert res["session_id"] == "plain-1"
    assert res["object"] == "sphere" and res["seed"] == 4 and res["policy"] == "tree"
    # One progress sample per grasp, in order, the last one agreeing with the result.
    assert [p["move"] for p in progress] == list(range(1, res["moves"] + 1))
    assert [p["pose_id"] for p in progress] == res["pose_ids"]
    assert [p["top3"][0][0] for p in progress] == res["labels"]
    assert progress[-1]["top3"][0][1] == pytest.approx(res["probability"])
    assert all(sum(pr for _l, pr in p["top3"]) <= 1.0 + 1e-9 for p in progress)
    # The same recognition as in-process: same seed, same grasps, same answer.
    local = in_process(trained_home, "sphere", 4, "tree")
    for key in ("label", "labels", "pose_ids", "moves", "skipped", "stop_reason"):
        assert res[key] == local[key], key
    assert res["probability"] == pytest.approx(local["probability"], abs=1e-9)


def test_status_with_a_plain_client(session: zenoh.Session) -> None:
    st = ask(session, f"{PREFIX}/status", None)
    assert st["ok"], st
    r = st["result"]
    assert r["robot"] == ROBOT and r["model_loaded"] and r["session"] is None
    assert all(n["alive"] for n in r["nodes"].values())
    assert set(r["nodes"]) == {"daemon", "hand", "arm", "sim"}


VALID = {"v": 1, "policy": "greedy", "max_moves": 3, "seed": 1, "object": "cup"}


@pytest.mark.parametrize(
    ("payload", "error_type", "expected"),
    [
        (b"this is not json", "MessageError", "not valid JSON"),
        (b"", "MessageError", "empty payload"),
        (b"[1, 2, 3]", "MessageError", "invalid RecognizeRequest"),
        ({**VALID, "max_moves": "three"}, "MessageError", "field `max_moves`: Expected `int`"),
        ({**VALID, "seed": 1.5}, "MessageError", "field `seed`"),
        ({**VALID, "object": 7}, "MessageError", "field `object`: Expected `str | null`"),
        ({**VALID, "max_moves": -2}, "MessageError", "field `max_moves`: Expected `int` >= 1"),
        ({**VALID, "policy": "best"}, "MessageError", "field `policy`: Invalid enum value 'best'"),
        ({**VALID, "object": "teapotx"}, "DataError", "unknown object 'teapotx'"),
        ({**VALID, "object": None}, "MessageError", "field `object`: the twin needs the object"),
        ({**VALID, "max_move": 3}, "MessageError", "unknown field `max_move`"),
        ({**VALID, "v": 2}, "MessageError", "schema version 2 is not supported"),
        ({k: v for k, v in VALID.items() if k != "v"}, "MessageError", "field `v`: missing"),
    ],
)
def test_malformed_requests_get_errors_and_the_daemon_goes_on(
    session: zenoh.Session, payload: Any, error_type: str, expected: str
) -> None:
    data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
    reply = ask(session, f"{PREFIX}/recognize", data)
    assert reply["ok"] is False
    assert reply["error_type"] == error_type
    assert expected in reply["error"], reply["error"]
    # Still serving, and idle.
    st = ask(session, f"{PREFIX}/status", None)
    assert st["ok"] and st["result"]["session"] is None


def test_a_valid_request_after_the_bad_ones(session: zenoh.Session) -> None:
    for bad in (b"{", b'{"v":1,"policy":"tree","max_moves":0,"object":"cup"}'):
        assert not ask(session, f"{PREFIX}/recognize", bad)["ok"]
    reply, progress = recognize(session, {**VALID, "session_id": "after-bad"})
    assert reply["ok"], reply
    assert len(progress) == reply["result"]["moves"] >= 1


def test_cancel_and_estop_with_empty_payloads(session: zenoh.Session) -> None:
    res = ask(session, f"{PREFIX}/cancel", None)
    assert res == {
        "v": 1,
        "ok": True,
        "result": {"v": 1, "cancelled": False, "session_id": None},
        "error": None,
        "error_type": None,
        "error_bases": [],
    }
    res = ask(session, f"{PREFIX}/estop", b'{"v":1,"reason":"plain client"}')
    assert res["ok"] and res["result"]["arm_stopped"] and res["result"]["hand_opened"]
    bad = ask(session, f"{PREFIX}/cancel", b'{"v":1,"session":"x"}')
    assert not bad["ok"] and "unknown field `session`" in bad["error"]
