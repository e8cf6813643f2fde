"""``arm.type = "baxter"`` with ``arm.emulate = "twin"``: the real Baxter driver against its
byte-level emulator, in this process, on a loopback Zenoh endpoint, with the emulated joints
carrying the Baxter twin's arm (`sim.baxter.TwinBaxterArm`) and so the twin's hand, in the
shared twin world (`sim.devices.TwinRig`: the object `sim/place` put there).

Nothing is short-circuited: the driver serialises JointCommands with its rosbags codec and
puts them through its own Zenoh session; the emulator parses them with its own `struct` code,
follows them (first-order lag, velocity limits, command timeout) and publishes JointState
bytes the driver decodes. Each control tick the emulator hands its step to `TwinFollower`,
which replays it on the twin arm with the twin's checks (robot links and hand against the
table, hand against the object mesh): a contact stops the emulated arm short, as Baxter's own
collision detection would, and the driver's motion ends with `UnreachableError` naming the
contact, as on the twin-baxter type.

The world is single-threaded and the hand grasps in it too, so the follower touches it only
while a driver `execute` runs (the device nodes hold the twin lock around it) and until the
emulated arm holds afterwards (its command timeout); between motions the arm does not move.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import re
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from activetouch.drivers.baxter.arm import BaxterArm, BaxterArmConfig
from activetouch.emulators.baxter_bridge import BaxterEmulator, EmulatorSettings
from activetouch.errors import ActiveTouchError, StoppedError, UnreachableError
from activetouch.interfaces import Arm, JointTrajectory
from activetouch.sim.baxter import (
    ObjectShapes,
    TwinBaxterArm,
    TwinBaxterArmConfig,
    baxter_model,
    check_object_xy,
    check_workcell,
    make_twin_wrist,
)
from activetouch.sim.devices import twin_rig

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext
    from activetouch.emulators.baxter_bridge import BaxterEmulator
    from activetouch.planning.motion.base import WristMotion
    from activetouch.planning.motion.baxter import BaxterWristMotion
    from activetouch.sim.baxter import TwinBaxterArm

log = logging.getLogger(__name__)

_TWIN_PREFIX = re.compile(r"^arm trajectory blocked at t = [^:]*: ")


class TwinFollower:
    """The emulator's `Body`: moves the twin arm along the emulated joints of `side`, and only
    while `live()` (a driver command runs); reports the first contact to `on_block`."""

    def __init__(self, twin: TwinBaxterArm, side: str, dt: float) -> None:
        self.twin, self.side, self.dt = twin, side, float(dt)
        self._lock = threading.Lock()
        self._live = False
        self.dirty = False  # the emulated arm moved while nobody was looking
        self.blocked: str | None = None  # the contact that stopped the arm, this command
        self.on_block: Any = None  # callable(reason), called once per command, lock held
        self.steps = 0  # ticks replayed on the twin
        self.max_step_s = 0.0  # the slowest replay (wall s): it delays the emulator's tick

    @contextlib.contextmanager
    def live(self, emulator: BaxterEmulator) -> Iterator[None]:
        """Let the follower move the twin (and its hand) while the block runs. First bring
        the twin to where the emulated arm is, should it have moved unobserved."""
        # Lock order: the emulator's lock is taken before this one (its loop calls `follow`
        # holding it), so the emulator is read and written here outside this lock.
        q = emulator.positions(self.side)
        with self._lock:
            self._live, self.blocked = True, None
            got = q
            if self.dirty:
                self.dirty = False
                got = self._move(q)
        if np.any(got != q):  # blocked on the way: the emulated arm is where the twin is
            emulator.teleport(self.side, got)
        try:
            yield
        finally:
            with self._lock:
                self._live = False

    def follow(self, side: str, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
        if side != self.side:
            return q_to  # the other arm carries nothing
        with self._lock:
            if not self._live:
                self.dirty = True
                return q_to
            return self._move(q_to)

    def _move(self, q_to: np.ndarray) -> np.ndarray:
        """The twin arm from where it is to `q_to` by its own checked `execute` (a two-point
        trajectory one tick long); where it got."""
        twin = self.twin
        q0 = twin.joint_state().position
        traj = JointTrajectory(twin.joint_names, np.array([0.0, self.dt]), np.stack([q0, q_to]))
        self.steps += 1
        t0 = time.perf_counter()
        try:
            twin.execute(traj)
        except ActiveTouchError as e:  # a contact, or (never expected) a limit
            if self.blocked is None:
                self.blocked = _TWIN_PREFIX.sub("", str(e))
                if self.on_block is not None:
                    self.on_block(self.blocked)
        self.max_step_s = max(self.max_step_s, time.perf_counter() - t0)
        return twin.joint_state().position


class TwinEmulatedBaxterArm(BaxterArm):
    """The Baxter driver, unchanged, plus the emulator it talks to and the twin its joints
    carry. `execute` opens the follower's gate around the driver's own execute and turns a
    contact in the twin into `UnreachableError` (twin-baxter's behaviour)."""

    def __init__(
        self,
        cfg: BaxterArmConfig,
        emulator: BaxterEmulator,
        follower: TwinFollower,
        emulator_session: Any,
    ) -> None:
        super().__init__(cfg)
        self.emulator, self.follower = emulator, follower
        self._emulator_session = emulator_session
        self._user_stopped = False  # a stop from outside: never cleared by a contact's stop
        self._block_stop: threading.Thread | None = None
        follower.on_block = self._on_block

    @property
    def twin(self) -> TwinBaxterArm:
        return self.follower.twin

    def _on_block(self, reason: str) -> None:
        # Called by the emulator's control loop with its lock held: stop from another thread
        # (the driver's stop publishes through Zenoh).
        log.debug("emulated Baxter blocked in the twin: %s", reason)
        t = threading.Thread(target=BaxterArm.stop, args=(self,), name="baxter-twin-block")
        self._block_stop = t
        t.start()

    def execute(self, trajectory: JointTrajectory) -> None:
        # Take a newly placed object into the twin arm's collision scene here, not in the
        # emulator's 10 ms control loop: building its hull stalled joint states for > 0.5 s
        # on a loaded machine (the driver then reports them lost).
        self.twin.sync_object()
        with self.follower.live(self.emulator):
            try:
                super().execute(trajectory)
            except StoppedError:
                if self._contact() is None or self._user_stopped:
                    raise
                # else: the driver stopped for the contact, reported below
            finally:
                # The emulated arm keeps following its last command until its timeout: the
                # twin must be where it finally holds before the hand grasps there.
                self._wait_holding()
            reason = self._contact()
        if reason is not None:
            raise UnreachableError(f"emulated Baxter arm blocked in the twin: {reason}")

    def _contact(self) -> str | None:
        """The contact that stopped this motion (its stop released unless one came from
        outside), or None."""
        t = self._block_stop
        if t is not None:
            t.join(timeout=2.0)
            self._block_stop = None
            if not self._user_stopped:
                BaxterArm.clear_stop(self)
        return self.follower.blocked

    def _wait_holding(self) -> None:
        deadline = time.monotonic() + self.cfg.command_timeout_s + 1.0
        while not self.emulator.holding(self.cfg.side) and time.monotonic() < deadline:
            time.sleep(0.01)

    def stop(self) -> None:
        self._user_stopped = True
        super().stop()

    def clear_stop(self) -> None:
        self._user_stopped = False
        super().clear_stop()

    def home(self) -> None:
        """Twin and emulated arm back at the ready pose at once (after `sim/place`, as the
        twin-baxter type does), and the driver told."""
        ready = self.twin.model.ready
        self.twin.home()
        self.twin.sync_object()  # the placed object, outside the control loop (see execute)
        self.emulator.teleport(self.cfg.side, ready)
        self.follower.dirty = False  # both at the ready pose
        if self._session is None:
            return
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:  # the next joint state (10 ms) says where it is
            js = self._joints
            if js is not None and np.allclose(js.value[0], ready, atol=1e-9):
                return
            time.sleep(0.005)
        log.warning("the driver did not see the emulated arm at its ready pose within 1 s")

    def close_emulator(self) -> None:
        self.emulator.close()
        self._emulator_session.close()


def make_twin_emulated(cfg: BaxterArmConfig, ctx: DeviceContext) -> TwinEmulatedBaxterArm:
    """Start the emulator on the shared twin rig and return the driver pointed at it."""

    check_object_xy(ctx.cfg.workcell)  # before seconds of loading
    rig = twin_rig(ctx)
    model = baxter_model(ctx, cfg.motion)
    check_workcell(ctx.cfg.workcell, model)
    twin_cfg = TwinBaxterArmConfig(
        motion=cfg.motion,
        time_scale=0.0,  # the emulator paces it: one tick per call
        sample_dt=cfg.sample_dt,
        start_tolerance_rad=cfg.start_tolerance_rad,
    )
    twin = TwinBaxterArm(rig.world, model, twin_cfg, ObjectShapes(rig.library_root))
    arm = start_emulated(cfg, twin)
    ctx.on_close(arm.close_emulator)  # registered after the rig's close: runs before it
    rig.after_place.append(arm.home)
    return arm


def start_emulated(
    cfg: BaxterArmConfig, twin: Any, rate_hz: float = 100.0
) -> TwinEmulatedBaxterArm:
    """The emulator on a fresh loopback Zenoh endpoint, its `side` arm at `twin`'s ready pose
    and carrying `twin` (a `TwinBaxterArm`, or anything with its joint_names, joint_state,
    execute, home and model.ready), and the driver pointed at it (not yet connected)."""
    # deferred: loads zenoh
    from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings, free_tcp_port

    cfg.check()  # resolves the side
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    zs = ZenohSession(ZenohSettings(listen=(endpoint,)))  # loopback, scouting off
    follower = TwinFollower(twin, cfg.side, 1.0 / rate_hz)
    try:
        emu = BaxterEmulator(
            zs.session,
            EmulatorSettings(
                namespace=cfg.bridge_namespace,
                legacy=cfg.bridge_format == "legacy",
                rate_hz=rate_hz,
                # An emulated robot stands in for a twin, which needs no enabling.
                enabled=True,
                start=dict(
                    zip(twin.joint_names, np.asarray(twin.model.ready).tolist(), strict=True)
                ),
            ),
            body=follower,
        )
    except BaseException:
        zs.close()
        raise
    driver_cfg = dataclasses.replace(
        cfg, connect=[endpoint], listen=[], zenoh_config="", emulate=""
    )
    return TwinEmulatedBaxterArm(driver_cfg, emu, follower, zs)


def make_twin_emulated_wrist(
    cfg: BaxterArmConfig, arm: Arm, ctx: DeviceContext
) -> BaxterWristMotion:
    """The twin-baxter type's motion layer on the emulated driver: placement and object hull
    from the twin world."""

    rig = twin_rig(ctx)
    model = baxter_model(ctx, cfg.motion)
    return make_twin_wrist(arm, rig.world, model, cfg.motion, ObjectShapes(rig.library_root))


@dataclass
class BaxterRigConfig(BaxterArmConfig):
    """``arm.type = "baxter"``: the driver, or with ``arm.emulate = "twin"`` the driver on the
    bridge emulator driving the twin-baxter arm (the registry names this class, so the driver
    floor never imports the rig)."""

    def make(self, ctx: DeviceContext) -> Arm:
        if self.emulate == "twin":
            self.check()
            return make_twin_emulated(self, ctx)
        return super().make(ctx)

    def make_wrist(self, arm: Arm, ctx: DeviceContext) -> WristMotion:
        if self.emulate == "twin":
            return make_twin_emulated_wrist(self, arm, ctx)
        return super().make_wrist(arm, ctx)
