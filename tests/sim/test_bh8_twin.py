"""The BH8 twin: PyBullet's links where the manual's D-H model puts them, guarded closes on
primitives whose surfaces are known exactly, the TorqueSwitch, stop and masks, and the CLI
training and recognising with `hand.type=twin-bh8`."""

from __future__ import annotations

import json
import threading
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from activetouch.config import SimConfig, load_config
from activetouch.errors import ConfigError, StoppedError
from activetouch.interfaces import Pose
from activetouch.models import bh8
from activetouch.sim.bh8 import BH8World, SimBH8Hand
from activetouch.sim.devices import TwinBH8HandConfig
from activetouch.sim.pybullet import pb

DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # palm facing -z: the hand above the object


@pytest.fixture
def twin():
    world = BH8World(SimConfig())
    hand = SimBH8Hand(world, TwinBH8HandConfig())
    try:
        yield world, hand
    finally:
        world.close()


def _above(world: BH8World, height: float, clearance: float = 0.01) -> None:
    """The palm face `clearance` above an object `height` tall (object frame at its centre)."""
    world.set_wrist(Pose(np.array([0.0, 0.0, height / 2 + bh8.DW + clearance]), DOWN))


def test_pybullet_links_are_the_dh_frames(twin) -> None:
    world, _ = twin
    spread, inner, outer = 0.8, np.array([0.3, 0.9, 1.4]), np.array([0.2, 0.5, 0.1])
    world.set_wrist(Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])))
    world.set_hand(spread, inner, outer)
    frames = bh8.link_frames(spread, inner, outer)
    by_link = {
        pb.getJointInfo(world.hand, j, physicsClientId=world.cid)[12].decode(): j
        for j in range(pb.getNumJoints(world.hand, physicsClientId=world.cid))
    }
    base_pos, base_quat = world.wrist_world()
    base = np.eye(4)
    base[:3, :3], base[:3, 3] = Rotation.from_quat(base_quat).as_matrix(), base_pos
    for name, j in by_link.items():
        st = pb.getLinkState(
            world.hand, j, computeForwardKinematics=True, physicsClientId=world.cid
        )
        got = np.eye(4)
        got[:3, :3], got[:3, 3] = Rotation.from_quat(st[5]).as_matrix(), st[4]
        want = base @ frames[name]
        np.testing.assert_allclose(got[:3, 3], want[:3, 3], atol=1e-5, err_msg=name)
        np.testing.assert_allclose(got[:3, :3], want[:3, :3], atol=1e-4, err_msg=name)


