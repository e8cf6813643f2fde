"""Recording device doubles for the suite (the package's own in-memory devices are
activetouch.fakes): deterministic, they record every call, and a test can make them slow or fail."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from activetouch.errors import DataError, UnreachableError
from activetouch.interfaces import (
    N_SENSORS,
    Arm,
    Grasp,
    Hand,
    HandState,
    JointLimits,
    JointState,
    JointTrajectory,
    Pose,
)
from activetouch.planning.motion.base import WristMotion


class RecordingHand(Hand):
    """Deterministic hand double: records calls; guarded_close touches sensors 0, 9, 18, 27."""

    def __init__(self, close_delay: float = 0.0) -> None:
        self.calls: list[tuple] = []
        self.angle = 0.0
        self.closed = False
        self.close_delay = close_delay
        self.fail_with: Exception | None = None
        self.before_close: Callable[[], None] | None = None  # runs inside guarded_close

    def connect(self) -> None:
        self.calls.append(("connect",))

    def disconnect(self) -> None:
        self.calls.append(("disconnect",))

    def open(self) -> None:
        self.calls.append(("open",))
        self.closed = False

    def preshape(self, angle: float) -> None:
        self.calls.append(("preshape", angle))
        if not 0.0 <= angle <= 1.6:
            raise ValueError(f"preshape {angle} rad outside 0..1.6")
        self.angle = angle

    def guarded_close(self) -> Grasp:
        self.calls.append(("guarded_close",))
        if self.fail_with is not None:
            raise self.fail_with
        if self.before_close is not None:
            self.before_close()
        if self.close_delay:
            time.sleep(self.close_delay)
        self.closed = True
        ids = np.array([0, 9, 18, 27])
        return Grasp(
            sensor_ids=ids,
            xyz=np.column_stack([ids * 0.001, ids * 0.002, ids * 0.003]),
            pressures=ids * 1.5 + 1.0,
            finger_angles=np.array([1.0, 1.1, 1.2]),
            preshape=self.angle,
        )

    def stop(self) -> None:
        self.calls.append(("stop",))

    def clear_stop(self) -> None:
        self.calls.append(("clear_stop",))

    def state(self) -> HandState:
        contact = np.zeros(N_SENSORS, dtype=bool)
        if self.closed:
            contact[[0, 9, 18, 27]] = True
        return HandState(
            pressures=np.arange(N_SENSORS, dtype=float) * contact,
            contact=contact,
            finger_angles=np.array([1.0, 1.1, 1.2]) if self.closed else np.zeros(3),
            preshape=self.angle,
            stamp=time.monotonic(),
        )


class RecordingArm(Arm, WristMotion):
    """Arm double, and its own wrist motion (recorded as "move_wrist"): poses with x > 1 m are
    unreachable; execute can be stopped."""

    NAMES = ("x", "y", "z", "roll", "pitch", "yaw")
    joint_names = NAMES
    limits = JointLimits(np.full(6, -10.0), np.full(6, 10.0), np.ones(6), np.ones(6))

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.q = np.zeros(6)
        self.stop_event = threading.Event()
        self.executing = threading.Event()

    def connect(self) -> None:
        self.calls.append(("connect",))

    def disconnect(self) -> None:
        self.calls.append(("disconnect",))

    def joint_state(self) -> JointState:
        return JointState(self.NAMES, self.q.copy(), np.zeros(6), time.monotonic())

    def execute(self, trajectory: JointTrajectory) -> None:
        self.calls.append(("execute", trajectory))
        self.stop_event.clear()
        self.executing.set()
        try:
            t0 = time.monotonic()
            # Follow the timing (scaled down 10x) so that stop() can interrupt a real motion.
            while time.monotonic() - t0 < float(trajectory.times[-1]) / 10:
                if self.stop_event.wait(0.005):
                    raise DataError("trajectory interrupted by stop")
            self.q = np.asarray(trajectory.positions[-1], dtype=float).copy()
        finally:
            self.executing.clear()

    def move_to(self, pose: Pose) -> None:
        self.calls.append(("move_wrist", pose))
        if pose.xyz[0] > 1.0:
            raise UnreachableError(f"wrist pose at x={pose.xyz[0]:.2f} m is out of reach")
        self.q[:3] = pose.xyz

    def stop(self) -> None:
        self.calls.append(("stop",))
        self.stop_event.set()

    def clear_stop(self) -> None:
        self.calls.append(("clear_stop",))

    def estop(self) -> None:
        self.calls.append(("estop",))
        self.stop_event.set()

    def enable(self) -> None:
        self.calls.append(("enable",))

    def disable(self) -> None:
        self.calls.append(("disable",))
