"""`activetouch hardware check` on a BarrettHand played by its emulator over python-can's
virtual bus: its own steps (connect, pucks, stream, tactile at rest, initialisation), and
nothing moves unless ``hand.initialize_on_connect`` asks for the HI."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

from activetouch.config import load_config
from activetouch.emulators.barrett_bh8 import BH8Emulator, BH8EmulatorConfig, Faults
from activetouch.pipelines.hardware_check import BH8_CONNECT_FIX, FAIL, OK, WARN, hardware_check

_n = itertools.count()


def config_overrides(channel: str, *extra: str) -> list[str]:
    return [
        "hand.type=barrett-bh8",
        "hand.can_interface=virtual",
        f"hand.can_channel={channel}",
        "hand.wake_settle_s=0.01",
        "hand.stream_timeout_s=1.0",  # a loaded machine polls late; not a lost stream
        "arm.type=fake",
        *extra,
    ]


def config(channel: str, *extra: str):
    return load_config(None, config_overrides(channel, *extra))


def steps_by_name(steps):
    return {(s.device, s.name): s for s in steps}


def test_an_uninitialised_hand_moves_nothing_and_names_its_stuck_cell(tmp_path: Path) -> None:
    channel = f"bh8-check-{next(_n)}"
    emu = BH8Emulator(BH8EmulatorConfig(channel=channel, faults=Faults(stuck_cells=[(12, 5)])))
    with emu:
        before = emu.joints()
        steps = steps_by_name(hardware_check(config(channel), tmp_path, seconds=0.5))
        assert emu.joints() == before
        assert emu.counts["hi"] == 0 and emu.counts["motion_before_init"] == 0
    assert [k for k in steps if k[0] == "hand"] == [
        ("hand", "connect"),
        ("hand", "pucks"),
        ("hand", "stream"),
        ("hand", "tactile at rest"),
        ("hand", "initialisation"),
    ]
    connect = steps[("hand", "connect")]
    assert connect.status == OK and "nothing moved" in connect.detail
    pucks = steps[("hand", "pucks")]
    assert pucks.status == OK and "F1 (puck 11) firmware 175, tactile pad, strain" in pucks.detail
    assert steps[("hand", "stream")].status in (OK, WARN)  # a loaded machine polls slower
    rest = steps[("hand", "tactile at rest")]
    assert rest.status == WARN and "29 (F2 cell 5) stuck at full scale: masked" in rest.detail
    init = steps[("hand", "initialisation")]
    assert init.status == WARN and "not initialised" in init.detail
    assert "hand.initialize_on_connect = true" in init.fix
    assert steps[("arm", "connect")].status == OK


def test_an_initialised_hand_passes(tmp_path: Path) -> None:
    channel = f"bh8-check-{next(_n)}"
    with BH8Emulator(BH8EmulatorConfig(channel=channel)) as emu:
        cfg = config(channel, "hand.initialize_on_connect=true")
        steps = steps_by_name(hardware_check(cfg, tmp_path, seconds=0.5))
        assert emu.counts["hi"] == 4  # asked for by the setting, at connect
    assert "initialised at connect" in steps[("hand", "connect")].detail
    rest = steps[("hand", "tactile at rest")]
    assert rest.status == OK and "no cell of 96 in contact with the hand open" in rest.detail
    assert steps[("hand", "initialisation")].status == OK
    assert not any(s.status == FAIL for s in steps.values())


def test_no_hand_on_the_bus_fails_the_connect_with_the_fix(tmp_path: Path) -> None:
    cfg = config(f"bh8-check-nobody-{next(_n)}", "hand.reply_timeout_s=0.05")
    steps = steps_by_name(hardware_check(cfg, tmp_path, seconds=0.2))
    connect = steps[("hand", "connect")]
    assert connect.status == FAIL and "no reply from F1 (puck 11)" in connect.detail
    assert connect.fix == BH8_CONNECT_FIX and "ip link set can0" in connect.fix
    assert ("hand", "stream") not in steps


def test_the_cli_runs_the_bh8_steps(tmp_path: Path, capsys) -> None:
    from activetouch.cli.main import main

    channel = f"bh8-check-{next(_n)}"
    sets = [f"--set={o}" for o in config_overrides(channel)]
    with BH8Emulator(BH8EmulatorConfig(channel=channel)) as emu:
        code = main(["hardware", "check", "--json", "--seconds=0.3", f"--data={tmp_path}", *sets])
        assert emu.counts["hi"] == 0
    steps = {(s["device"], s["name"]): s for s in json.loads(capsys.readouterr().out)["steps"]}
    assert code == 0  # warnings (not initialised) but no failure
    assert steps[("hand", "initialisation")]["status"] == WARN
    assert ("hand", "fingers calibration") not in steps  # the ReFlex's steps are not run
