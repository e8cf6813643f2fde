"""``hand.emulate = "twin"``: the TakkTile driver on its byte-level emulator, backed by the twin
world the floating arm moves in, made by the device layer as `serve` makes it."""

from __future__ import annotations

import numpy as np
import pytest

from activetouch.config import load_config
from activetouch.errors import ConfigError
from tests.waiting import wait_for

pytest.importorskip("pybullet")

EMULATED = [
    "hand.type=reflex-takktile",
    "hand.emulate=twin",
    # The emulator reads the twin world for each packet during a command; a loaded machine can
    # hold it longer than the 0.2 s default: late, not a lost stream (not under test here).
    "hand.stream_timeout_s=5.0",
]


def test_emulate_setting_is_checked_and_makes_the_hand_simulated():
    cfg = load_config(None, EMULATED)
    assert cfg.hand.simulated and cfg.arm.simulated  # serve: sim mode, sim/place served
    assert not load_config(None, ["hand.type=reflex-takktile"]).hand.simulated
    with pytest.raises(ConfigError, match=r"hand\.emulate"):
        load_config(None, ["hand.type=reflex-takktile", "hand.emulate=gazebo"])


@pytest.mark.slow
def test_recognition_through_driver_agrees_with_twin(trained_home):
    """Through the device layer as `serve` makes it: at the same wrist poses in the shared
    world, the driver (UDP, its own codec) on the emulator closes the same fingers to the same
    angles and feels the twin's sensors (a neighbour more or less: it reads at packet
    resolution); then a whole recognition runs through it and names an object."""
    from activetouch import paths
    from activetouch.devices import make_devices
    from activetouch.interfaces import Pose
    from activetouch.model import load_model
    from activetouch.objects.library import ObjectLibrary
    from activetouch.planning.policies import make_policy
    from activetouch.rigs.reflex_emulated import TwinEmulatedHand
    from activetouch.session.loop import RecognitionSession
    from activetouch.sim.devices import twin_rig
    from activetouch.sim.twin import open_twin

    obj, seed = "sphere", 1
    model = load_model(paths.default_model(trained_home))
    poses = np.concatenate([model.observation.pose_xyz, model.observation.pose_quat], axis=1)
    cfg = load_config(None, [*EMULATED, "session.max_moves=3"])
    spec = ObjectLibrary(paths.objects_dir(trained_home)).get(obj)
    devices = make_devices(cfg, trained_home)
    try:
        hand = devices.hand
        assert isinstance(hand, TwinEmulatedHand) and devices.simulated
        rig = twin_rig(devices.ctx)
        assert hand.fingers.world is rig.world  # the arm's world, not a copy
        devices.ctx.place(obj, seed)
        devices.wrist.set_placement(devices.placement())
        grasped = 0
        with open_twin(spec, cfg.sim, seed=seed, workcell=cfg.workcell) as twin:
            for pid in range(0, len(poses), max(1, len(poses) // 6)):
                pose = Pose.from_array(poses[pid])
                try:
                    twin.hand.open()
                    twin.wrist.move_to(pose)
                except Exception:
                    continue  # unreachable for the twin: skipped as the session does
                direct = twin.hand.guarded_close()
                hand.open()
                devices.wrist.move_to(pose)
                g = hand.guarded_close()
                grasped += 1
                assert np.allclose(g.finger_angles, direct.finger_angles, atol=0.04), pid
                a, b = set(direct.sensor_ids.tolist()), set(g.sensor_ids.tolist())
                # Light tip contacts sit near the threshold: noise decides a sensor or two.
                assert a == b or (a & b and len(a ^ b) <= 4), (pid, a, b)
                for i in a & b:  # same sensor, same place (mm)
                    da = direct.xyz[list(direct.sensor_ids).index(i)]
                    db = g.xyz[list(g.sensor_ids).index(i)]
                    assert np.linalg.norm(da - db) < 0.004, (pid, i)
        assert grasped >= 3
        hand.open()
        stats0 = hand.stats()
        res = RecognitionSession(
            hand,
            devices.wrist,
            model,
            make_policy("greedy", cfg.planner, model.observation, model.classifier.kernel()),
            cfg.session,
            np.random.default_rng(seed),
            support_z=rig.world.support_z,
        ).run()
        stats = hand.stats()
    finally:
        devices.close()
    assert res.moves >= 1 and res.label in model.class_names
    assert stats["accepted"] - stats0["accepted"] > 20  # every grasp paced by UDP packets


def test_emulator_reads_the_world_only_inside_commands():
    """Between driver commands the arm owns the world: the emulator must not touch it."""
    from activetouch.devices import make_devices

    devices = make_devices(load_config(None, EMULATED))
    try:
        hand = devices.hand
        hand.open()
        reads = hand.fingers.reads
        sent, accepted = hand.emulator.sent, hand.stats()["accepted"]
        # Packets go on between commands: the emulator makes one at a time, so past `sent` + 1
        # every one was made after `reads` was taken; the driver takes them.
        assert wait_for(
            lambda: (
                hand.emulator.sent >= sent + 5
                and hand.stats()["accepted"] >= accepted + 4
                and not hand.stale
            ),
            30.0,
        )
        assert hand.fingers.reads == reads
        hand.preshape(0.3)  # a few packets inside the command: the world follows
        assert hand.fingers.reads > reads
        assert abs(devices.ctx.shared("twin", lambda: None).world.preshape_angle - 0.3) < 0.06
    finally:
        devices.close()
