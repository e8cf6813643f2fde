"""Hand, arm and place nodes over Zenoh (the serving side; the clients: activetouch.daemon.remote).

Serving side (`HandNode`, `ArmNode`): any `Hand` / `Arm` (the twin or a real driver) is
served on the keys of `activetouch.transport.keys`. Zenoh callbacks only enqueue the query;
one worker thread per node owns the device, runs one command at a time in arrival order,
replies, and between commands publishes the state periodically. The node's liveliness token
``activetouch/<robot>/alive/<node>`` is declared once everything is served and dropped first
on close. Arm ``stop`` bypasses the queue (its own thread, no lock), so it can halt a running
``execute`` / ``move_wrist``: an `Arm.stop()` must therefore be safe to call from another
thread while a motion runs. Nodes sharing one simulated world pass the same `lock`, so the
twin is never touched by two threads at once.

A query may carry the parameter ``timeout=<seconds>`` (the clients below always do): a command
that waited in the queue longer than that is not executed (its caller has given up) and gets
an error reply instead.

Client side: activetouch.daemon.remote.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from activetouch.clock import SYSTEM_CLOCK, Clock
from activetouch.daemon.serving import JSON, MAX_STREAM_HZ, Op, ServedNode
from activetouch.daemon.supervision import DeviceLink
from activetouch.errors import (
    ActiveTouchError,
    MessageError,
)
from activetouch.interfaces import (
    Arm,
    Hand,
    HandState,
    Placed,
)
from activetouch.planning.motion.base import Placement, WristMotion
from activetouch.transport.keys import ARM_NODE, HAND_NODE, SIM_NODE, Keys
from activetouch.transport.messages import (
    Empty,
    ExecuteRequest,
    HandInfo,
    MaskRequest,
    Message,
    MotionStats,
    MoveWristRequest,
    PreshapeRequest,
    SensorFlagsMsg,
    SensorSitesMsg,
    SimPlaceRequest,
    SimPlaceResult,
    ThresholdsRequest,
    check_sensor_count,
    encode,
    grasp_to_msg,
    hand_state_to_msg,
    joint_state_to_msg,
    pose_from_msg,
    trajectory_from_msg,
)
from activetouch.transport.zenoh_session import undeclare_quietly

log = logging.getLogger(__name__)


class HandNode(ServedNode):
    """Serve `hand` on ``activetouch/<robot>/hand/...``; publish its state at `state_hz`.

    The hand must already be connected, or `link` (activetouch.daemon.supervision) connects it
    and the node serves commands only while it is connected. ``hand/info`` tells clients the
    hand's sensor count (`Hand.n_sensors`, 1 .. MAX_SENSORS) and its type (`device`, e.g.
    ``hand.type``); states and grasps go out with that many sensors, and thresholds of another
    length or mask ids beyond it are refused with an error reply."""

    node_name = HAND_NODE

    def __init__(
        self,
        hand: Hand,
        session: zenoh.Session,
        robot: str,
        *,
        state_hz: float = 20.0,
        lock: threading.Lock | None = None,
        clock: Clock = SYSTEM_CLOCK,
        link: DeviceLink | None = None,
        device: str | None = None,
    ) -> None:
        # Refused here (the daemon does not start), not at every state: a hand the messages
        # cannot carry.
        self.n_sensors = check_sensor_count(hand.n_sensors, f"hand {type(hand).__name__}")
        self.device = device if device is not None else (link.device_type if link else "")
        # A hand that reports each reading as it arrives (the ReFlex drivers: 40 Hz, and once
        # when its stream goes stale) is published from there, beside a running grasp;
        # other hands on the node's timer, between commands.
        streams = callable(getattr(hand, "add_state_listener", None))
        super().__init__(
            session,
            robot,
            state_key=Keys(robot).hand_state,
            state_hz=0.0 if streams else state_hz,
            lock=lock,
            clock=clock,
            link=link,
        )
        self.hand = hand
        self._stream_pub: Any = None
        self._min_gap = 1.0 / MAX_STREAM_HZ
        self._last_put = 0.0
        if streams:
            self._stream_pub = session.declare_publisher(
                self.keys.hand_state, encoding=JSON, congestion_control=zenoh.CongestionControl.DROP
            )
            hand.add_state_listener(self._on_reading)
        k = self.keys
        n = self.n_sensors
        self._ops = {
            # At once (no device lock, also while the hand is away): a fixed fact of the hand.
            "info": Op(
                k.hand_info,
                Empty,
                lambda _r: HandInfo(n_sensors=n, device=self.device),
                fast=True,
            ),
            "open": Op(k.hand_open, Empty, lambda _r: hand.open()),
            "preshape": Op(k.hand_preshape, PreshapeRequest, lambda r: hand.preshape(r.angle)),
            "guarded_close": Op(
                k.hand_guarded_close, Empty, lambda _r: grasp_to_msg(hand.guarded_close(), n)
            ),
            "state": Op(k.hand_state, Empty, lambda _r: hand_state_to_msg(hand.state(), n)),
            "mask": Op(k.hand_mask, MaskRequest, self._mask),
            "thresholds": Op(k.hand_thresholds, ThresholdsRequest, self._thresholds),
            "sensor_flags": Op(
                k.hand_sensor_flags,
                Empty,
                lambda _r: SensorFlagsMsg(
                    flags={str(i): f for i, f in hand.sensor_flags().items()}
                ),
            ),
            "sensor_sites": Op(k.hand_sensor_sites, Empty, lambda _r: self._sensor_sites()),
            # At once, beside a running grasp: the close ends within one control step.
            "stop": Op(k.hand_stop, Empty, lambda _r: hand.stop(), fast=True),
            "clear_stop": Op(k.hand_clear_stop, Empty, lambda _r: hand.clear_stop(), fast=True),
        }
        self._start()

    def _mask(self, req: MaskRequest) -> bool:
        n = self.n_sensors
        bad = sorted({i for i in req.sensor_ids if i >= n})
        if bad:
            raise MessageError(
                f"invalid MaskRequest: field `sensor_ids`: {bad[:8]} are not sensor ids of "
                f"this hand ({self._what()}: ids 0..{n - 1})",
                field="sensor_ids",
            )
        return self.hand.mask_sensors(req.sensor_ids)

    def _thresholds(self, req: ThresholdsRequest) -> bool:
        n = self.n_sensors
        if len(req.thresholds) != n:
            raise MessageError(
                f"invalid ThresholdsRequest: field `thresholds`: {len(req.thresholds)} values, "
                f"expected {n}, one per sensor of this hand ({self._what()})",
                field="thresholds",
            )
        return self.hand.set_contact_thresholds(req.thresholds)

    def _sensor_sites(self) -> SensorSitesMsg:
        sites, own = self.hand.sensor_sites(), self.hand.own_contact_thresholds()
        return SensorSitesMsg(
            sites=[] if sites is None else [tuple(map(float, p)) for p in np.asarray(sites)],
            own_thresholds=[] if own is None else [float(t) for t in np.asarray(own)],
        )

    def _what(self) -> str:
        return ", ".join(w for w in (self.device, f"{self.n_sensors} sensors") if w)

    def _read_state(self) -> Message:
        return hand_state_to_msg(self.hand.state(), self.n_sensors)

    def _on_reading(self, state: HandState) -> None:
        # The driver's receive thread: encode and put (non-blocking, drops under congestion).
        pub = self._stream_pub
        now = time.monotonic()
        if pub is None or (now - self._last_put < self._min_gap and not state.stale):
            return
        self._last_put = now
        try:
            pub.put(encode(hand_state_to_msg(state, self.n_sensors)))
            self.published += 1
        except Exception as e:
            log.debug("hand node: publishing a reading failed: %s", e)

    def _on_close(self) -> None:
        pub, self._stream_pub = self._stream_pub, None
        if pub is not None:
            undeclare_quietly(pub)


class ArmNode(ServedNode):
    """Serve `arm` on ``activetouch/<robot>/arm/...``; publish joint states at `state_hz`.

    ``move_wrist`` (a wrist pose in the object frame) goes through `wrist`, the motion layer
    for this arm, next to the arm (`placement()` says where the object is before each move).
    ``stop`` runs at once on its own thread, concurrently with a running motion. Closing the
    node while a motion runs stops the arm."""

    node_name = ARM_NODE

    def __init__(
        self,
        arm: Arm,
        session: zenoh.Session,
        robot: str,
        *,
        wrist: WristMotion | None = None,
        placement: Callable[[], Placement] | None = None,
        state_hz: float = 20.0,
        lock: threading.Lock | None = None,
        clock: Clock = SYSTEM_CLOCK,
        link: DeviceLink | None = None,
    ) -> None:
        super().__init__(
            session,
            robot,
            state_key=Keys(robot).arm_joint_states,
            state_hz=state_hz,
            lock=lock,
            clock=clock,
            link=link,
        )
        self.arm = arm
        self.wrist = wrist
        self.placement = placement
        k = self.keys
        self._ops = {
            "joint_state": Op(
                k.arm_joint_state, Empty, lambda _r: joint_state_to_msg(arm.joint_state())
            ),
            "move_wrist": Op(k.arm_move_wrist, MoveWristRequest, self._move_wrist),
            "execute": Op(
                k.arm_execute,
                ExecuteRequest,
                lambda r: arm.execute(trajectory_from_msg(r.trajectory)),
            ),
            "stop": Op(k.arm_stop, Empty, lambda _r: arm.stop(), fast=True),
            "clear_stop": Op(k.arm_clear_stop, Empty, lambda _r: arm.clear_stop(), fast=True),
            # The robot's own e-stop where it has one (stop() otherwise): at once, beside a
            # motion. Enabling is explicit, queued like a motion.
            "estop": Op(k.arm_estop, Empty, lambda _r: arm.estop(), fast=True),
            "enable": Op(k.arm_enable, Empty, lambda _r: arm.enable()),
            "disable": Op(k.arm_disable, Empty, lambda _r: arm.disable()),
            # Robot time of the motion layer (a read of three numbers: at once, beside a
            # motion, so a progress report never waits for one).
            "motion_stats": Op(k.arm_motion_stats, Empty, self._motion_stats, fast=True),
        }
        self._start()

    def _motion_stats(self, _req: Empty) -> MotionStats:
        w = self.wrist
        if w is None:
            return MotionStats()
        return MotionStats(
            robot_s=float(w.robot_seconds), planning_s=float(w.planning_seconds), moves=w.moves
        )

    def _move_wrist(self, req: MoveWristRequest) -> None:
        if self.wrist is None:
            raise ActiveTouchError(f"the {self.node_name} node has no motion layer for move_wrist")
        if self.placement is not None:
            self.wrist.set_placement(self.placement())
        self.wrist.move_to(pose_from_msg(req.pose))

    def _read_state(self) -> Message:
        return joint_state_to_msg(self.arm.joint_state())

    def _on_close(self) -> None:
        if self._busy in ("move_wrist", "execute"):
            log.warning("arm node closing during %s: stopping the arm", self._busy)
            self.arm.stop()


class PlaceNode(ServedNode):
    """Simulated robots only: ``sim/place`` puts an object on the table via `place`
    (`SimPlaceRequest` -> `SimPlaceResult` on the wire; `place(object, seed) -> Placed`), e.g.
    the twin's or the fake's."""

    node_name = SIM_NODE

    def __init__(
        self,
        place: Callable[[str, int | None], Placed],
        session: zenoh.Session,
        robot: str,
        *,
        lock: threading.Lock | None = None,
    ) -> None:
        super().__init__(session, robot, state_key=Keys(robot).sim_place, state_hz=0.0, lock=lock)

        def served(req: SimPlaceRequest) -> SimPlaceResult:
            placed = place(req.object, req.seed)
            return SimPlaceResult(object=placed.object, extents=placed.extents)

        self._ops = {"place": Op(self.keys.sim_place, SimPlaceRequest, served)}
        self._start()


# --------------------------------------------------------------------------- clients
