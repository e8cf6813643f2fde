"""SimHand: guarded enclosure on primitives, tactile sensing, determinism."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from activetouch.config import SimConfig
from activetouch.interfaces import SENSORS_PER_FINGER, Grasp, Pose
from activetouch.sim.hand import STOP_CONTACT, STOP_LIMIT, STOP_STALL, SimHand, site_forces
from activetouch.sim.reflex_urdf import coupled_joints
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
    arm.move_wrist(pose)
    return hand.guarded_close()


def fingers_touched(g: Grasp) -> set[int]:
    return {int(i) // SENSORS_PER_FINGER for i in g.sensor_ids if i < 27}


def test_coupling_and_patch_assignment_are_pure_functions() -> None:
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
    sites = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.0, 0, 0]])
    site_link = np.array([1, 1, 2])
    radius = np.full(3, 0.006)
    # Two points on link 1 near site 1, one on link 2 but far from its site: not sensed.
    f = site_forces(
        np.array([1, 1, 2]),
        np.array([[0.009, 0, 0], [0.012, 0, 0], [0.0, 0.02, 0]]),
        np.array([0.001, 0.002, 0.005]),
        site_link,
        sites,
        radius,
        1000.0,
    )
    np.testing.assert_allclose(f, [0.0, 3.0, 0.0])


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
    assert bench.main(["--grasps", "4", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["grasps"]["poses"] == 4
    assert figures["grasps"]["grasped"] + figures["grasps"]["unreachable"] == 4
    assert figures["peak_rss_mb"] > 0
