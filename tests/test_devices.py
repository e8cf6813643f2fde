"""The device registry: typed sections from config, lazy imports, the fake devices, and a
whole daemon served on them without PyBullet."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from activetouch.config import load_config
from activetouch.device_types import HAND_TYPES
from activetouch.devices import make_devices
from activetouch.errors import ConfigError, StoppedError, UnreachableError
from activetouch.fakes.memory_arm import MemoryArm
from activetouch.fakes.replay import FakeHand
from activetouch.interfaces import JointTrajectory, Pose
from activetouch.planning.motion.floating import WRIST_JOINTS

FACES_DOWN = [1.0, 0.0, 0.0, 0.0]


def test_types_and_their_settings_come_from_config() -> None:
    cfg = load_config(None, ["hand.type=fake", "hand.close_s=0.5", "arm.type=fake"])
    assert cfg.hand.type == "fake" and cfg.hand.close_s == 0.5
    assert cfg.arm.type == "fake"
    default = load_config()
    assert (default.hand.type, default.arm.type) == ("twin", "twin-floating")
    assert default.arm.path == "teleport"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["hand.type=gripper"], "unknown hand type 'gripper'"),
        (["hand.close_s=1"], "unknown setting 'hand.close_s' of hand type 'twin'"),
        (["hand.type=fake", "hand.close_s=-1"], "hand.close_s must be >= 0"),
        (["arm.path=wobbly"], "arm.path: 'wobbly' is not one of"),
        (["workcell.table_size=[1, 0, 1]"], "workcell.table_size must be positive"),
    ],
)
def test_bad_device_settings_are_one_clear_error(overrides: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(None, overrides)


def test_a_config_file_sets_device_sections(tmp_path: Path) -> None:
    p = tmp_path / "robot.toml"
    p.write_text('[hand]\ntype = "fake"\nmatch_m = 0.02\n[arm]\ntype = "fake"\ntime_scale = 1\n')
    cfg = load_config(p, ["arm.time_scale=0.5"])
    assert cfg.hand.match_m == 0.02 and cfg.arm.time_scale == 0.5


def test_a_type_whose_module_is_missing_says_so(monkeypatch) -> None:
    monkeypatch.setitem(HAND_TYPES, "ghost", "activetouch.drivers.nowhere:GhostConfig")
    with pytest.raises(ConfigError, match="'ghost' is not available in this build"):
        load_config(None, ["hand.type=ghost"])


def test_fake_arm_checks_limits_before_moving_and_keeps_a_stop() -> None:
    cfg = load_config(None, ["hand.type=fake", "arm.type=fake"])
    devices = make_devices(cfg)
    arm = devices.arm
    assert isinstance(arm, MemoryArm) and isinstance(devices.hand, FakeHand)
    q0 = arm.joint_state().position
    far = q0.copy()
    far[0] = 1e308
    with pytest.raises(UnreachableError, match="wrist_x"):
        arm.execute(JointTrajectory(WRIST_JOINTS, np.array([0.0, 1.0]), np.stack([q0, far])))
    np.testing.assert_array_equal(arm.joint_state().position, q0)
    arm.stop()
    with pytest.raises(StoppedError):
        devices.wrist.move_to(Pose([0.0, 0.0, 0.3], FACES_DOWN))
    arm.clear_stop()
    devices.wrist.move_to(Pose([0.0, 0.0, 0.3], FACES_DOWN))
    np.testing.assert_allclose(arm.joint_state().position[:3], [0.0, 0.0, 0.3])
    devices.close()


def test_fake_hand_replays_the_dataset_grasp_at_the_wrist_pose(trained_home: Path) -> None:
    from activetouch import paths
    from activetouch.recognition.dataset import Dataset

    cfg = load_config(None, ["hand.type=fake", "arm.type=fake"])
    devices = make_devices(cfg, trained_home)
    assert devices.simulated and devices.ctx.place is not None
    devices.ctx.place("cup")
    devices.wrist.set_placement(devices.placement())
    stored = Dataset.open(paths.default_dataset(trained_home)).read("cup")
    i = int(np.argmax([g.n_contacts for g in stored.grasps]))
    devices.wrist.move_to(Pose.from_array(stored.poses[i]))
    g = devices.hand.guarded_close()
    np.testing.assert_array_equal(g.sensor_ids, stored.grasps[i].sensor_ids)
    np.testing.assert_allclose(g.xyz, stored.grasps[i].xyz)
    # Far from every stored pose: nothing felt.
    devices.wrist.move_to(Pose([0.0, 0.0, 0.9], FACES_DOWN))
    assert devices.hand.guarded_close().n_contacts == 0
    devices.close()


FAKE_SERVE = """
import json, sys, threading
from pathlib import Path
from activetouch.config import load_config
from activetouch.daemon.process import DaemonOptions, serve
from activetouch.daemon.client import open_client
from activetouch.transport.messages import RecognizeRequest
from activetouch.cli.commands.serve import resolve_mode
from activetouch.transport.zenoh_session import free_tcp_port
from activetouch import paths

home = Path({home!r})
ep = f"tcp/127.0.0.1:{{free_tcp_port()}}"
cfg = load_config(None, ["hand.type=fake", "arm.type=fake", "service.robot=fakebot",
                         f'service.listen=["{{ep}}"]'])
opts = DaemonOptions(mode=resolve_mode(None, cfg), role="all", data=home,
                     model_dir=paths.default_model(home), cfg=cfg)
stop = threading.Event()
t = threading.Thread(target=serve, args=(opts, stop))
t.start()
try:
    with open_client([ep], "fakebot", timeout=30.0) as c:
        c.connect(60.0)
        st = c.status()
        res = c.recognize(RecognizeRequest(policy="tree", max_moves=4, seed=1, object="cup"),
                          timeout=120.0)
finally:
    stop.set()
    t.join(30)
print(json.dumps({{"mode": st.mode, "nodes": sorted(st.nodes), "moves": res.moves,
                  "label": res.label, "pybullet": "pybullet" in sys.modules}}))
"""


def test_serve_on_fake_devices_without_pybullet(trained_home: Path) -> None:
    script = textwrap.dedent(FAKE_SERVE.format(home=str(trained_home)))
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=240
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["pybullet"] is False
    assert out["mode"] == "sim" and out["nodes"] == ["arm", "daemon", "hand", "sim"]
    assert 1 <= out["moves"] <= 4
    assert out["label"] in ("cup", "sphere", "bottle", "")


def test_twin_rig_calls_its_after_place_hooks_once_the_object_stands(trained_home: Path) -> None:
    """`TwinRig.after_place`: devices on the twin hook into `sim/place` (the Baxter twin homes
    its arm there) instead of replacing `ctx.place`; each hook sees the new object placed."""
    from activetouch.sim.devices import TWIN

    devices = make_devices(load_config(), trained_home)
    try:
        rig = devices.ctx.shared(TWIN, lambda: pytest.fail("no twin rig"))
        assert devices.ctx.place == rig.place  # not wrapped by anybody
        seen: list[np.ndarray] = []
        rig.after_place.append(lambda: seen.append(rig.world.object_origin.copy()))
        res = devices.ctx.place("cup", 0)
        top = devices.ctx.cfg.workcell.table_top_z
        assert len(seen) == 1 and seen[0][2] == pytest.approx(top + res.extents[2] / 2)
        devices.ctx.place("sphere")
        assert len(seen) == 2 and seen[1][2] != pytest.approx(seen[0][2])
    finally:
        devices.close()
