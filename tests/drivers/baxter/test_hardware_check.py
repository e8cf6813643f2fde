"""`activetouch hardware check` on Baxter behind a tagged-release (legacy-key) bridge: the key
format found, the joint state rate, and the robot's state with what to do about it."""

from __future__ import annotations

from pathlib import Path

import pytest

from activetouch.cli.main import main
from activetouch.emulators.baxter_bridge import BaxterEmulator, EmulatorSettings
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint


@pytest.mark.parametrize("enabled", [True, False])
def test_check_names_the_bridge_format_and_the_robot_state(
    tmp_path: Path, enabled: bool, capsys
) -> None:
    ep = loopback_endpoint()
    with (
        ZenohSession(ZenohSettings(listen=(ep,))) as zs,
        BaxterEmulator(zs.session, EmulatorSettings(enabled=enabled, legacy=True)),
    ):
        args = ["--set", "hand.type=fake", "--set", "arm.type=baxter"]
        args += ["--set", f'arm.connect=["{ep}"]', "--data", str(tmp_path)]
        rc = main(["hardware", "check", "--json", "--seconds", "0.5", *args])
    import json

    steps = {(s["device"], s["name"]): s for s in json.loads(capsys.readouterr().out)["steps"]}
    assert steps[("arm", "connect")]["status"] == "ok"
    assert steps[("arm", "bridge keys")]["detail"].startswith("legacy")
    assert steps[("arm", "joint states")]["status"] in ("ok", "warn")
    state = steps[("arm", "robot state")]
    if enabled:
        bad = {k: v for k, v in steps.items() if v["status"] == "fail"}
        assert rc == 0 and state["status"] == "ok" and state["detail"] == "enabled", bad
    else:
        assert rc == 1 and state["status"] == "fail" and "enable" in state["fix"]


def test_no_bridge_is_a_failed_step_not_a_traceback(tmp_path: Path, capsys) -> None:
    ep = loopback_endpoint()  # nothing listens there
    args = ["--set", "hand.type=fake", "--set", "arm.type=baxter", "--set", f'arm.connect=["{ep}"]']
    args += ["--set", "arm.connect_timeout_s=0.5", "--data", str(tmp_path)]
    assert main(["hardware", "check", *args]) == 1
    out = capsys.readouterr().out
    assert "fail" in out and "zenoh-bridge-ros1" in out
