"""The Baxter twin (``arm.type = "twin-baxter"``): limits refused before moving, a latched stop
that ends a running trajectory, contacts stop the arm, the twin's hand is where pinocchio puts
Baxter's hand, and a whole recognition on ``hand.type=twin`` + ``arm.type=twin-baxter``."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from activetouch.clock import ManualClock
from activetouch.config import WorkcellConfig, load_config
from activetouch.errors import ConfigError, MotionBlockedError, StoppedError, UnreachableError
from activetouch.interfaces import JointTrajectory, Pose, StopLatch

ROOT = Path(__file__).resolve().parents[2]
BAXTER_TOML = ROOT / "deploy" / "baxter-twin.toml"
PALM_DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # hand z (palm normal) pointing down


@pytest.fixture(scope="module")
def baxter():
    pytest.importorskip("pinocchio")
    from activetouch.planning.motion.robot import load_arm

    return load_arm()


@pytest.fixture()
def twin(baxter):
    """A twin world with the Baxter workcell, a 0.1 m box on the table, and the arm."""
    from activetouch.sim.baxter import TwinBaxterArm, TwinBaxterArmConfig
    from activetouch.sim.world import SimWorld

    cfg = load_config(BAXTER_TOML)
    world = SimWorld(cfg.sim, workcell=cfg.workcell)
    world.place_primitive("box", (0.1, 0.1, 0.1))
    arm = TwinBaxterArm(world, baxter, TwinBaxterArmConfig())
    yield arm
    world.close()


def line(q0: np.ndarray, q1: np.ndarray, seconds: float, names) -> JointTrajectory:
    t = np.linspace(0.0, seconds, 51)
    f = (t / seconds)[:, None]
    return JointTrajectory(tuple(names), t, q0 + (q1 - q0) * f)


def solve(baxter, xyz, quat=PALM_DOWN) -> np.ndarray:
    """An IK solution for the hand at `xyz`, `quat` (base frame) near the ready pose."""
    from activetouch.planning.motion.ik import IKSolver
    from activetouch.planning.motion.robot import pose_to_se3

    q = IKSolver(baxter, None, restarts=30).solve(pose_to_se3(Pose(xyz, quat)), baxter.ready)
    assert q is not None
    return q


def world_hand_pose(world) -> tuple[np.ndarray, np.ndarray]:
    """The hand base frame as PyBullet has it (its base pose minus the COM offset)."""
    from activetouch.sim.pybullet import pb

    com_pos, com_orn = pb.getBasePositionAndOrientation(world.hand, physicsClientId=world.cid)
    inv_pos, inv_orn = pb.invertTransform(world._com_pos, world._com_orn)
    pos, orn = pb.multiplyTransforms(com_pos, com_orn, inv_pos, inv_orn)
    return np.array(pos), np.array(orn)


def test_config_is_light_and_the_default_workcell_is_refused() -> None:
    code = (
        "import sys; from activetouch.config import load_config; "
        f"c = load_config({str(BAXTER_TOML)!r}, ['arm.motion.side=right', 'arm.time_scale=1']); "
        "assert c.arm.motion.side == 'right' and c.arm.time_scale == 1.0; "
        "print('pybullet' in sys.modules, 'pinocchio' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
    with pytest.raises(ConfigError, match=r"arm\.sample_dt"):
        load_config(BAXTER_TOML, ["arm.sample_dt=0.05"])
    from activetouch.sim.baxter import check_object_xy

    with pytest.raises(ConfigError, match="inside Baxter"):
        check_object_xy(WorkcellConfig())  # the default workcell: object at the origin
    check_object_xy(load_config(BAXTER_TOML).workcell)


def test_hand_in_the_world_is_where_pinocchio_puts_it(twin, baxter) -> None:
    from activetouch.planning.motion.robot import hand_pose

    data = baxter.model.createData()
    q1 = solve(baxter, [0.6, 0.25, 0.15])
    twin.execute(line(twin.joint_state().position, q1, 2.0, twin.joint_names))
    np.testing.assert_allclose(twin.joint_state().position, q1, atol=1e-12)
    fk = hand_pose(baxter, data, q1)
    pos, orn = world_hand_pose(twin.world)
    assert np.linalg.norm(pos - fk.xyz) < 1e-6  # issue 11: within 1 mm
    assert abs(abs(float(orn @ fk.quat)) - 1.0) < 1e-9
    # ... and in the object frame, which is where a grasp's contacts are read.
    obj = twin.world.wrist_pose
    np.testing.assert_allclose(obj.xyz + twin.world.object_origin, fk.xyz, atol=1e-9)
    assert twin.samples_checked > 200  # 2 s at <= 10 ms, hand steps <= 1 cm


def test_out_of_limit_trajectories_are_refused_before_moving(twin) -> None:
    q0 = twin.joint_state().position
    hand0 = twin.world.wrist_pose
    far = q0.copy()
    far[1] = twin.limits.upper[1] + 0.1  # s1 past its limit
    with pytest.raises(UnreachableError, match="left_s1"):
        twin.execute(line(q0, far, 2.0, twin.joint_names))
    fast = q0.copy()
    fast[0] += 1.0
    traj = line(q0, fast, 2.0, twin.joint_names)
    traj = JointTrajectory(traj.names, traj.times, traj.positions, np.full((51, 7), 9.0))
    with pytest.raises(UnreachableError, match="velocity"):
        twin.execute(traj)
    away = q0 + 0.2
    with pytest.raises(UnreachableError, match=r"starts 0\.200 rad from"):
        twin.execute(line(away, away, 1.0, twin.joint_names))
    np.testing.assert_array_equal(twin.joint_state().position, q0)
    assert twin.world.wrist_pose == hand0
    assert twin.samples_checked == 0


def test_a_contact_stops_the_arm_at_the_last_free_sample(twin, baxter) -> None:
    q0 = twin.joint_state().position
    above = solve(baxter, [0.6, 0.25, 0.1])  # the box's top is at -0.08
    twin.execute(line(q0, above, 2.0, twin.joint_names))
    # Straight down into the box: the hand meets it (the world's check, not the planner's).
    into = solve(baxter, [0.6, 0.25, -0.1])
    with pytest.raises(MotionBlockedError, match=r"blocked at t = .*object") as blocked:
        twin.execute(line(above, into, 2.0, twin.joint_names))
    # The trajectory time it moved before the contact (robot time spent, the pose not reached).
    at = float(re.search(r"t = ([0-9.]+) s", str(blocked.value)).group(1))
    assert 0.0 < blocked.value.executed_s <= at <= 2.0
    stopped = twin.joint_state().position
    assert not np.allclose(stopped, into, atol=1e-3) and not np.allclose(stopped, above)
    assert twin.collision_reason(stopped) is None
    # The table: a robot link or the hand against it is named by the coal check.
    low = baxter.ready.copy()
    low[1] += 0.8  # the shoulder pitches down: the arm swings through the table top
    twin.home()
    with pytest.raises(UnreachableError, match=r"blocked .*table"):
        twin.execute(line(baxter.ready, low, 3.0, twin.joint_names))


def test_stop_is_latched_and_ends_a_running_trajectory_within_a_sample(twin, baxter) -> None:
    q0 = twin.joint_state().position
    q1 = solve(baxter, [0.6, 0.25, 0.15])
    twin.stop()
    with pytest.raises(StoppedError):
        twin.execute(line(q0, q1, 2.0, twin.joint_names))
    np.testing.assert_array_equal(twin.joint_state().position, q0)
    twin.clear_stop()
    # Real time on a manual clock: a 2 s trajectory takes 2 s of it, and the stop comes at 0.3 s
    # of it whatever the machine's load.
    clock = ManualClock()
    twin.clock, twin.stop_latch = clock, StopLatch(clock)
    twin.cfg.time_scale = 1.0
    clock.call_at(0.3, twin.stop)
    with pytest.raises(StoppedError):
        twin.execute(line(q0, q1, 2.0, twin.joint_names))
    assert clock.now - 0.3 <= twin.cfg.sample_dt + 1e-9  # within one sample of the stop
    q_stop = twin.joint_state().position
    assert not np.allclose(q_stop, q0) and not np.allclose(q_stop, q1)
    with pytest.raises(StoppedError):  # still stopped
        twin.execute(line(q_stop, q1, 1.0, twin.joint_names))
    twin.clear_stop()
    twin.cfg.time_scale = 0.0
    twin.execute(line(q_stop, q1, 1.0, twin.joint_names))
    np.testing.assert_allclose(twin.joint_state().position, q1, atol=1e-12)


@pytest.mark.slow
def test_recognition_on_the_twin_hand_and_the_baxter_twin(trained_home, small_model) -> None:
    """The whole session (Alg. 2) on make_devices(hand twin, arm twin-baxter): grasps happen
    where Baxter's hand is, unreachable training poses are skipped, robot seconds add up."""
    from activetouch.devices import make_devices
    from activetouch.planning.motion.robot import hand_pose
    from activetouch.planning.policies import make_policy
    from activetouch.session.loop import RecognitionSession

    cfg = load_config(BAXTER_TOML, ["session.max_skips=200"])
    devices = make_devices(cfg, trained_home)
    try:
        assert devices.simulated and devices.ctx.place is not None
        devices.ctx.place("cup", 0)
        devices.wrist.set_placement(devices.placement())
        placement = devices.placement()
        assert np.linalg.norm(placement.xyz[:2] - [0.6, 0.25]) < 1e-9
        model = small_model
        policy = make_policy("tree", cfg.planner, model.observation, model.classifier.kernel())
        session = RecognitionSession(
            devices.hand,
            devices.wrist,
            model,
            policy,
            type(cfg.session)(max_moves=4, confidence=1.1, max_skips=200),
            np.random.default_rng(0),
            support_z=placement.support_z(cfg.workcell.table_top_z),
        )
        res = session.run()
        wrist = devices.wrist
        assert res.moves == 4, res.stop_reason
        assert sum(len(c) for c in res.contacts) >= 3  # the hand felt the cup
        assert wrist.moves == 4 and 4 * 1.0 < wrist.robot_seconds < 4 * 15.0
        # The last grasp was at the training pose, in the object frame, by Baxter's hand.
        last = model.observation.pose_xyz[res.pose_ids[-1]]
        arm = devices.arm.inner
        q = arm.joint_state().position
        at = placement.to_object(hand_pose(arm.model, arm.model.model.createData(), q))
        assert np.linalg.norm(at.xyz - last) < 1e-3
        assert np.linalg.norm(arm.world.wrist_pose.xyz - at.xyz) < 1e-6
    finally:
        devices.close()


