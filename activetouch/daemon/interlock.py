"""The safety interlock of a recognition: once tripped (e-stop, cancel), every further hand or
arm command of that recognition is refused, so it ends at once whatever it was doing."""

from __future__ import annotations

from collections.abc import Callable

from activetouch.daemon.client import RecognitionAbortedError
from activetouch.interfaces import Grasp, Hand, HandWrapper, Pose
from activetouch.planning.motion.base import WristMotion


class Interlock:
    """Refuses every further hand/arm command of one recognition once tripped."""

    def __init__(self) -> None:
        self.reason: str | None = None

    def trip(self, reason: str) -> None:
        if self.reason is None:
            self.reason = reason

    def check(self, what: str) -> None:
        if self.reason is not None:
            raise RecognitionAbortedError(f"{what} refused: {self.reason}")


class GuardedHand(HandWrapper):
    """The hand as one recognition uses it: motions refused once its interlock trips. It
    neither connects nor disconnects the hand (the service does not own it)."""

    def __init__(
        self,
        hand: Hand,
        interlock: Interlock,
        on_grasp: Callable[[Grasp], None] | None = None,
    ) -> None:
        super().__init__(hand)
        self.interlock = interlock
        self.on_grasp = on_grasp  # told of every grasp (the service's observers)

    def connect(self) -> None:
        pass

    def disconnect(self) -> None:
        pass

    def open(self) -> None:
        self.interlock.check("hand open")
        self.inner.open()

    def preshape(self, angle: float) -> None:
        self.interlock.check("hand preshape")
        self.inner.preshape(angle)

    def guarded_close(self) -> Grasp:
        self.interlock.check("grasp")
        grasp = self.inner.guarded_close()
        if self.on_grasp is not None:
            self.on_grasp(grasp)
        return grasp


class GuardedWrist(WristMotion):
    def __init__(self, wrist: WristMotion, interlock: Interlock) -> None:
        self.inner, self.interlock = wrist, interlock

    def move_to(self, pose: Pose) -> None:
        self.interlock.check("arm motion")
        self.inner.move_to(pose)

    # Robot time of the wrapped wrist (a read: allowed after a trip too).
    @property  # type: ignore[override]
    def robot_seconds(self) -> float:
        return self.inner.robot_seconds

    @property  # type: ignore[override]
    def planning_seconds(self) -> float:
        return self.inner.planning_seconds
