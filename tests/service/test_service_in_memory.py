"""The recognition service's admission, queue, cancel and e-stop without Zenoh or
subprocesses: the fake devices called directly, queries handed in by `submit`."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import msgspec

from activetouch import paths
from activetouch.config import load_config
from activetouch.daemon.links import local_links
from activetouch.daemon.recognition_service import RecognitionService
from activetouch.devices import make_devices
from activetouch.transport.keys import Keys
from activetouch.transport.messages import RecognizeRequest
from tests.conftest import SMALL_OBJECTS

ROBOT = "memory"


class Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class FakeQuery:
    """What the service uses of a zenoh.Query; records the reply."""

    def __init__(self, body: bytes | msgspec.Struct, timeout: float | None = None) -> None:
        data = body if isinstance(body, bytes) else msgspec.json.encode(body)
        self.payload = Payload(data) if data else None
        self.parameters = {"timeout": str(timeout)} if timeout else {}
        self.reply_json: dict | None = None
        self.ok: bool | None = None
        self.done = threading.Event()

    def reply(self, _key: str, data: bytes, encoding=None) -> None:
        self.ok, self.reply_json = True, json.loads(data)

    def reply_err(self, data: bytes, encoding=None) -> None:
        self.ok, self.reply_json = False, json.loads(data)

    def __enter__(self) -> FakeQuery:
        return self

    def __exit__(self, *exc: object) -> None:
        self.done.set()


def _service(home: Path, *overrides: str) -> tuple[RecognitionService, object]:
    cfg = load_config(None, ["hand.type=fake", "arm.type=fake", *overrides])
    devices = make_devices(cfg, home)
    svc = RecognitionService(
        None, ROBOT, "sim", cfg, paths.default_model(home), home, links=local_links(devices)
    )
    svc.start(0.0)
    return svc, devices


def _wait(q: FakeQuery, timeout: float = 60.0) -> dict:
    assert q.done.wait(timeout), "no reply"
    assert q.reply_json is not None
    return q.reply_json


def test_recognize_busy_queue_cancel_and_estop_in_memory(trained_home: Path) -> None:
    svc, devices = _service(
        trained_home, "hand.close_s=0.2", "session.stable_grasps=1000", "service.max_queued=1"
    )
    k = Keys(ROBOT)
    try:
        req = RecognizeRequest(policy="tree", max_moves=30, seed=1, object="cup")
        first, second, third = FakeQuery(req), FakeQuery(req), FakeQuery(req)
        svc.submit(k.recognize, first)
        while devices.hand.closes < 1:
            time.sleep(0.01)
        svc.submit(k.recognize, second)  # queued (max_queued = 1)
        svc.submit(k.recognize, third)  # busy
        assert _wait(third)["error_type"] == "BusyError"
        status = FakeQuery(b"")
        svc.submit(k.status, status)
        assert _wait(status)["result"]["queued"] == 1
        stop = FakeQuery(b"")
        svc.submit(k.estop, stop)
        assert _wait(stop)["result"]["arm_stopped"] is True
        assert devices.hand.stop_latch.is_set and devices.arm.stop_latch.is_set
        aborted = _wait(first)
        assert aborted["error_type"] == "RecognitionAbortedError", aborted
        assert _wait(second)["error_type"] == "RecognitionAbortedError"  # dropped from the queue
        # The next request is the go-ahead: it clears the stops and runs.
        nxt = FakeQuery(RecognizeRequest(policy="random", max_moves=2, seed=2, object="cup"))
        devices.hand.cfg.close_s = 0.0
        svc.submit(k.recognize, nxt)
        assert _wait(nxt)["result"]["moves"] == 2
        assert not devices.hand.stop_latch.is_set
    finally:
        svc.close()
        devices.close()


def test_bad_requests_are_refused_before_anything_moves(trained_home: Path) -> None:
    svc, devices = _service(trained_home)
    k = Keys(ROBOT)
    try:
        for body in (
            b"{",
            b'{"v":1,"policy":"tree","max_moves":2,"seed":3,"object":"cup","simulations":3000000}',
            b'{"v":1,"policy":"tree","max_moves":2}',  # no object on a simulated robot
        ):
            q = FakeQuery(body)
            svc.submit(k.recognize, q)
            assert _wait(q)["error_type"] == "MessageError", body
        assert devices.hand.closes == 0 and devices.arm.executed == 0
    finally:
        svc.close()
        devices.close()


def test_the_result_reports_the_wrists_robot_seconds(trained_home: Path) -> None:
    """RecognizeResult.motion_s is the devices' wrist robot seconds over the recognition (the
    service reads them through the session's wrapped wrist); grasp_s the hand's time."""
    svc, devices = _service(trained_home, "hand.close_s=0.01")
    k = Keys(ROBOT)
    try:
        devices.wrist.robot_seconds = 100.0  # earlier motions: not this recognition's
        q = FakeQuery(RecognizeRequest(policy="random", max_moves=3, seed=4, object="cup"))
        svc.submit(k.recognize, q)
        res = _wait(q)["result"]
        moved = devices.wrist.robot_seconds - 100.0
        assert res["moves"] >= 1 and moved > 0
        assert abs(res["motion_s"] - moved) < 1e-9
        assert res["motion_planning_s"] == 0.0  # the fake's floating wrist plans nothing
        assert 0.01 * res["moves"] <= res["grasp_s"] < res["elapsed_s"]
    finally:
        svc.close()
        devices.close()


def test_the_service_recognises_on_the_grasp_likelihood_belief(trained_home: Path) -> None:
    """recognition.belief=grasp_likelihood reaches the daemon's sessions and planner."""
    svc, devices = _service(trained_home, "recognition.belief=grasp_likelihood")
    k = Keys(ROBOT)
    try:
        q = FakeQuery(RecognizeRequest(policy="tree", max_moves=3, seed=4, object="cup"))
        svc.submit(k.recognize, q)
        res = _wait(q)["result"]
        assert res["moves"] == 3
        assert res["label"] in SMALL_OBJECTS and 0.0 < res["probability"] <= 1.0
    finally:
        svc.close()
        devices.close()
