"""``hand.emulate = "twin"`` for the BH8: the driver (python-can frames, its own codec) on the
byte-level emulator, backed by the BH8 twin world the floating arm moves in, made by the device
layer as `serve` makes it; it closes as the twin does, directly."""

from __future__ import annotations

import json

import numpy as np
import pytest

from activetouch.config import load_config
from activetouch.errors import ConfigError

pytest.importorskip("pybullet")
pytest.importorskip("can")

EMULATED = ["hand.type=barrett-bh8", "hand.emulate=twin"]
WRIST_DOWN = np.array([1.0, 0.0, 0.0, 0.0])


def test_emulate_setting_is_checked_and_makes_the_hand_simulated() -> None:
    cfg = load_config(None, EMULATED)
    assert cfg.hand.simulated and cfg.hand.family == "bh8"
    assert cfg.grid.palm_offset_m == pytest.approx(0.084)  # the BH8's grid, as the twin's
    assert not load_config(None, ["hand.type=barrett-bh8"]).hand.simulated
    with pytest.raises(ConfigError, match=r"hand\.emulate"):
        load_config(None, ["hand.type=barrett-bh8", "hand.emulate=gazebo"])


@pytest.mark.slow
def test_the_driver_on_the_twin_backed_emulator_closes_as_the_twin(tmp_path) -> None:
    """At the same wrist poses over a cylinder, the driver on the emulator stops the same
    fingers on their pads at the same inner angles (to the emulator's 2 ms tick) and reports
    the twin's cells (a neighbour more or less: the reading falls at another instant)."""
    from activetouch.devices import make_devices
    from activetouch.interfaces import Pose
    from activetouch.rigs.bh8_emulated import TwinEmulatedBH8
    from activetouch.sim.bh8 import BH8World, SimBH8Hand
    from activetouch.sim.devices import TwinBH8HandConfig, twin_rig

    cfg = load_config(None, EMULATED)
    devices = make_devices(cfg, tmp_path)
    direct_world = BH8World(cfg.sim, workcell=cfg.workcell)
    try:
        hand = devices.hand
        assert isinstance(hand, TwinEmulatedBH8) and devices.simulated
        rig = twin_rig(devices.ctx)
        assert hand.fingers.world is rig.world  # the arm's world, not a copy
        assert hand.stats()["crashes"] == 0
        direct = SimBH8Hand(direct_world, TwinBH8HandConfig(), cfg.sim)
        for world in (rig.world, direct_world):
            world.place_primitive("cylinder", (0.045, 0.14))
        devices.wrist.set_placement(devices.placement())
        agreed = 0
        for spread, dx in ((0.0, 0.0), (np.pi / 3, 0.01), (np.pi / 2, -0.015), (0.3, 0.02)):
            pose = Pose(np.array([dx, 0.0, 0.07 + 0.084 + 0.01]), WRIST_DOWN)
            direct.open()
            direct.preshape(spread)
            direct_world.set_wrist(pose)
            want = direct.guarded_close()
            hand.open()
            hand.preshape(spread)
            devices.wrist.move_to(pose)
            got = hand.guarded_close()
            for f in range(3):
                if direct.last_close_reasons[f] == "contact":
                    assert hand.last_close_reasons[f] == "contact", (spread, f)
                    assert abs(got.finger_angles[f] - want.finger_angles[f]) < 0.03, (spread, f)
                    agreed += 1
            a, b = set(want.sensor_ids.tolist()), set(got.sensor_ids.tolist())
            assert a and len(a & b) >= len(a) - 2 and len(a ^ b) <= 6, (spread, a, b)
        assert agreed >= 10
        assert hand.stats()["crashes"] == 0
    finally:
        direct_world.close()
        devices.close()


@pytest.mark.slow
def test_a_whole_recognition_runs_through_the_driver_on_the_emulator(tmp_path, capsys) -> None:
    """A BH8 model trained in the twin, then a recognition through the driver's CAN frames on
    the twin-backed emulator (as `serve --set hand.type=barrett-bh8 --set hand.emulate=twin`
    makes it): it names the object, as the same recognition in the twin directly does."""
    from activetouch import paths
    from activetouch.cli.main import main
    from activetouch.devices import make_devices
    from activetouch.model import load_model
    from activetouch.planning.policies import make_policy
    from activetouch.session.loop import RecognitionSession
    from activetouch.sim.devices import twin_rig

    fast = ["--set", "hand.type=twin-bh8", "--set", "grid.step_deg=40"]
    assert main(["train", "--objects", "cup,bowl", "--data", str(tmp_path), *fast]) == 0
    capsys.readouterr()
    model = load_model(paths.default_model(tmp_path, "bh8"))
    direct = ["recognize", "--object", "bowl", "--data", str(tmp_path), *fast, "--json"]
    assert main([*direct, "--max-moves", "3", "--policy", "greedy", "--no-record"]) == 0
    assert json.loads(capsys.readouterr().out)["label"] == "bowl"
    cfg = load_config(None, [*EMULATED, "grid.step_deg=40", "session.max_moves=3"])
    devices = make_devices(cfg, tmp_path)
    try:
        hand = devices.hand
        rig = twin_rig(devices.ctx)
        devices.ctx.place("bowl", 0)
        devices.wrist.set_placement(devices.placement())
        before = hand.stats()["accepted"]
        res = RecognitionSession(
            hand,
            devices.wrist,
            model,
            make_policy("greedy", cfg.planner, model.observation, model.classifier.kernel()),
            cfg.session,
            np.random.default_rng(0),
            support_z=rig.world.support_z,
        ).run()
        stats = hand.stats()
    finally:
        devices.close()
    assert res.moves >= 1 and res.label == "bowl"
    assert stats["accepted"] - before > 50 and stats["crashes"] == 0  # paced by CAN frames
