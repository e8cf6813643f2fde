"""A lab's own ReFlex calibration (issue 23): `calibrate import` of reflex-ros-pkg's yaml
files, and `calibrate fingers` for the SF, against the SF emulator (which imports no driver
code) playing a hand whose zero points are not the public file's."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from activetouch.calibration import store
from activetouch.calibration.sf_fingers import find_zero_points
from activetouch.cli.main import main
from activetouch.config import load_config
from activetouch.devices import make_devices
from activetouch.drivers.reflex.common import ServoFaultError
from activetouch.drivers.reflex.sf import ReflexSFConfig, ReflexSFHand
from activetouch.emulators.reflex_sf import FixedStops, SFEmulator, SFEmulatorConfig

THIS_HAND = (20.5, 30.1, 22.0, 27.3)  # motor rad with the hand open: not the public 25.21 ...
TICK = 2 * math.pi / 4096

# Written by hand in reflex-ros-pkg's formats (reflex/yaml, reflex_driver/yaml).
SF_YAML = """\
reflex_sf_f1: {zero_point: 20.5}
reflex_sf_f2: {zero_point: 30.1}
reflex_sf_f3: {zero_point: 22.0}
reflex_sf_preshape: {zero_point: 27.3}
"""
FINGER_YAML = """\
# Calibration constants for [f1, f2, f3, preshape]
encoder_zero_reference: [2.2, 6.0, 4.6]
motor_zero_reference: [59.5, 56.5, 60.2, 55.3]
"""
TACTILE_YAML = """\
tactile_offset_f1: [168, 57, 159, 298, 148, 152, 302, 153, 305]
tactile_offset_f2: [255, 255, 255, 255, 255, 255, 255, 255, 255]
tactile_offset_f3: [154, 112, 101, 114, 125, 86, 83, 93, 163]
"""


@pytest.fixture
def emu():
    e = SFEmulator(SFEmulatorConfig(zero_points=THIS_HAND), FixedStops([1.0, 1.3, math.inf]))
    e.start()
    yield e
    e.stop()


def sf_args(emu: SFEmulator, data: Path) -> list[str]:
    return ["--data", str(data), "--set", "hand.type=reflex-sf", "--set", f"hand.port={emu.port}"]


def test_the_public_zero_points_do_not_fit_this_hand(emu) -> None:
    with pytest.raises(ServoFaultError, match="calibrate fingers"):
        ReflexSFHand(ReflexSFConfig(port=emu.port, stream_timeout_s=0.5)).connect()


def test_import_of_an_sf_zero_point_file_is_used_by_the_driver(emu, tmp_path: Path) -> None:
    f = tmp_path / "reflex_sf_motor_zero_points.yaml"
    f.write_text(SF_YAML)
    assert main(["calibrate", "import", str(f), *sf_args(emu, tmp_path)]) == 0
    rec = store.load(tmp_path, "fingers", "reflex-sf")
    assert rec is not None and rec.values["motor_zero_points"] == list(THIS_HAND)
    cfg = load_config(None, [f"hand.port={emu.port}", "hand.type=reflex-sf", "arm.type=fake"])
    devices = make_devices(cfg, tmp_path)  # connects: the stored zero points fit this hand
    try:
        np.testing.assert_allclose(devices.hand.zero, THIS_HAND)
        devices.hand.open()
        np.testing.assert_allclose(
            emu.raw_positions(), np.round(np.array(THIS_HAND) / TICK), atol=40
        )
    finally:
        devices.close()


def test_sf_calibrate_fingers_takes_the_open_positions(emu, tmp_path: Path) -> None:
    assert main(["calibrate", "fingers", "--accept-current", *sf_args(emu, tmp_path)]) == 0
    rec = store.load(tmp_path, "fingers", "reflex-sf")
    assert rec is not None
    np.testing.assert_allclose(rec.values["motor_zero_points"], THIS_HAND, atol=2 * TICK)
    assert rec.method["procedure"] == "fingers (ReFlex SF)"


def test_sf_jogging_finds_the_taut_point(tmp_path: Path) -> None:
    # Finger 1 starts 0.3 motor rad slack (servo id 1 is not inverted: slack is -0.3), the
    # preshape (inverted) 0.2 rad off the other way; the operator tightens / loosens them.
    cfg = SFEmulatorConfig(zero_points=THIS_HAND, start_offset_rad=(-0.3, 0.0, 0.0, -0.2))
    with SFEmulator(cfg, FixedStops([1.0, 1.3, math.inf])) as emu:
        hand = ReflexSFHand(ReflexSFConfig(port=emu.port, stream_timeout_s=0.5), check_travel=False)
        hand.connect()
        try:
            keys = {0: ["t"] * 6, 3: ["L"] * 1}  # 6 x 0.05 tightens; the preshape 0.25 back
            zero, jogs = find_zero_points(hand, lambda k, _n, _p: (keys.get(k) or [""]).pop(0))
        finally:
            hand.disconnect()
    assert jogs == [6, 0, 0, 1]
    np.testing.assert_allclose(zero[:3], THIS_HAND[:3], atol=0.02)
    assert zero[3] == pytest.approx(THIS_HAND[3] + 0.05, abs=0.02)  # 0.2 off, 0.25 back


def test_import_of_takktile_files(tmp_path: Path) -> None:
    (tmp_path / "finger_calibrate.yaml").write_text(FINGER_YAML)
    (tmp_path / "tactile_calibrate.yaml").write_text(TACTILE_YAML)
    args = [
        "--data",
        str(tmp_path),
        "--set",
        "hand.type=reflex-takktile",
        "--set",
        "hand.serial=h7",
    ]
    files = [str(tmp_path / "finger_calibrate.yaml"), str(tmp_path / "tactile_calibrate.yaml")]
    assert main(["calibrate", "import", *files, *args]) == 0
    fingers = store.load(tmp_path, "fingers", "h7")
    assert fingers is not None
    assert fingers.values["motor_zero_rad"] == [59.5, 56.5, 60.2, 55.3]
    np.testing.assert_allclose(
        fingers.values["motor_zero_points"], [59.5 * 1.42, 56.5 * 1.42, 60.2 * 1.42, 55.3 * 1.5]
    )
    assert fingers.values["encoder_zero_rad"] == [2.2, 6.0, 4.6]
    tactile = store.load(tmp_path, "tactile", "h7")
    assert tactile is not None
    assert tactile.values["zero"][:9] == [168, 57, 159, 298, 148, 152, 302, 153, 305]
    assert tactile.values["zero"][9:18] == [255] * 9
    assert tactile.values["flags"]["not_imported"] == list(range(27, 38))
    assert min(tactile.values["threshold"][27:]) >= 1023  # the palm never reads contact


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("reflex_sf_f1: {zero_point: 20.5}\n", "not a reflex-ros-pkg calibration file"),
        ("motor_zero_reference: [1, 2]\nencoder_zero_reference: [1, 2, 3]\n", "4 numbers"),
        ("tactile_offset_f1: [1, 2]\n", "9 numbers"),
        ("a: [\n", "not valid YAML"),
        ("- 1\n", "mapping"),
    ],
)
def test_import_refuses_files_it_cannot_read(
    tmp_path: Path, text: str, message: str, capsys
) -> None:
    f = tmp_path / "x.yaml"
    f.write_text(text)
    assert main(["calibrate", "import", str(f), "--data", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err
    assert not list((tmp_path).rglob("*.json"))


def test_import_json_output(tmp_path: Path, capsys) -> None:
    f = tmp_path / "z.yaml"
    f.write_text(SF_YAML)
    args = ["--data", str(tmp_path), "--set", "hand.type=reflex-sf", "--json", "--dry-run"]
    assert main(["calibrate", "import", str(f), *args]) == 0
    out = capsys.readouterr().out
    rec, _end = json.JSONDecoder().raw_decode(out)  # the record first, then the summary line
    assert rec["values"]["motor_zero_points"] == list(THIS_HAND)
    assert not list((tmp_path).rglob("*.json"))