def test_a_close_on_a_cylinder_touches_its_surface_with_every_fingertip(twin) -> None:
    world, hand = twin
    radius, height = 0.04, 0.12
    world.place_primitive("cylinder", (radius, height))
    _above(world, height)
    hand.preshape(np.pi / 3)  # fingers 120 deg apart
    grasp = hand.guarded_close()
    assert hand.last_close_reasons == ("contact", "contact", "contact")
    pads = set((grasp.sensor_ids // bh8.CELLS_PER_PAD).tolist())
    assert {0, 1, 2} <= pads
    # Every reported cell lies on the cylinder's side (object frame = its centre), within the
    # foam's compression and the cell's offset from where the surface touched it.
    xyz = world.hand_to_world(grasp.xyz) - world.object_origin
    r = np.hypot(xyz[:, 0], xyz[:, 1])
    assert np.all(np.abs(r - radius) < 0.006), r
    assert np.all(np.abs(xyz[:, 2]) <= height / 2 + 0.006)
    # The fingers closed to where the cylinder is: not to their limits, and alike by symmetry
    # for F1 and F2 (F3's knuckle sits at another distance from the axis).
    assert np.all(grasp.finger_angles < bh8.INNER_LIMIT - 0.1)
    assert abs(grasp.finger_angles[0] - grasp.finger_angles[1]) < 0.03


def test_an_empty_table_lets_every_finger_close_to_its_limit(twin) -> None:
    world, hand = twin
    world.set_wrist(Pose(np.array([0.0, 0.0, 0.5]), DOWN))
    t0 = hand.robot_seconds
    grasp = hand.guarded_close()
    assert grasp.n_contacts == 0
    assert hand.last_close_reasons == ("limit", "limit", "limit")
    # One reading per control step for the whole motor travel (the driver's ~2 s close).
    steps = np.ceil(hand.motor_limit / hand.motor_step)
    assert hand.robot_seconds - t0 == pytest.approx((steps + 1) * 0.02, abs=0.021)
    # The driver's finger_limit_counts (190000 of 195000) ends the travel first: 133.6 deg.
    np.testing.assert_allclose(world.proximal, hand.motor_limit / bh8.INNER_RATIO)
    np.testing.assert_allclose(world.distal, bh8.coupled_outer(world.proximal))


def test_the_torque_switch_breaks_away_when_the_inner_link_is_blocked(twin) -> None:
    """A bar across F3's inner link (no cells there): the inner link stops on it, the outer
    link curls on past inner / 3 until its own pad or its limit stops it."""
    world, hand = twin
    # A thin wall whose top edge runs across the thumb's inner link, 3 cm out from its
    # knuckle (hand y = 0.08), 4 mm clear of it; palm down, hand y is world -y.
    world.place_primitive("box", (0.2, 0.01, 0.2))
    knuckle = bh8.inner_link_frame(2, 0.0, 0.0)[:3, 3]
    y = knuckle[1] + 0.03
    world.set_wrist(Pose(np.array([0.0, y, 0.1 + bh8.DW + 0.009 + 0.004]), DOWN))
    assert world.collision_reason() is None
    hand.guarded_close()
    inner, outer = world.proximal[2], world.distal[2]
    assert 0.05 < inner < 0.2, inner  # atan(4 mm / 30 mm) less the 2.46 deg of Phi2
    assert outer > bh8.coupled_outer(inner) + 0.1, (inner, outer)


def test_a_stop_ends_a_close_within_one_control_step(twin) -> None:
    world, hand = twin
    world.set_wrist(Pose(np.array([0.0, 0.0, 0.5]), DOWN))
    calls = {"n": 0}
    sense = hand._sense

    def counting(*a, **k):
        calls["n"] += 1
        if calls["n"] == 5:  # a stop from another thread, mid-close
            threading.Thread(target=hand.stop).start()
            hand.stop_latch._event.wait(5.0)
        return sense(*a, **k)

    hand._sense = counting  # type: ignore[method-assign]
    with pytest.raises(StoppedError):
        hand.guarded_close()
    assert calls["n"] == 5  # no reading after the stop
    with pytest.raises(StoppedError):
        hand.preshape(0.5)
    hand.clear_stop()
    hand.preshape(0.5)


def test_masked_cells_are_never_reported_and_stop_no_finger(twin) -> None:
    world, hand = twin
    world.place_primitive("cylinder", (0.04, 0.12))
    _above(world, 0.12)
    first = hand.guarded_close()
    hand.open()
    ids = first.sensor_ids[first.sensor_ids < bh8.CELLS_PER_PAD]  # F1's cells
    assert ids.size
    hand.mask_sensors(list(range(bh8.CELLS_PER_PAD)))  # F1's whole pad
    again = hand.guarded_close()
    assert not np.any(again.sensor_ids < bh8.CELLS_PER_PAD)
    assert hand.last_close_reasons[0] != "contact"  # its load stopped it (strain) or a limit
    with pytest.raises(ValueError):
        hand.mask_sensors([96])
    with pytest.raises(ValueError):
        hand.set_contact_thresholds([1.0] * 38)


def test_a_session_refuses_a_model_of_another_hand(twin) -> None:
    from activetouch.session.loop import check_model_hand, model_hand_family

    _, hand = twin
    reflex_model = SimpleNamespace(config={"hand": {"type": "twin"}})
    bh8_model = SimpleNamespace(config={"hand": {"type": "twin-bh8"}})
    old_model = SimpleNamespace(config={})
    assert model_hand_family(bh8_model) == "bh8" and model_hand_family(old_model) == "reflex"
    check_model_hand(bh8_model, hand)
    with pytest.raises(ConfigError, match="trained for the reflex hand"):
        check_model_hand(reflex_model, hand)


def test_the_bh8_config_brings_its_own_grid_unless_set() -> None:
    cfg = load_config(None, ["hand.type=twin-bh8"])
    assert cfg.grid.palm_offset_m == pytest.approx(bh8.DW) and cfg.grid.margin_m == 0.05
    cfg = load_config(None, ["hand.type=twin-bh8", "grid.margin_m=0.07"])
    assert cfg.grid.margin_m == 0.07 and cfg.grid.palm_offset_m == pytest.approx(bh8.DW)
    assert load_config(None, []).grid.palm_offset_m == pytest.approx(0.0896)
    with pytest.raises(ConfigError, match=r"hand\.pad_depth_m"):
        load_config(None, ["hand.type=twin-bh8", "hand.pad_depth_m=0"])


def test_faulty_cells_on_the_bh8_twin() -> None:
    """The robot's sensor faults on the BH8's 96 cells: a stuck cell reads over threshold at
    rest, dead ones read nothing, the extra noise is the ReFlex's scaled to cell units."""
    from activetouch.sim.twin import open_twin

    cfg = load_config(
        None,
        ["hand.type=twin-bh8", "sim.fault_stuck=1", "sim.fault_dead=4", "sim.fault_noise_std=5"],
    )
    with open_twin(None, cfg.sim, seed=3, hand=cfg.hand) as tw:
        hand = tw.hand
        assert hand.n_sensors == 96 and hand.noise_scale == pytest.approx(0.5 / 20)
        stuck, dead = hand.faulty.stuck, hand.faulty.dead
        assert len(stuck) == 1 and len(dead) == 4 and 0 <= stuck.max() < 96
        st = hand.state()
        assert st.contact[stuck].all() and np.all(st.pressures[dead] == 0.0)
        # Noise +5 ReFlex units is +0.125 cell units: quiet cells stay under the 0.5 threshold.
        quiet = np.setdiff1d(np.arange(96), np.concatenate([stuck, dead]))
        assert st.pressures[quiet].std() < 0.3 and not st.contact[quiet].any()


@pytest.mark.slow
def test_train_and_recognize_with_the_bh8_twin(tmp_path, capsys) -> None:
    from activetouch.cli.main import main

    home = ["--data", str(tmp_path)]
    fast = ["--set", "hand.type=twin-bh8", "--set", "grid.step_deg=40"]
    assert main(["train", "--objects", "cup,bowl", *home, *fast, "--workers", "1"]) == 0
    assert (tmp_path / "models" / "default-bh8" / "model.json").is_file()
    assert not (tmp_path / "models" / "default").exists()  # the ReFlex's model is untouched
    capsys.readouterr()
    assert main(["recognize", "--object", "bowl", *home, *fast, "--json", "--max-moves", "4"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["profile"] == "robust" and doc["object"] == "bowl" and 1 <= doc["moves"] <= 4
    assert doc["label"] in ("bowl", "cup") and "pose_estimate" in doc
    # The ReFlex twin has no model here: a clear error, not a BH8 model read as a ReFlex one.
    assert main(["recognize", "--object", "bowl", *home, "--max-moves", "2"]) != 0
    assert "train one first" in capsys.readouterr().err