def test_place_homes_the_arm_through_the_rigs_after_place_hook(trained_home, baxter) -> None:
    """twin-baxter hooks its homing into `TwinRig.after_place` (ctx.place stays the rig's)."""
    from activetouch.devices import DeviceContext
    from activetouch.sim.baxter import BAXTER_MODEL
    from activetouch.sim.devices import TWIN

    cfg = load_config(BAXTER_TOML)
    ctx = DeviceContext(cfg, trained_home)
    ctx.shared(BAXTER_MODEL, lambda: baxter)  # the module's model: no second load
    try:
        arm = cfg.arm.make(ctx).inner  # the arm alone: no motion layer needed here
        rig = ctx.shared(TWIN, lambda: pytest.fail("no twin rig"))
        assert ctx.place == rig.place and rig.after_place == [arm.home]
        ready = arm.model.ready.copy()
        q = ready + 0.1
        arm.execute(line(ready, q, 1.0, arm.joint_names))
        assert np.abs(arm.joint_state().position - q).max() < 1e-9
        ctx.place("cup", 0)
        np.testing.assert_allclose(arm.joint_state().position, ready, atol=1e-12)
    finally:
        ctx.close()


@pytest.mark.slow
def test_recognize_cli_on_the_baxter_twin_reports_robot_seconds(trained_home, capsys) -> None:
    """`activetouch recognize --set arm.type=twin-baxter` (the default workcell becomes
    Baxter's, as in deploy/baxter-twin.toml): the poses Baxter cannot reach are ruled out
    first, the JSON has the robot time."""
    from activetouch.cli.main import main

    common = ["recognize", "--object", "cup", "--data", str(trained_home)]
    common += ["--set", "arm.type=twin-baxter", "--set", "grid.step_deg=40"]
    assert main([*common, "--json", "--max-moves", "4"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert 1 <= doc["moves"] <= 4 and doc["unreachable"] > 0 and doc["skipped"] == 0
    assert doc["motion_s"] > 1.0 * doc["moves"]  # seconds per Baxter move, not a teleport
    assert doc["grasp_s"] > 0.3 * doc["moves"]  # the twin hand's robot time, not its wall time
    assert doc["motion_planning_s"] > 0
    assert doc["planning_s"] == pytest.approx(doc["search_s"] + doc["motion_planning_s"])
    assert doc["total_s"] == pytest.approx(doc["motion_s"] + doc["grasp_s"] + doc["planning_s"])
    common += ["--config", str(BAXTER_TOML)]  # the same workcell, written out
    assert main([*common, "--max-moves", "2"]) == 0
    out = capsys.readouterr().out
    assert "robot time:" in out and "moving" in out and "out of the arm's reach" in out
