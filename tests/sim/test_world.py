"""SimWorld / SimArm: lifetime, URDF kinematics, objects, reachability of wrist poses."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest
from scipy.spatial.transform import Rotation

from activetouch.config import SimConfig
from activetouch.errors import ActiveTouchError, StoppedError, UnreachableError
from activetouch.interfaces import JointTrajectory, Pose
from activetouch.models.reflex import (
    DISTAL_SENSOR_X_GAZEBO,
    DISTAL_SENSOR_Z_GAZEBO,
    ReflexGeometry,
    build_urdf,
    finger_link_transforms,
    geometry_with_distal_sites,
    sensor_link_name,
    sensor_positions,
    urdf_file,
)
from activetouch.sim.twin import twin_wrist
from activetouch.sim.world import (
    WRIST_JOINTS,
    SimArm,
    SimWorld,
    pose_to_wrist_joints,
    wrist_joints_to_pose,
)

TOP = np.array([1.0, 0.0, 0.0, 0.0])  # hand +z pointing down


def side_quat() -> np.ndarray:
    """Hand +z along world +x, hand x horizontal (world y): fingers close sideways."""
    return Rotation.from_matrix(np.column_stack([[0, 1, 0], [0, 0, 1], [1, 0, 0]])).as_quat()


@pytest.fixture
def world():
    with SimWorld() as w:
        yield w


@pytest.mark.parametrize(
    "geom",
    [
        ReflexGeometry(),
        geometry_with_distal_sites(DISTAL_SENSOR_X_GAZEBO, DISTAL_SENSOR_Z_GAZEBO, 0.28),
    ],
)
def test_numpy_kinematics_match_the_urdf_in_pybullet(geom: ReflexGeometry, tmp_path) -> None:
    """sensor_positions equals PyBullet's frames of the URDF's sensor-site links."""
    rng = np.random.default_rng(3)
    c = pb.connect(pb.DIRECT)
    try:
        hand = pb.loadURDF(str(urdf_file(geom, tmp_path, sensor_links=True)), physicsClientId=c)
        joint, link = {}, {}
        for j in range(pb.getNumJoints(hand, physicsClientId=c)):
            info = pb.getJointInfo(hand, j, physicsClientId=c)
            joint[info[1].decode()], link[info[12].decode()] = j, j
        for _ in range(5):
            pre = rng.uniform(0, 1.6)
            prox, dist = rng.uniform(0, 2.5, 3), rng.uniform(0, 1.5, 3)
            values = {"preshape_1": pre, "preshape_2": -pre}
            for f in range(3):
                values[f"proximal_{f + 1}"], values[f"distal_{f + 1}"] = prox[f], dist[f]
            for name, v in values.items():
                pb.resetJointState(hand, joint[name], v, physicsClientId=c)
            got = np.array(
                [
                    pb.getLinkState(
                        hand,
                        link[sensor_link_name(s)],
                        computeForwardKinematics=True,
                        physicsClientId=c,
                    )[4]
                    for s in range(38)
                ]
            )
            # loadURDF puts the URDF base frame at the origin: world = hand frame.
            np.testing.assert_allclose(got, sensor_positions(geom, pre, prox, dist), atol=2e-6)
    finally:
        pb.disconnect(c)


def test_world_sites_follow_the_configured_geometry() -> None:
    cfg = SimConfig(
        distal_sensor_x=list(DISTAL_SENSOR_X_GAZEBO),
        distal_sensor_z=list(DISTAL_SENSOR_Z_GAZEBO),
        proximal_zero_pitch_rad=0.28,
    )
    with SimWorld(cfg) as w:
        assert w.geometry.distal_sensor_x == DISTAL_SENSOR_X_GAZEBO
        w.set_hand(0.5, np.array([0.1, 0.2, 0.3]), np.array([0.4, 0.5, 0.6]))
        np.testing.assert_allclose(
            w.sensor_sites_hand(),
            sensor_positions(w.geometry, 0.5, [0.1, 0.2, 0.3], [0.4, 0.5, 0.6]),
        )
        # The loaded body's distal links sit where the numpy kinematics put them.
        state = pb.getLinkState(
            w.hand, w.links.distal[2], computeForwardKinematics=True, physicsClientId=w.cid
        )
        _, t_dist = finger_link_transforms(w.geometry, 2, 0.5, 0.3, 0.6)
        np.testing.assert_allclose(w.world_to_hand(np.array(state[4])), t_dist[:3, 3], atol=2e-6)


def test_geometry_follows_the_hardware_facts() -> None:
    g = ReflexGeometry()
    sites = sensor_positions(g, 0.0, np.zeros(3), np.zeros(3))
    # Open (0) fingers lie flat: proximal sensors of finger 0 at the proximal joint
    # (0.0504 + 0.01, -0.026, 0.063 + 0.0186) plus the site offsets.
    np.testing.assert_allclose(sites[0], [0.0604 + 0.0189, -0.026, 0.0816 + 0.0154])
    np.testing.assert_allclose(sites[8, 0], 0.0604 + 0.076 + 0.0375)
    # The thumb points the other way; the palm sites are at z = 0.082.
    np.testing.assert_allclose(sites[18], [-0.03 - 0.0189, 0.0, 0.0816 + 0.0154], atol=1e-12)
    np.testing.assert_allclose(sites[27:, 2], 0.082)
    # Closing by pi/2 turns the proximal sensors to face the palm centre (-x for finger 0).
    closed = sensor_positions(g, 0.0, np.full(3, np.pi / 2), np.zeros(3))
    np.testing.assert_allclose(closed[0], [0.0604 - 0.0154, -0.026, 0.0816 + 0.0189], atol=1e-12)
    # Preshape swivels fingers 0 and 1 in opposite senses; the thumb does not move.
    pre = sensor_positions(g, 0.8, np.zeros(3), np.zeros(3))
    assert pre[4, 1] < sites[4, 1] and pre[13, 1] > sites[13, 1]
    np.testing.assert_allclose(pre[18:27], sites[18:27])
    text = build_urdf(g)
    assert text.count("<link ") == 1 + 1 + 2 + 3 + 3 + 38
    assert '<mass value="0.017"/>' in text and '<mass value="0.271"/>' in text


def test_worlds_are_independent_and_close_disconnects() -> None:
    a, b = SimWorld(), SimWorld()
    try:
        assert a.cid != b.cid
        a.place_primitive("sphere", 0.05)
        assert a.object is not None and b.object is None
        assert pb.getNumBodies(physicsClientId=b.cid) == 2  # table + hand
    finally:
        a.close()
    assert a.client is None
    with pytest.raises(ActiveTouchError):
        _ = a.cid
    b.close()
    b.close()  # idempotent


def test_primitives_stand_on_the_table_and_clear(world: SimWorld) -> None:
    body = world.place_primitive("cylinder", (0.03, 0.2))
    np.testing.assert_allclose(world.object_origin, [0, 0, 0.1])
    lo, hi = pb.getAABB(body, physicsClientId=world.cid)
    assert abs(lo[2]) < 1e-6 and abs(hi[2] - 0.2) < 1e-6
    world.place_primitive("box", (0.05, 0.06, 0.07))
    np.testing.assert_allclose(world.object.extents, [0.05, 0.06, 0.07])
    assert pb.getNumBodies(physicsClientId=world.cid) == 3  # the cylinder is gone
    world.clear()
    assert world.object is None and pb.getNumBodies(physicsClientId=world.cid) == 2
    np.testing.assert_allclose(world.object_origin, 0.0)
    with pytest.raises(ValueError):
        world.place_primitive("cone", 0.1)


def test_wrist_pose_is_in_the_object_frame(world: SimWorld) -> None:
    world.place_primitive("sphere", 0.05)
    arm = SimArm(world)
    pose = Pose([0.0, 0.0, 0.2], TOP)
    twin_wrist(arm).move_to(pose)
    pos, _ = world.wrist_world()
    np.testing.assert_allclose(pos, [0, 0, 0.25])
    # The pad (hand z = 0.0896) is below the hand origin, facing the sphere.
    pad_world = world.hand_to_world(np.array([0.0, 0.0, 0.0896]))
    np.testing.assert_allclose(pad_world, [0, 0, 0.25 - 0.0896], atol=1e-12)
    js = arm.joint_state()
    assert js.names == WRIST_JOINTS
    np.testing.assert_allclose(
        # The arm's joints are the hand pose in the world (base) frame, not the object frame.
        wrist_joints_to_pose(js.position).as_array(),
        Pose([0.0, 0.0, 0.25], TOP).as_array(),
        atol=1e-12,
    )


def test_wrist_joint_conversions_round_trip() -> None:
    for q in Rotation.random(5, random_state=1).as_quat():
        pose = Pose([0.1, 0.2, 0.3], q)
        back = wrist_joints_to_pose(pose_to_wrist_joints(pose))
        assert abs(abs(np.dot(back.quat, pose.quat)) - 1) < 1e-12
        np.testing.assert_allclose(back.xyz, pose.xyz)


def test_move_wrist_into_the_table_raises_and_leaves_the_hand(world: SimWorld) -> None:
    arm = SimArm(world)
    start = Pose([0.0, 0.0, 0.3], TOP)
    twin_wrist(arm).move_to(start)
    # Palm down, pad 2 cm into the table.
    with pytest.raises(UnreachableError, match="table"):
        twin_wrist(arm).move_to(Pose([0.0, 0.0, 0.0896 - 0.02], TOP))
    np.testing.assert_allclose(world.wrist_pose.as_array(), start.as_array(), atol=1e-12)
    # Entirely under the table.
    with pytest.raises(UnreachableError, match="below the table"):
        twin_wrist(arm).move_to(Pose([0.0, 0.0, -0.09], TOP))
    # Just touching is allowed (within the tolerance).
    twin_wrist(arm).move_to(Pose([0.0, 0.0, 0.0896 + 0.0074 + 0.0005], TOP))


def test_below_the_table_test_is_for_teleports_only(world: SimWorld) -> None:
    # A hand teleported wholly under the table touches nothing there: only the bounding-box
    # test sees it. An arm moving in small steps (below_table=False) relies on contacts,
    # which stay exact: the pad 2 cm into the table is refused either way.
    assert world.check_hand_pose(Pose([0.0, 0.0, -0.3], TOP)) is not None
    world.set_wrist(Pose([0.0, 0.0, -0.3], TOP))
    assert "below the table" in world.collision_reason()
    assert world.collision_reason(below_table=False) is None
    world.set_wrist(Pose([0.0, 0.0, 0.0896 - 0.02], TOP))
    assert "penetrates the table" in world.collision_reason(below_table=False)


def test_move_wrist_into_the_object_raises(world: SimWorld) -> None:
    world.place_primitive("box", (0.08, 0.08, 0.1))
    arm = SimArm(world)
    with pytest.raises(UnreachableError, match="object"):
        twin_wrist(arm).move_to(Pose([0.0, 0.0, 0.05 + 0.0896 - 0.01], TOP))
    assert arm.check_pose(Pose([0.0, 0.0, 0.05 + 0.0896 + 0.02], TOP)) is None
    assert "object" in arm.check_pose(Pose([0.0, 0.0, 0.05], TOP))


def test_execute_follows_and_stops_before_collisions(world: SimWorld) -> None:
    world.place_primitive("box", (0.08, 0.08, 0.1))
    arm = SimArm(world, path="straight")
    twin_wrist(arm).move_to(Pose([0.0, 0.0, 0.3], TOP))
    names = ("wrist_yaw", "wrist_x", "wrist_y", "wrist_z", "wrist_roll", "wrist_pitch")
    q0 = arm.joint_state().position  # the hand in the world: the object stands at z = 0.05
    np.testing.assert_allclose(q0[:3], [0.0, 0.0, 0.35], atol=1e-9)
    goal = q0.copy()
    goal[0] = 0.1
    reorder = [WRIST_JOINTS.index(n) for n in names]
    traj = JointTrajectory(names, np.array([0.0, 1.0]), np.stack([q0, goal])[:, reorder])
    arm.execute(traj)
    np.testing.assert_allclose(world.wrist_pose.xyz, [0.1, 0.0, 0.3], atol=1e-9)
    down = goal.copy()
    down[2] = -0.1  # straight down through the box
    traj = JointTrajectory(WRIST_JOINTS, np.array([0.0, 2.0]), np.stack([goal, down]))
    with pytest.raises(UnreachableError, match="blocked"):
        arm.execute(traj)
    z = world.wrist_pose.xyz[2]
    assert 0.05 + 0.0896 - 0.01 < z < 0.3  # stopped above the box
    with pytest.raises(ActiveTouchError):
        arm.execute(JointTrajectory(("a",), np.zeros(1), np.zeros((1, 1))))


def test_execute_refuses_a_trajectory_outside_the_workspace_before_moving(
    world: SimWorld,
) -> None:
    arm = SimArm(world, path="straight")
    q0 = arm.joint_state().position
    far = q0.copy()
    far[0] = 1.0e6  # the probe of a careless client: it used to run 10^8 collision checks
    with pytest.raises(UnreachableError, match="wrist_x"):
        arm.execute(JointTrajectory(WRIST_JOINTS, np.array([0.0, 1.0]), np.stack([q0, far])))
    np.testing.assert_allclose(arm.joint_state().position, q0)


def test_a_stop_stays_in_force_until_cleared(world: SimWorld) -> None:
    arm = SimArm(world)
    q0 = arm.joint_state().position
    up = q0.copy()
    up[2] += 0.1
    traj = JointTrajectory(WRIST_JOINTS, np.array([0.0, 1.0]), np.stack([q0, up]))
    arm.stop()
    for _ in range(2):  # a queued execute does not clear it
        with pytest.raises(StoppedError):
            arm.execute(traj)
    np.testing.assert_allclose(arm.joint_state().position, q0)
    arm.clear_stop()
    arm.execute(traj)
    np.testing.assert_allclose(arm.joint_state().position, up, atol=1e-9)


def test_library_object_is_placed_by_its_spawner(world: SimWorld, tmp_path) -> None:
    objects = pytest.importorskip("activetouch.objects.library")
    lib = objects.ObjectLibrary(tmp_path / "objects")
    lib.ensure_builtins(["sphere"])
    spec = lib.get("sphere")
    world.place(spec)
    np.testing.assert_allclose(world.object_origin, [0, 0, spec.extents[2] / 2])
    arm = SimArm(world)
    with pytest.raises(UnreachableError):
        twin_wrist(arm).move_to(Pose([0.0, 0.0, 0.0], TOP))
    twin_wrist(arm).move_to(Pose([0.0, 0.0, spec.extents[2] / 2 + 0.0896 + 0.01], TOP))


def test_beside_the_table_the_hand_may_go_below_its_top() -> None:
    from activetouch.config import WorkcellConfig

    wc = WorkcellConfig(table_center=[0.0, 0.0, -0.025], table_size=[0.4, 0.4, 0.05])
    with SimWorld(workcell=wc) as w:
        arm = SimArm(w)
        # Palm down, 5 cm below the table top, beside the table (x = 0.5 m): allowed.
        assert arm.check_pose(Pose([0.5, 0.0, -0.05], TOP)) is None
        # The same height over the table: below its top.
        assert "below the table top" in arm.check_pose(Pose([0.0, 0.0, -0.05], TOP))
