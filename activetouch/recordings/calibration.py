"""Recording a `calibrate` procedure as MCAP, beside the recognitions under <data>/recordings/.

The procedure is handed a `RecordingHand` and a `RecordingFlange` instead of the devices, so
what it reads and where it moves is recorded as it happens, whatever the procedure: each new
hand state (all 38 pressures, contacts, finger angles; also as /joint_states), each flange
goal (/activetouch/wrist_goal, world frame) and the pose reached (/tf world -> hand), each
grasp's contacts (/activetouch/contacts). The result is the calibration record as stored, or
the error that ended the procedure. Like a recognition's, a recording that fails logs one
warning and stops; the calibration goes on.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from activetouch.interfaces import Grasp, HandState, HandWrapper, Pose
from activetouch.recordings import format as fmt
from activetouch.recordings.store import new_recording_path, prune
from activetouch.recordings.writer import McapFile, SafeRecorder

log = logging.getLogger(__name__)


class CalibrationWriter(McapFile):
    def __init__(self, path: Path, request: dict[str, Any]) -> None:
        super().__init__(path, fmt.CALIBRATION_TOPICS)
        self.moves = 0
        self._json(fmt.REQUEST, {"move": 0, "kind": fmt.CALIBRATION, **request})
        self._w.flush()

    def hand_state(self, s: HandState) -> None:
        ns = time.time_ns()
        contact = np.flatnonzero(np.asarray(s.contact, dtype=bool))
        self._json(
            fmt.HAND_STATE,
            {
                "move": self.moves,
                "pressures": np.asarray(s.pressures, dtype=np.float64),
                "contact": contact,
                "finger_angles": np.asarray(s.finger_angles, dtype=np.float64),
                "preshape": float(s.preshape),
                "stamp": float(s.stamp),
            },
            ns,
        )
        self._add(fmt.JOINT_STATES, fmt.joint_state(ns, s.preshape, s.finger_angles), ns)

    def grasp(self, g: Grasp) -> None:
        ns = time.time_ns()
        self._add(fmt.CONTACTS, fmt.point_cloud(ns, g.xyz, g.pressures, g.sensor_ids), ns)
        self._add(fmt.JOINT_STATES, fmt.joint_state(ns, g.preshape, g.finger_angles), ns)

    def wrist_goal(self, pose: Pose) -> None:
        self._add(
            fmt.WRIST_GOAL, fmt.pose_stamped(time.time_ns(), fmt.WORLD_FRAME, pose.as_array())
        )

    def reached(self, pose: Pose) -> None:
        """Where the flange got to after a move; the chunk is written out."""
        ns = time.time_ns()
        self.moves += 1
        self._add(fmt.TF, fmt.tf_message(ns, [(fmt.WORLD_FRAME, fmt.HAND_FRAME, pose.as_array())]))
        self._w.flush()

    def finish(
        self,
        record: dict[str, Any] | None = None,
        stored: bool = False,
        error: BaseException | None = None,
    ) -> None:
        if self.finished:
            return
        self.finished = True
        try:
            if error is not None:
                text = str(error)[:4000]
                self._json(fmt.ERROR, {"move": self.moves, "kind": "failed", "error": text,
                                       "error_type": type(error).__name__})  # fmt: skip
                self._json(fmt.RESULT, {"move": self.moves, "error": text,
                                        "error_type": type(error).__name__})  # fmt: skip
            else:
                self._json(fmt.RESULT, {"move": self.moves, "record": record, "stored": stored})
        finally:
            self._close()


class RecordingHand(HandWrapper):
    """The hand as a procedure sees it, every new state and grasp recorded. Attributes the
    `Hand` interface does not name (a driver's calibration hooks) are the inner hand's."""

    def __init__(self, inner: Any, recorder: SafeRecorder) -> None:
        super().__init__(inner)
        self._recorder = recorder
        self._last: tuple[float, Any] | None = None

    _OWN = ("inner", "_recorder", "_last")

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in self._OWN:
            raise AttributeError(name)
        return getattr(self.inner, name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name in self._OWN:
            object.__setattr__(self, name, value)
        else:  # a procedure setting a driver's attribute sets the driver's
            setattr(self.inner, name, value)

    def state(self) -> HandState:
        s = self.inner.state()
        key = (s.stamp, getattr(s, "systime_us", 0))
        if key != self._last:  # procedures poll faster than the hand streams
            self._last = key
            self._recorder.call("hand_state", s)
        return s

    def guarded_close(self) -> Grasp:
        g = self.inner.guarded_close()
        self._recorder.call("grasp", g)
        return g


class Flange(Protocol):
    def pose(self) -> Pose: ...

    def move_to(self, pose: Pose) -> None: ...


class RecordingFlange:
    """A flange (`calibration.probing.Flange`) whose goals and reached poses are recorded."""

    def __init__(self, inner: Flange, recorder: SafeRecorder) -> None:
        self.inner = inner
        self._recorder = recorder

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("inner", "_recorder"):
            raise AttributeError(name)
        return getattr(self.inner, name)

    def pose(self) -> Pose:
        return self.inner.pose()

    def move_to(self, pose: Pose) -> None:
        self._recorder.call("wrist_goal", pose)
        try:
            self.inner.move_to(pose)
        finally:  # a refused or stopped move still left the flange somewhere
            try:
                self._recorder.call("reached", self.inner.pose())
            except Exception:
                log.debug("cannot read the flange pose after a move", exc_info=True)


def open_calibration_recorder(
    root: Path,
    cfg: Any,
    *,
    procedure: str,
    device: str,
    settings: dict[str, Any] | None = None,
) -> SafeRecorder | None:
    """Start recording `calibrate <procedure>` if ``cfg.recording.enabled`` (None otherwise,
    or when the file cannot be made: a warning, the calibration goes on)."""

    if not cfg.recording.enabled:
        return None
    prune(root, cfg.recording)
    started = time.time()
    session_id = f"calibrate-{procedure}-{device}"
    request = {
        "session_id": session_id,
        "source": "calibrate",
        "procedure": procedure,
        "device": device,
        "hand": cfg.hand.type,
        "arm": cfg.arm.type,
        "settings": settings or {},
        "started": started,
    }
    path = new_recording_path(root, session_id, started)
    try:
        return SafeRecorder(CalibrationWriter(path, request))
    except Exception as e:
        log.warning("cannot record to %s: %s: %s", path, type(e).__name__, e)
        return None
