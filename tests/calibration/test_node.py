"""`calibrate/<kind>` served by CalibrationNode on the twin's devices, over loopback Zenoh."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from activetouch.daemon.calibration_node import (
    CalibrateRequest,
    CalibrateResult,
    CalibrationNode,
    calibrate_key,
)
from activetouch.transport.keys import Keys
from activetouch.transport.messages import Reply, decode, encode
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint

ROBOT = "calbot"


@pytest.fixture(scope="module")
def twin_devices(tmp_path_factory) -> Iterator:
    from activetouch.config import load_config
    from activetouch.devices import make_devices
    from activetouch.objects.library import ObjectLibrary

    root = tmp_path_factory.mktemp("home")
    ObjectLibrary.in_data_dir(root).ensure_builtins(["sphere"])
    cfg = load_config(None, ["hand.type=twin", "arm.type=twin-floating"])
    devices = make_devices(cfg, root)
    yield devices
    devices.close()


@pytest.fixture
def served(twin_devices) -> Iterator[ZenohSession]:
    ep = loopback_endpoint()
    with ZenohSession(ZenohSettings(listen=(ep,))) as node_zs:
        node_zs.closing(CalibrationNode(twin_devices, node_zs.session, ROBOT))
        with ZenohSession(ZenohSettings.client(ep)) as client:
            yield client


def ask(client: ZenohSession, kind: str, req: CalibrateRequest | None, timeout: float = 60.0):
    payload = encode(req) if req is not None else b'{"v": 1, "bogus": 1}'
    key = calibrate_key(Keys(ROBOT), kind)
    [r] = list(client.session.get(key, payload=payload, timeout=timeout))
    sample = r.ok if r.ok is not None else r.err
    return decode(sample.payload.to_bytes(), Reply[CalibrateResult])


def test_keys():
    assert calibrate_key(Keys("r1"), "object") == "activetouch/r1/calibrate/object"
    with pytest.raises(Exception, match="unknown calibration kind"):
        calibrate_key(Keys("r1"), "everything")


def test_object_needs_a_name_and_bad_requests_are_refused(served):
    reply = ask(served, "object", CalibrateRequest(store=False))
    assert not reply.ok and "name the object" in reply.error
    reply = ask(served, "object", None)
    assert not reply.ok and "bogus" in reply.error
    reply = ask(served, "object", CalibrateRequest(store=False, object="no_such_thing"))
    assert not reply.ok


@pytest.mark.slow
def test_object_query_runs_the_procedure_on_the_devices(served, twin_devices, tmp_path):
    from activetouch.objects.library import ObjectLibrary

    ObjectLibrary.in_data_dir(twin_devices.ctx.data).get("sphere")
    twin_devices.ctx.place("sphere", 0)
    reply = ask(served, "object", CalibrateRequest(store=True, object="sphere"))
    assert reply.ok, reply.error
    res = reply.result
    assert res.kind == "object" and res.stored and res.values["object"] == "sphere"
    # placed at the nominal place: the correction is ~0
    assert np.hypot(*res.quality["correction_xy_mm"]) < 2.0
    assert res.quality["n_touches"] >= 6
    assert not twin_devices.lock.locked()
