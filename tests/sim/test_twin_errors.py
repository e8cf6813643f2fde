"""The real robot's errors in the twin: a misplaced object the session does not know about, and
faulty tactile sensors."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from activetouch.config import load_config
from activetouch.errors import ConfigError
from activetouch.interfaces import SENSORS_PER_FINGER
from activetouch.objects.library import ObjectLibrary
from activetouch.sim.pybullet import pb
from activetouch.sim.twin import (
    FaultySimHand,
    PlacementError,
    open_twin,
    place_displaced,
    placement_error,
)


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    root = tmp_path_factory.mktemp("errors")
    mesh = root / "box.obj"
    trimesh.creation.box(extents=(0.10, 0.06, 0.08)).export(mesh)
    return ObjectLibrary(root / "objects").add("box", mesh)


def _body_pose(twin):
    pos, quat = pb.getBasePositionAndOrientation(
        twin.world.object.body, physicsClientId=twin.world.cid
    )
    return np.array(pos), np.array(quat)


def _ray_hits(twin, x: float, y: float) -> bool:
    hit = pb.rayTest([x, y, 0.5], [x, y, 0.001], physicsClientId=twin.world.cid)[0]
    return hit[0] == twin.world.object.body


def test_nominal_twin_has_no_error(box):
    cfg = load_config(None, [])
    assert placement_error(cfg.sim, 5) == PlacementError()
    with open_twin(box, cfg.sim, seed=5) as twin:
        np.testing.assert_array_equal(twin.world.object.offset, 0.0)
        pos, _ = _body_pose(twin)
        np.testing.assert_allclose(pos, twin.world.object_origin, atol=1e-9)
        assert type(twin.hand).__name__ == "SimHand"


def test_placement_error_moves_the_body_not_the_believed_frame(box):
    cfg = load_config(None, ["sim.placement_error_m=0.02", "sim.placement_error_deg=15"])
    nominal = load_config(None, [])
    with open_twin(box, nominal.sim, seed=3) as ref:
        origin, support = ref.world.object_origin, ref.support_z
    draws = [placement_error(cfg.sim, s) for s in range(50)]
    assert all(abs(d.dx) <= 0.02 and abs(d.dy) <= 0.02 for d in draws)
    assert all(abs(np.degrees(d.yaw_rad)) <= 15 for d in draws)
    assert max(abs(d.dx) for d in draws) > 0.015 and len(set(draws)) == 50  # spread, per seed
    err = placement_error(cfg.sim, 3)
    with open_twin(box, cfg.sim, seed=3) as twin:
        # What the session reads is the nominal placement ...
        np.testing.assert_allclose(twin.world.object_origin, origin)
        np.testing.assert_allclose(twin.wrist.placement.xyz, origin)
        assert twin.support_z == pytest.approx(support)
        # ... while Bullet's body stands where the error put it.
        pos, quat = _body_pose(twin)
        np.testing.assert_allclose(pos, origin + np.array([err.dx, err.dy, 0.0]), atol=1e-9)
        yaw = 2 * np.arctan2(quat[2], quat[3])
        assert yaw == pytest.approx(err.yaw_rad, abs=1e-6)
        np.testing.assert_allclose(twin.world.object.offset, [err.dx, err.dy, 0.0])


def test_a_shifted_and_turned_box_is_felt_where_it_really_is(box):
    cfg = load_config(None, [])
    with open_twin(box, cfg.sim, seed=0) as twin:
        assert _ray_hits(twin, 0.045, 0.0) and not _ray_hits(twin, 0.065, 0.0)
        place_displaced(twin.world, box, PlacementError(dx=0.02))
        assert _ray_hits(twin, 0.065, 0.0) and not _ray_hits(twin, -0.045, 0.0)
        place_displaced(twin.world, box, PlacementError(yaw_rad=np.radians(90)))
        # Turned a quarter: 6 cm along x, 10 cm along y.
        assert _ray_hits(twin, 0.0, 0.045) and not _ray_hits(twin, 0.045, 0.0)


def test_reused_twin_is_misplaced_like_a_fresh_one(box):
    cfg = load_config(None, ["sim.placement_error_m=0.02", "sim.placement_error_deg=15"])
    with open_twin(box, cfg.sim, seed=1) as twin:
        twin.place(box, 9)
        err = placement_error(cfg.sim, 9)
        np.testing.assert_allclose(twin.world.object.offset, [err.dx, err.dy, 0.0])
        assert twin.world.object.yaw_rad == pytest.approx(err.yaw_rad)


def test_stuck_sensors_always_report_and_stop_their_finger(box):
    cfg = load_config(None, ["sim.fault_stuck=6"])
    with open_twin(None, cfg.sim, seed=2) as twin:  # an empty table: nothing to touch
        hand = twin.hand
        assert isinstance(hand, FaultySimHand)
        stuck = set(hand.faulty.stuck.tolist())
        g = hand.guarded_close()
        assert set(g.sensor_ids.tolist()) == stuck
        stuck_fingers = {s // SENSORS_PER_FINGER for s in stuck if s < 27}
        for f in range(3):
            moved = g.finger_angles[f] > 0.1
            assert moved != (f in stuck_fingers)  # the ReFlex stops a finger that reads contact


def test_masked_stuck_sensors_stop_no_finger_and_are_not_reported(box):
    # Issue 24: a sensor reading contact with the hand open is ignored (Hand.mask_sensors).
    cfg = load_config(None, ["sim.fault_stuck=6"])
    with open_twin(None, cfg.sim, seed=2) as twin:
        hand = twin.hand
        hand.open()
        at_rest = np.flatnonzero(hand.state().contact)
        assert set(at_rest.tolist()) == set(hand.faulty.stuck.tolist())
        assert hand.mask_sensors(at_rest.tolist())
        g = hand.guarded_close()
        assert g.sensor_ids.size == 0  # nothing on the empty table, the stuck ones ignored
        assert (g.finger_angles > 0.1).all()  # every finger closed
        hand.open()
        hand.mask_sensors([])  # cleared: they stop their fingers again
        assert set(hand.guarded_close().sensor_ids.tolist()) == set(at_rest.tolist())


def test_dead_sensors_never_report(box):
    from activetouch.interfaces import Pose

    cfg = load_config(None, ["sim.fault_dead=20"])
    top = Pose([0.0, 0.0, 0.04 + 0.0896 + 0.012], [1.0, 0.0, 0.0, 0.0])  # palm down, over it
    seen_dead = set()
    with open_twin(box, cfg.sim, seed=4) as twin, open_twin(box, load_config().sim, 4) as ref:
        dead = set(twin.hand.faulty.dead.tolist())
        for t in (twin, ref):
            t.hand.open()
            t.wrist.move_to(top)
        faulty, clean = twin.hand.guarded_close(), ref.hand.guarded_close()
        seen_dead = dead & set(clean.sensor_ids.tolist())
        assert not dead & set(faulty.sensor_ids.tolist())
    assert seen_dead  # the test grasp does touch with sensors that are dead in the faulty twin


def test_bad_error_settings_name_the_setting(box):
    with pytest.raises(ConfigError, match="placement_error"):
        placement_error(load_config(None, ["sim.placement_error_m=-1"]).sim, 0)
    with (
        pytest.raises(ConfigError, match="fault"),
        open_twin(None, load_config(None, ["sim.fault_dead=40"]).sim),
    ):
        pass


def test_noise_thresholds_from_rest_readings_by_hand():
    from activetouch.session.contacts import noise_thresholds, rest_levels

    p = np.zeros((4, 38))
    p[:, 0] = [10.0, 12.0, 14.0, 12.0]  # mean 12, sample std 1.633
    p[:, 1] = [1.0, 1.0, 1.0, 1.0]  # agrees by chance: gets the median sigma, not a hair trigger
    p[:, 2:] = np.array([0.0, 2.0, 0.0, 2.0])[:, None]  # std 1.1547 each: the median
    contact = np.zeros((4, 38), dtype=bool)
    contact[:3, 5] = True  # in contact in 3 of 4 readings
    rest = rest_levels(p, contact)
    assert rest.readings == 4 and rest.contact[5] == 0.75 and rest.contact[6] == 0.0
    thr = noise_thresholds(rest, k=5.0)
    assert thr[0] == pytest.approx(12.0 + 5.0 * np.std([10, 12, 14, 12], ddof=1))
    assert thr[1] == pytest.approx(1.0 + 5.0 * np.std([0, 2, 0, 2], ddof=1))
    assert thr[7] == pytest.approx(1.0 + 5.0 * np.std([0, 2, 0, 2], ddof=1))


def test_above_thresholds_drops_only_the_contacts_under_their_sensor():
    from activetouch.interfaces import Grasp
    from activetouch.session.contacts import above_thresholds

    ids = np.array([3, 9, 30])
    g = Grasp(
        sensor_ids=ids,
        xyz=np.arange(9, dtype=float).reshape(3, 3),
        pressures=np.array([20.0, 5.0, 50.0]),
        finger_angles=np.zeros(3),
        preshape=0.0,
    )
    thr = np.full(38, 10.0)
    thr[30] = 60.0
    kept = above_thresholds(g, thr)
    assert kept.sensor_ids.tolist() == [3]
    assert kept.xyz.tolist() == [[0.0, 1.0, 2.0]]
    assert above_thresholds(g, np.zeros(38)) is g  # nothing under: the grasp as it was


def test_noisy_sensors_read_at_rest_set_thresholds_that_silence_them():
    # noise +10 sensor units: the configured threshold trips on the empty table; thresholds set
    # from 20 readings at rest (rest + 5 sigma) do not, and every finger closes.
    cfg = load_config(None, ["sim.fault_noise_std=10"])
    from activetouch.session.contacts import noise_thresholds, rest_levels

    with open_twin(None, cfg.sim, seed=3) as twin:
        hand = twin.hand
        hand.open()
        spurious = sum(int(hand.state().contact.sum()) for _ in range(20))
        assert spurious > 0
        states = [hand.state() for _ in range(20)]
        rest = rest_levels(
            np.array([s.pressures for s in states]), np.array([s.contact for s in states])
        )
        assert hand.set_contact_thresholds(noise_thresholds(rest, 5.0).tolist())
        assert sum(int(hand.state().contact.sum()) for _ in range(50)) == 0
        g = hand.guarded_close()
        assert g.sensor_ids.size == 0
        assert (g.finger_angles > 0.1).all()
        with pytest.raises(ValueError):
            hand.set_contact_thresholds([1.0] * 5)


def test_mask_reasons_from_flags_and_rest_readings():
    from activetouch.session.contacts import dead_at_rest, mask_reasons, rest_levels

    rng = np.random.default_rng(0)
    p = rng.normal(0.0, 2.0, (20, 38))
    p[:, 6] = 0.0  # dead: exactly nothing
    contact = np.zeros((20, 38), dtype=bool)
    contact[:15, 11] = True  # stuck: in contact in 15 of 20
    contact[:3, 12] = True  # a few spikes: not stuck
    rest = rest_levels(p, contact)
    assert dead_at_rest(rest).tolist() == [6]
    flags = {2: "noisy", 3: "drifting", 30: "saturated", 6: "dead"}
    assert mask_reasons(flags, rest) == {
        2: "noisy (tactile calibration)",
        6: "dead (tactile calibration)",
        11: "in contact with the hand open",
        30: "saturated (tactile calibration)",
    }
    flat = rest_levels(np.zeros((20, 38)), np.zeros((20, 38), dtype=bool))
    assert dead_at_rest(flat).size == 0  # a hand that reads all zeros (a fake) has no dead


def test_the_registrys_twin_rig_applies_the_errors_too(box, tmp_path):
    """The daemon's twin and the Baxter twin are made through the device registry: a seed's
    misplacement and the faulty sensors reach them as they reach `open_twin` (an evaluation
    on the Baxter twin once ran nominal while it reported the errors it drew)."""
    from activetouch.devices import make_devices
    from activetouch.sim.devices import twin_rig

    data = box.visual_mesh.parent.parent.parent  # <data>/objects/box/...
    over = ["sim.placement_error_m=0.02", "sim.placement_error_deg=15", "sim.fault_stuck=1"]
    cfg = load_config(None, over)
    devices = make_devices(cfg, data)
    try:
        devices.ctx.place("box", 3)
        world = twin_rig(devices.ctx).world
        err = placement_error(cfg.sim, 3)
        np.testing.assert_allclose(world.object.offset[:2], [err.dx, err.dy])
        assert world.object.yaw_rad == pytest.approx(err.yaw_rad) and err.dx != 0
        assert devices.hand.state().contact.sum() == 1  # the stuck sensor, the hand open
        devices.ctx.place("box", 4)  # the next run's draw
        assert not np.allclose(world.object.offset[:2], [err.dx, err.dy])
    finally:
        devices.close()
    nominal = make_devices(load_config(), data)
    try:
        nominal.ctx.place("box", 3)
        assert not twin_rig(nominal.ctx).world.object.offset.any()
        assert not nominal.hand.state().contact.any()
    finally:
        nominal.close()


def test_confirmed_keeps_only_contacts_that_last():
    from activetouch.interfaces import Grasp
    from activetouch.session.contacts import confirmed

    g = Grasp(
        sensor_ids=np.array([1, 4, 7]),
        xyz=np.arange(9, dtype=float).reshape(3, 3),
        pressures=np.array([40.0, 40.0, 40.0]),
        finger_angles=np.zeros(3),
        preshape=0.0,
    )
    p = np.zeros((2, 38))
    p[:, [1, 7]] = 35.0
    p[0, 4] = 35.0  # sensor 4 in the first reading after the close, gone in the second
    kept = confirmed(g, p, p > 20.0, np.full(38, 20.0))
    assert kept.sensor_ids.tolist() == [1, 7] and kept.xyz.tolist() == [[0, 1, 2], [6, 7, 8]]
    thr = np.full(38, 20.0)
    thr[7] = 36.0  # over the session's threshold for sensor 7 only in the hand's flags
    assert confirmed(g, p, p > 20.0, thr).sensor_ids.tolist() == [1]
    assert confirmed(g, p, p > 20.0, None).sensor_ids.tolist() == [1, 7]  # the hand's flags
    assert confirmed(g, np.zeros((0, 38)), np.zeros((0, 38), bool), None) is g  # no reading


def test_spurious_contacts_do_not_last_a_touch_does(box):
    # On the empty table every contact a grasp reports is spurious: none is in contact in the
    # next reading, the fingers still closed. On the box, the contacts all last.
    from activetouch.interfaces import Pose
    from activetouch.planning.grid import training_grid
    from activetouch.session.contacts import confirmed

    cfg = load_config(None, ["sim.fault_spurious=0.5"])
    with open_twin(None, cfg.sim, seed=4) as twin:
        g = twin.hand.guarded_close()
        assert g.sensor_ids.size > 5
        s = twin.hand.state()
        assert confirmed(g, s.pressures[None], s.contact[None], None).sensor_ids.size == 0
    nominal = load_config(None, [])
    grid = training_grid(np.array([0.10, 0.06, 0.08]), nominal.grid)
    with open_twin(box, nominal.sim, seed=4) as twin:
        twin.wrist.move_to(Pose.from_array(grid.poses[len(grid) // 2]))
        g = twin.hand.guarded_close()
        assert g.sensor_ids.size >= 2
        s = twin.hand.state()
        assert confirmed(g, s.pressures[None], s.contact[None], None) is g


def test_contacts_decided_on_the_mean_of_the_readings_after_the_close():
    from activetouch.interfaces import Grasp
    from activetouch.session.contacts import RestLevels, mean_contacts, mean_thresholds

    std = np.full(38, 10.0)
    std[3] = 2.0  # a quiet sensor: still held to the median sigma
    rest = RestLevels(np.full(38, 1.0), std, np.zeros(38), 20)
    own = np.full(38, 20.0)
    # rest 1 + 5 * 10 / sqrt(4) = 26 over the hand's own 20; with 100 readings the own 20
    thr = mean_thresholds(rest, 5.0, 4, own)
    np.testing.assert_allclose(thr, np.full(38, 26.0))
    np.testing.assert_allclose(mean_thresholds(rest, 5.0, 100, own), own)
    g = Grasp(
        sensor_ids=np.array([4, 9]),
        xyz=np.zeros((2, 3)),
        pressures=np.array([60.0, 70.0]),
        finger_angles=np.array([1.0, 1.1, 1.2]),
        preshape=0.3,
    )
    p = np.zeros((4, 38))
    p[:, 4] = [40.0, 50.0, 30.0, 40.0]  # the close's contact: mean 40
    p[:, 5] = [20.0, 35.0, 25.0, 24.0]  # its neighbour, under 52 in each: mean 26 is not over 26
    p[:, 6] = [30.0, 27.0, 29.0, 30.0]  # another neighbour: mean 29
    p[:, 9] = [80.0, 0.0, 0.0, 0.0]  # a spike the close caught: mean 20
    sites = np.arange(38 * 3, dtype=float).reshape(38, 3)
    out = mean_contacts(g, p, thr, sites)
    assert out.sensor_ids.tolist() == [4, 6]
    np.testing.assert_allclose(out.pressures, [40.0, 29.0])
    np.testing.assert_allclose(out.xyz, sites[[4, 6]])
    np.testing.assert_array_equal(out.finger_angles, g.finger_angles)
    assert out.preshape == 0.3


def test_averaged_contacts_under_heavy_noise_come_back_to_the_quiet_hands(box):
    """Under noise +10 a finger stops on its first noisy reading over rest + 5 sigma and the
    close reports fewer sensors than the quiet twin's; decided on the mean of 8 readings of
    the closed hand (at the sites the hand tells), they are the quiet twin's again."""
    from activetouch.calibration.tactile import read_states
    from activetouch.interfaces import Pose
    from activetouch.planning.grid import training_grid
    from activetouch.session.contacts import (
        mean_contacts,
        mean_thresholds,
        noise_thresholds,
        rest_levels,
    )

    nominal = load_config(None, [])
    noisy = load_config(None, ["sim.fault_noise_std=10"])
    grid = training_grid(np.array([0.10, 0.06, 0.08]), nominal.grid)
    pose = Pose.from_array(grid.poses[len(grid) // 2])
    with open_twin(box, nominal.sim, seed=4) as twin:
        twin.wrist.move_to(pose)
        quiet = set(twin.hand.guarded_close().sensor_ids.tolist())
    close, averaged = [], []
    for seed in range(4):
        with open_twin(box, noisy.sim, seed=seed) as twin:
            hand = twin.hand
            rest = rest_levels(*read_states(hand, 20))
            hand.set_contact_thresholds(noise_thresholds(rest, 5.0).tolist())
            twin.wrist.move_to(pose)
            g = hand.guarded_close()
            np.testing.assert_allclose(hand.sensor_sites()[g.sensor_ids], g.xyz)
            thr = mean_thresholds(rest, 5.0, 8, hand.own_contact_thresholds())
            m = mean_contacts(g, read_states(hand, 8)[0], thr, hand.sensor_sites())
            close.append(len(quiet ^ set(g.sensor_ids.tolist())))
            averaged.append(len(quiet ^ set(m.sensor_ids.tolist())))
    assert len(quiet) >= 3
    # measured: the close differs from the quiet set by 1-3 sensors, the mean by none
    assert sum(close) >= 4 and max(averaged) == 0, (close, averaged)


def test_a_zero_walks_only_beyond_the_readings_noise():
    from activetouch.session.contacts import rest_levels, zero_walk

    rng = np.random.default_rng(1)
    rest = rest_levels(rng.normal(0.0, 2.0, (20, 38)), np.zeros((20, 38), dtype=bool))
    now = rng.normal(0.0, 2.0, (8, 38))
    now[:, 3] += 9.0  # walked 9 units: far beyond 3 standard errors of 8 readings (~2.1)
    now[:, 5] += 9.0  # ... but in contact: no zero to read
    walk = zero_walk(rest, now, np.array([5]))
    assert walk[3] == pytest.approx(now[:, 3].mean() - rest.mean[3])
    assert walk[5] == 0.0
    assert np.count_nonzero(walk) == 1  # the others' noise moves no threshold
