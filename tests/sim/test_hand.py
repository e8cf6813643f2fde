"""SimHand: guarded enclosure on primitives, tactile sensing, determinism."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from activetouch.config import SimConfig
from activetouch.interfaces import SENSORS_PER_FINGER, Grasp, Pose
from activetouch.models.reflex import coupled_joints
from activetouch.sim.hand import (
    STOP_CONTACT,
    STOP_LIMIT,
    STOP_STALL,
    SimHand,
    site_forces,
    spread_kernel,
)
from activetouch.sim.twin import twin_wrist
from activetouch.sim.world import SimArm, SimWorld

TOP = np.array([1.0, 0.0, 0.0, 0.0])  # hand +z pointing down
PAD = 0.0896


def quat_from_axes(x: list[float], y: list[float], z: list[float]) -> np.ndarray:
    return Rotation.from_matrix(np.column_stack([x, y, z])).as_quat()


# Hand +z along world +x (towards the object), fingers 0/1 and thumb closing horizontally.
SIDE = quat_from_axes([0, 1, 0], [0, 0, 1], [1, 0, 0])


@pytest.fixture
def rig():
    with SimWorld() as w:
        yield w, SimArm(w), SimHand(w)


def grasp_at(arm: SimArm, hand: SimHand, pose: Pose, preshape: float = 0.0) -> Grasp:
    hand.open()
    hand.preshape(preshape)
    twin_wrist(arm).move_to(pose)
    return hand.guarded_close()


def fingers_touched(g: Grasp) -> set[int]:
    return {int(i) // SENSORS_PER_FINGER for i in g.sensor_ids if i < 27}


def test_coupling_is_a_pure_function() -> None:
    prox, dist = coupled_joints(
        np.array([1.0, 1.0, 1.0]),
        np.array([0.0, 0.3, 0.0]),
        np.array([False, True, False]),
        0.25,
        np.pi,
        2.74,
    )
    np.testing.assert_allclose(prox, [0.8, 0.3, 0.8])
    np.testing.assert_allclose(dist, [0.2, 0.7, 0.2])


def test_site_forces_spread_each_contact_over_its_own_links_sites() -> None:
    sigma, k = 0.005, 1000.0
    np.testing.assert_allclose(spread_kernel(np.array([0.0, sigma]), sigma), [1.0, np.exp(-0.5)])
    sites = np.array([[0.0, 0, 0], [0.0079, 0, 0], [0.0, 0, 0], [0.0237, 0, 0]])
    site_link = np.array([1, 1, 2, 1])
    # Right over site 0 (link 1): site 0 reads the full force, the neighbour 7.9 mm away a
    # share, the site 3 pitches away ~nothing, and site 2 (same place, other link) nothing.
    f = site_forces(np.array([1]), np.zeros((1, 3)), np.array([0.002]), site_link, sites, sigma, k)
    share = np.exp(-0.5 * (0.0079 / sigma) ** 2)
    np.testing.assert_allclose(f[:3], [2.0, 2.0 * share, 0.0], rtol=1e-12)
    assert 0.0 < f[3] < 1e-4 * f[0]
    # Forces of several points add up; a point on link 2 loads only link 2's site.
    pts = np.array([[0.004, 0.0, 0.0], [0.004, 0.003, 0.0], [0.0, 0.0, 0.001]])
    f = site_forces(
        np.array([1, 1, 2]), pts, np.array([0.001, 0.001, 0.003]), site_link, sites, sigma, k
    )
    d = np.linalg.norm(pts[:2, None, :] - sites[None, [0, 1, 3], :], axis=2)
    np.testing.assert_allclose(f[[0, 1, 3]], spread_kernel(d, sigma).sum(axis=0), rtol=1e-12)
    np.testing.assert_allclose(f[2], 3.0 * spread_kernel(0.001, sigma))
    assert (
        site_forces(
            np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), site_link, sites, sigma, k
        ).tolist()
        == [0.0] * 4
    )


def _press_proximal_site(depth: float, noise_std: float = 0.0) -> np.ndarray:
    """Pressures with finger 0 lying open and a small sphere pressed `depth` into the skin
    right over its proximal sensor 1 (nothing else touches)."""
    cfg = SimConfig(noise_std=noise_std)
    with SimWorld(cfg) as w:
        hand = SimHand(w)
        r = 0.015
        w.place_primitive("sphere", r)
        site = w.sensor_sites_hand()[1]
        centre = site + np.array([0.0, 0.0, r - depth])  # on the tactile (+z) side
        # Hand +z down (TOP: hand x = world x, y = -y, z = -z): the object-frame origin is
        # at the sphere's centre.
        w.set_wrist(Pose(centre * np.array([-1.0, 1.0, 1.0]), TOP))
        contacts = w.hand_contacts()
        assert set(contacts.link.tolist()) == {w.links.site_link[1]}, contacts
        return hand.state().pressures


def test_a_light_touch_registers_on_one_sensor_a_firm_one_on_its_neighbours_too() -> None:
    thr = SimConfig().contact_threshold
    light = _press_proximal_site(0.0003)
    assert np.flatnonzero(light > thr).tolist() == [1]
    firm = _press_proximal_site(0.0015)
    assert np.flatnonzero(firm > thr).tolist() == [0, 1, 2]
    assert firm[1] > firm[0] > thr and abs(firm[0] - firm[2]) < 1e-6 * firm[1]
    # Three pitches away (sensor 4), on the distal link and elsewhere: no load at all.
    assert firm[4] < 1e-3 * firm[1]
    np.testing.assert_array_equal(firm[5:], 0.0)
    # Noise does not change that picture.
    noisy = _press_proximal_site(0.0015, noise_std=2.0)
    assert np.flatnonzero(noisy > thr).tolist() == [0, 1, 2]


def test_each_finger_stops_on_its_own_contact(rig) -> None:
    w, arm, hand = rig
    # A thin vertical rod that lies only in finger 0's closing plane (hand x = world z: fingers
    # 0 and 1 above, thumb below; finger 0 at hand y = -0.026).
    w.place_primitive("cylinder", (0.01, 0.4))
    pose = Pose([-0.13, -0.026, 0.0], quat_from_axes([0, 0, 1], [0, -1, 0], [1, 0, 0]))
    g = grasp_at(arm, hand, pose)
    reasons = hand.last_close.stop_reasons
    assert reasons == (STOP_CONTACT, STOP_LIMIT, STOP_LIMIT)
    assert g.finger_angles[0] < g.finger_angles[1] - 0.5
    assert abs(g.finger_angles[1] - g.finger_angles[2]) < 1e-9  # both free to the limit
    assert len(g.sensor_ids) >= 1 and fingers_touched(g) == {0}
    # The contact lies on the rod's surface: world distance from its axis ~ radius.
    world_xyz = w.hand_to_world(g.xyz)
    assert np.all(np.abs(np.hypot(world_xyz[:, 0], world_xyz[:, 1]) - 0.01) < 0.004)


def test_sphere_enclosure_touches_all_three_fingers_on_its_surface(rig) -> None:
    w, arm, hand = rig
    r = 0.06
    w.place_primitive("sphere", r)
    # From the side (fingers sweep horizontally) and from above with a spherical preshape (a
    # swivelled flat finger would reach under the table from the side).
    for pose, preshape in [
        (Pose([-(r + PAD + 0.005), 0, 0], SIDE), 0.0),
        (Pose([-(r + PAD + 0.03), 0, 0], SIDE), 0.0),
        (Pose([0, 0, r + PAD + 0.01], TOP), 0.8),
    ]:
        g = grasp_at(arm, hand, pose, preshape)
        assert fingers_touched(g) == {0, 1, 2}, (pose, g.sensor_ids)
        assert hand.last_close.stop_reasons == (STOP_CONTACT,) * 3
        centre = w.world_to_hand(w.object_origin)
        dist = np.linalg.norm(g.xyz - centre, axis=1)
        assert np.all(np.abs(dist - r) < 0.004), dist
        assert np.all(g.pressures > hand.cfg.contact_threshold)
        # Fingers 0 and 1 are mirror images about the hand's xz plane (same sensor index).
        assert {int(i) % 9 for i in g.sensor_ids if i < 9} == {
            int(i) % 9 for i in g.sensor_ids if 9 <= i < 18
        }


def test_cylinder_contacts_lie_on_its_side(rig) -> None:
    w, arm, hand = rig
    r, h = 0.04, 0.25
    w.place_primitive("cylinder", (r, h))
    for gap in (0.01, 0.03):
        g = grasp_at(arm, hand, Pose([-(r + PAD + gap), 0, 0], SIDE))
        assert fingers_touched(g) == {0, 1, 2}
        p = w.hand_to_world(g.xyz)
        assert np.all(np.abs(np.hypot(p[:, 0], p[:, 1]) - r) < 0.004)
        assert np.all((p[:, 2] > 0) & (p[:, 2] < h))


def test_box_contacts_lie_on_its_faces(rig) -> None:
    w, arm, hand = rig
    size = np.array([0.07, 0.07, 0.25])
    w.place_primitive("box", size)
    for pose in (
        Pose([-(size[0] / 2 + PAD + 0.03), 0, 0], SIDE),
        Pose([0, 0, size[2] / 2 + PAD + 0.03], TOP),
    ):
        g = grasp_at(arm, hand, pose)
        assert fingers_touched(g) == {0, 1, 2}
        q = np.abs(w.hand_to_world(g.xyz) - w.object_origin) - size / 2
        sdf = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
        assert np.all(np.abs(sdf) < 0.004), sdf


def test_empty_table_gives_no_contact(rig) -> None:
    w, arm, hand = rig
    assert w.object is None
    g = grasp_at(arm, hand, Pose([0, 0, 0.3], TOP), 0.8)
    assert g.n_contacts == 0 and g.sensor_ids.shape == (0,) and g.xyz.shape == (0, 3)
    assert hand.last_close.stop_reasons == (STOP_LIMIT,) * 3
    spool = hand.cfg.spool_limit_rad
    np.testing.assert_allclose(g.finger_angles, spool / (1 + hand.cfg.flexure_coupling))
    assert g.preshape == 0.8
    st = hand.state()
    assert not st.contact.any() and st.pressures.shape == (38,)


def test_after_a_proximal_contact_the_distal_wraps_on_to_the_commanded_spool() -> None:
    # A thin vertical rod across the closing planes of fingers 0 and 1 (hand y = world z), 4 cm
    # out along the open fingers and 3 cm above them: their proximal links meet it first.
    xr, zr = 0.0604 + 0.04, 0.0816 + 0.03
    pose = Pose([-zr, -xr, 0.0], SIDE)
    runs = {}
    for travel in (0.0, 0.05):
        with SimWorld(SimConfig(post_contact_travel_rad=travel)) as w:
            w.place_primitive("cylinder", (0.006, 0.3))
            hand = SimHand(w)
            runs[travel] = (grasp_at(SimArm(w), hand, pose), hand.last_close)
    c0, (g1, c1) = runs[0.0][1], runs[0.05]
    k, step = SimConfig().flexure_coupling, SimConfig().spool_step_rad
    for f in (0, 1):
        assert c0.stop_reasons[f] == c1.stop_reasons[f] == STOP_CONTACT
        ids = g1.sensor_ids[g1.sensor_ids // SENSORS_PER_FINGER == f] % SENSORS_PER_FINGER
        assert len(ids) and ids.max() < 5  # proximal sensors only
        # Same proximal angle: it holds where it touched ...
        assert c1.proximal[f] == pytest.approx(c0.proximal[f], abs=1e-12)
        # ... and the tendon runs on to the end of the step it was commanded, the distal
        # taking that travel (wrapped beyond the free coupling).
        assert c1.spool[f] == pytest.approx(step * round(c1.spool[f] / step), abs=1e-9)
        assert c1.spool[f] > c0.spool[f] + 1e-6
        assert c1.distal[f] - c0.distal[f] == pytest.approx(c1.spool[f] - c0.spool[f])
        assert c1.distal[f] > k * c1.proximal[f] + 1e-3


def test_post_contact_travel_presses_firmer_but_no_deeper_than_the_skin() -> None:
    r = 0.06
    for gap in (0.01, 0.02, 0.03):
        pose = Pose([-(r + PAD + gap), 0, 0], SIDE)
        seen = {}
        for travel in (0.0, 0.05):
            with SimWorld(SimConfig(post_contact_travel_rad=travel)) as w:
                w.place_primitive("sphere", r)
                hand = SimHand(w)
                g = grasp_at(SimArm(w), hand, pose)
                assert hand.last_close.stop_reasons == (STOP_CONTACT,) * 3
                deepest = w.hand_contacts().depth.max()
                assert deepest <= hand.cfg.skin_depth_m + 1e-9
                seen[travel] = (g.pressures.sum(), g.n_contacts, deepest, hand.last_close.spool)
        (p0, n0, d0, s0), (p1, n1, d1, s1) = seen[0.0], seen[0.05]
        assert p1 > p0 and n1 >= n0 >= 3 and d1 >= d0
        assert np.all(s1 >= s0) and np.any(s1 > s0)


def test_state_reports_the_grasp_contacts(rig) -> None:
    w, arm, hand = rig
    w.place_primitive("sphere", 0.06)
    g = grasp_at(arm, hand, Pose([-(0.06 + PAD + 0.01), 0, 0], SIDE))
    st = hand.state()
    np.testing.assert_array_equal(st.contact, st.pressures > hand.cfg.contact_threshold)
    assert set(np.flatnonzero(st.contact)) == set(g.sensor_ids.tolist())
    np.testing.assert_allclose(st.finger_angles, g.finger_angles)
    hand.open()
    assert not hand.state().contact.any()


def test_unsensed_contact_stalls_instead_of_passing_through(rig) -> None:
    w, arm, _ = rig
    cfg = dataclasses.replace(w.cfg, contact_threshold=1e9)  # nothing is ever sensed
    hand = SimHand(w, cfg)
    w.place_primitive("sphere", 0.06)
    g = grasp_at(arm, hand, Pose([-(0.06 + PAD + 0.01), 0, 0], SIDE))
    assert g.n_contacts == 0
    assert hand.last_close.stop_reasons == (STOP_STALL,) * 3
    free = cfg.spool_limit_rad / (1 + cfg.flexure_coupling)
    assert np.all(g.finger_angles < free - 0.3)
    w.set_hand(w.preshape_angle, hand.last_close.proximal, hand.last_close.distal)
    assert w.hand_contacts().depth.max() <= cfg.stall_depth_m + 1e-9


def _grasps(seed: int, mode: str, poses: list[Pose]) -> list[Grasp]:
    cfg = SimConfig(seed=seed, noise_mode=mode)
    with SimWorld(cfg) as w:
        arm, hand = SimArm(w), SimHand(w)
        w.place_primitive("sphere", 0.06)
        return [grasp_at(arm, hand, p) for p in poses]


def _equal(a: Grasp, b: Grasp) -> bool:
    return (
        np.array_equal(a.sensor_ids, b.sensor_ids)
        and np.array_equal(a.xyz, b.xyz)
        and np.array_equal(a.pressures, b.pressures)
        and np.array_equal(a.finger_angles, b.finger_angles)
    )


@pytest.mark.parametrize("mode", ["pose", "stream"])
def test_equal_seeds_give_equal_grasps(mode: str) -> None:
    poses = [
        Pose([-(0.06 + PAD + 0.01), 0, 0], SIDE),
        Pose([-(0.06 + PAD + 0.02), 0.01, 0.0], SIDE),
    ]
    a, b, c = _grasps(7, mode, poses), _grasps(7, mode, poses), _grasps(8, mode, poses)
    assert all(_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x.pressures, y.pressures) for x, y in zip(a, c, strict=True))


def test_pose_seeded_noise_does_not_depend_on_earlier_grasps() -> None:
    first = Pose([-(0.06 + PAD + 0.01), 0, 0], SIDE)
    second = Pose([0, 0, 0.06 + PAD + 0.02], TOP)
    alone = _grasps(3, "pose", [second])[0]
    after = _grasps(3, "pose", [first, second])[1]
    assert _equal(alone, after)


def test_preshape_out_of_range_is_refused(rig) -> None:
    _, _, hand = rig
    with pytest.raises(ValueError):
        hand.preshape(2.0)
    with pytest.raises(ValueError):
        hand.preshape(-0.1)


def test_bench_main_writes_its_figures(tmp_path) -> None:
    from activetouch.sim import bench

    out = tmp_path / "sim.json"
    argv = ["--grasps", "4", "--grid-object", "primitive:sphere", "--set", "grid.step_deg=45"]
    assert bench.main([*argv, "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["grasps"]["poses"] == 4
    assert figures["grasps"]["grasped"] + figures["grasps"]["unreachable"] == 4
    assert figures["peak_rss_mb"] > 0
    grid = figures["grid"]
    assert grid["object"] == "primitive:sphere" and grid["grasped"] > 0
    assert grid["grasped"] == round((1 - grid["unreachable_fraction"]) * grid["poses"])
    histogram = [int(v) for v in grid["contacts_histogram"].split()]
    assert sum(histogram) == grid["grasped"] and len(histogram) == grid["max_contacts"] + 1
    assert grid["mean_contacts"] == pytest.approx(
        sum(i * v for i, v in enumerate(histogram)) / grid["grasped"]
    )
    # Enclosing a sphere touches it with every finger: every grasp gives triangles.
    assert grid["grasps_with_3plus_contacts"] == 1.0 and grid["mean_fingers_touching"] > 2.5


def test_stop_ends_a_running_guarded_close_within_one_step(rig) -> None:
    """From another thread, as the hand node's stop does: the close raises at its next spool
    step, the fingers stay where they were, and closing is refused until the stop is cleared."""
    import threading

    from activetouch.errors import StoppedError

    w, arm, hand = rig
    w.place_primitive("sphere", 0.06)
    twin_wrist(arm).move_to(Pose([-(0.06 + PAD + 0.01), 0, 0], SIDE))
    steps: list[np.ndarray] = []
    real_set_hand = w.set_hand

    def counting_set_hand(preshape, proximal, distal):
        steps.append(np.asarray(proximal).copy())
        if len(steps) == 3:  # mid-close: the operator hits stop
            stopper = threading.Thread(target=hand.stop)
            stopper.start()
            stopper.join(30.0)  # the stop lands before the next step (30 s: a hang bound)
            assert not stopper.is_alive()
        real_set_hand(preshape, proximal, distal)

    w.set_hand = counting_set_hand
    with pytest.raises(StoppedError, match="guarded close"):
        hand.guarded_close()
    assert len(steps) == 3  # not one spool step after the stop
    w.set_hand = real_set_hand
    with pytest.raises(StoppedError):
        hand.guarded_close()
    hand.open()  # releasing stays allowed
    hand.clear_stop()
    assert hand.guarded_close().n_contacts >= 3


def test_stall_sensing_reports_one_distal_contact_per_stopped_finger() -> None:
    # The ReFlex SF's grasp in the twin: no tactile sensors, a finger that stopped against the
    # object gives one contact at its distal site (drivers/reflex/sf.py reports the same).
    r = 0.06
    cfg = dataclasses.replace(SimConfig(), sensing="stall", stall_contact_site=6)
    with SimWorld(cfg) as w:
        arm, hand = SimArm(w), SimHand(w)
        tactile = SimHand(w, dataclasses.replace(cfg, sensing="tactile"))
        w.place_primitive("sphere", r)
        pose = Pose([-(r + PAD + 0.005), 0, 0], SIDE)
        g = grasp_at(arm, hand, pose)
        assert hand.last_close.stop_reasons == (STOP_CONTACT,) * 3
        assert g.sensor_ids.tolist() == [6, 15, 24]
        np.testing.assert_allclose(g.xyz, w.sensor_sites_hand()[[6, 15, 24]])
        assert np.all(g.pressures > 0)  # the fingers press: their load stands in for pressure
        # The same close as the tactile hand's: only what is reported differs.
        full = grasp_at(arm, tactile, pose)
        assert tactile.last_close.stop_reasons == hand.last_close.stop_reasons
        assert len(full.sensor_ids) > 3
        w.clear()
        empty = grasp_at(arm, hand, Pose([0, 0, 0.3], TOP))  # nothing there: fingers at their limit
        assert empty.n_contacts == 0
        assert hand.last_close.stop_reasons == (STOP_LIMIT,) * 3


def test_the_hand_keeps_robot_time() -> None:
    # A close takes one spool step per control period; opening runs at the servos' speed.
    cfg = SimConfig()
    with SimWorld(cfg) as w:
        arm, hand = SimArm(w), SimHand(w)
        assert hand.robot_seconds == 0.0
        grasp_at(arm, hand, Pose([0, 0, 0.3], TOP))  # nothing to touch: to the spool limit
        steps = int(np.ceil(cfg.spool_limit_rad / cfg.spool_step_rad))
        assert hand.robot_seconds == pytest.approx((steps + 1) * cfg.hand_period_s)
        before = hand.robot_seconds
        hand.open()
        travel = cfg.spool_limit_rad - cfg.open_spool_rad
        assert hand.robot_seconds - before == pytest.approx(travel / cfg.finger_speed_rad_s)
        before = hand.robot_seconds
        hand.preshape(0.5)
        assert hand.robot_seconds - before == pytest.approx(0.5 / cfg.finger_speed_rad_s)
