"""Writing one recognition's MCAP file, incrementally.

Every grasp's messages end a chunk (`mcap.Writer.flush`: the chunk is compressed, written and
the file flushed), so a crash loses at most the grasp in progress; `reader.read_recording`
reads such a file without its summary and footer. The summary (statistics, message counts)
is written by `finish`.

`SafeRecorder` is what a recognition holds: a recording that fails (disk full, permissions)
logs one warning and stops recording, never ends the recognition.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.writer import CompressionType, Writer

from activetouch.recordings import format as fmt
from activetouch.recordings.store import new_recording_path, prune

log = logging.getLogger(__name__)

LIBRARY = "activetouch"


def _clean(value: Any) -> Any:
    """JSON-able: numpy to Python, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, np.generic):
        return _clean(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class McapFile:
    """One MCAP file with the ROS 2 channels and the JSON channels of `json_topics`; each
    message stamped with the wall clock (ns since the epoch). `flush` ends a chunk."""

    def __init__(self, path: Path, json_topics: dict[str, tuple[str, dict]]) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in _close()
        self._w = Writer(self._file, compression=CompressionType.ZSTD)
        self._w.start(profile=fmt.PROFILE, library=LIBRARY)
        self._channels: dict[str, int] = {}
        for topic, typename in fmt.ROS_TOPICS.items():
            sid = self._w.register_schema(typename, "ros2msg", fmt.ros_schema(typename))
            self._channels[topic] = self._w.register_channel(topic, "cdr", sid)
        for topic, (name, schema) in json_topics.items():
            sid = self._w.register_schema(name, "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._w.register_channel(topic, "json", sid)
        self._seq = 0
        self.finished = False

    def _add(self, topic: str, data: bytes, ns: int | None = None) -> None:
        ns = time.time_ns() if ns is None else ns
        self._seq += 1
        self._w.add_message(
            self._channels[topic], log_time=ns, data=data, publish_time=ns, sequence=self._seq
        )

    def _json(self, topic: str, payload: dict[str, Any], ns: int | None = None) -> None:
        body = {"v": fmt.SCHEMA_VERSION, **payload}
        self._add(topic, json.dumps(_clean(body), allow_nan=False).encode(), ns)

    def _close(self) -> None:
        """Summary and footer, then the file is closed."""
        try:
            self._w.finish()
        finally:
            self._file.close()


class RecordingWriter(McapFile):
    """One recognition's recording. `request`: what `fmt.REQUEST` carries (session_id,
    policy, class_names ...)."""

    def __init__(self, path: Path, request: dict[str, Any]) -> None:
        super().__init__(path, fmt.JSON_TOPICS)
        self.class_names = list(request.get("class_names", []))
        self.grasps = 0
        self._json(fmt.REQUEST, {"move": 0, "kind": fmt.RECOGNITION, **request})
        placement = request.get("placement")
        if placement is not None:
            self.placement(np.asarray(placement, dtype=np.float64))
        self._w.flush()

    def placement(self, pose: np.ndarray) -> None:
        """The object frame in the world (robot base) frame, (7,) x y z qx qy qz qw."""
        ns = time.time_ns()
        tf = fmt.tf_message(ns, [(fmt.WORLD_FRAME, fmt.OBJECT_FRAME, pose)])
        self._add(fmt.TF_STATIC, tf, ns)

    def wrist_goal(self, move: int, pose_id: int, pose: np.ndarray) -> None:
        """Before the arm moves to `pose` (object frame) for grasp `move`."""
        self._add(fmt.WRIST_GOAL, fmt.pose_stamped(time.time_ns(), fmt.OBJECT_FRAME, pose))

    def plan(self, move: int, plan: dict[str, Any]) -> None:
        self._json(fmt.PLAN, {"move": move, **plan})

    def error(self, move: int, kind: str, error: str, error_type: str = "", **extra: Any) -> None:
        self._json(
            fmt.ERROR,
            {"move": move, "kind": kind, "error": error, "error_type": error_type, **extra},
        )

    def grasp(
        self,
        move: int,
        pose_id: int,
        pose: np.ndarray,
        grasp: Any,
        probabilities: np.ndarray,
        label: str,
        felt: bool,
        robot_time: dict[str, float],
        ignored: np.ndarray | None = None,
        support_z: float | None = None,
    ) -> None:
        """One grasp (an `interfaces.Grasp`, hand frame, as the session observed it), the
        belief after it and the robot seconds so far; then the chunk is written out.
        `ignored`: the sensors masked this recognition (replay leaves them out alike).
        `support_z`: the table plane in the object frame (the pose belief stands each class
        on it; replay does alike)."""
        ns = time.time_ns()
        p = np.asarray(probabilities, dtype=np.float64)
        self._json(
            fmt.GRASP,
            {
                "move": move,
                "pose_id": int(pose_id),
                "pose": np.asarray(pose, dtype=np.float64),
                "sensor_ids": grasp.sensor_ids,
                "xyz": grasp.xyz,
                "pressures": grasp.pressures,
                "finger_angles": grasp.finger_angles,
                "preshape": float(grasp.preshape),
                "ignored_sensors": [] if ignored is None else [int(i) for i in ignored],
                **({} if support_z is None else {"support_z": float(support_z)}),
            },
            ns,
        )
        order = np.argsort(-p, kind="stable")[:3]
        top3 = [[self.class_names[i], float(p[i])] for i in order] if felt else []
        self._json(
            fmt.BELIEF,
            {
                "move": move,
                "label": label,
                "felt": felt,
                "probabilities": p,
                "class_names": self.class_names,
                "top3": top3,
            },
            ns,
        )
        self._json(fmt.ROBOT_TIME, {"move": move, **robot_time}, ns)
        self._add(
            fmt.CONTACTS, fmt.point_cloud(ns, grasp.xyz, grasp.pressures, grasp.sensor_ids), ns
        )
        self._add(fmt.JOINT_STATES, fmt.joint_state(ns, grasp.preshape, grasp.finger_angles), ns)
        self._add(fmt.TF, fmt.tf_message(ns, [(fmt.OBJECT_FRAME, fmt.HAND_FRAME, pose)]), ns)
        self.grasps += 1
        self._w.flush()  # this grasp is on disk now

    def finish(
        self, result: dict[str, Any] | None = None, error: BaseException | None = None
    ) -> None:
        """The result (or the error that ended the recognition), then summary and footer."""
        if self.finished:
            return
        self.finished = True
        try:
            if error is not None:
                text = str(error)[:4000]
                self.error(self.grasps, "failed", text, type(error).__name__)
                self._json(
                    fmt.RESULT,
                    {"move": self.grasps, "error": text, "error_type": type(error).__name__},
                )
            else:
                self._json(fmt.RESULT, {"move": self.grasps, **(result or {})})
        finally:
            self._close()


class SafeRecorder:
    """Forwards to a writer (`RecordingWriter`, or a calibration's); the first failure is logged
    and ends the recording, never what is being recorded."""

    def __init__(self, writer: Any) -> None:
        self.writer = writer

    @property
    def path(self) -> Path | None:
        return None if self.writer is None else self.writer.path

    def call(self, name: str, *args: Any, **kw: Any) -> None:
        w = self.writer
        if w is None:
            return
        try:
            getattr(w, name)(*args, **kw)
        except Exception as e:
            log.warning("recording %s stopped: %s: %s", w.path, type(e).__name__, e)
            self.writer = None
            try:
                w.finish(error=e)
            except Exception:
                log.debug("cannot finish the recording", exc_info=True)

    def placement(self, *args: Any, **kw: Any) -> None:
        self.call("placement", *args, **kw)

    def wrist_goal(self, *args: Any, **kw: Any) -> None:
        self.call("wrist_goal", *args, **kw)

    def plan(self, *args: Any, **kw: Any) -> None:
        self.call("plan", *args, **kw)

    def error(self, *args: Any, **kw: Any) -> None:
        self.call("error", *args, **kw)

    def grasp(self, *args: Any, **kw: Any) -> None:
        self.call("grasp", *args, **kw)

    def finish(self, *args: Any, **kw: Any) -> None:
        self.call("finish", *args, **kw)
        self.writer = None


def open_recorder(
    root: Path,
    cfg: Any,
    *,
    session_id: str,
    source: str,
    policy: str,
    max_moves: int,
    seed: int,
    object_name: str | None,
    model: Any,
    model_dir: Path | None,
    placement: np.ndarray | None = None,
    extra: dict[str, Any] | None = None,
) -> SafeRecorder | None:
    """Start a recording under ``<root>/recordings/`` if ``cfg.recording.enabled`` (None
    otherwise, or if it cannot be created: a warning, the recognition goes on). `cfg`: the
    `Config`; `model`: the `TrainedModel` that recognises."""

    if not cfg.recording.enabled:
        return None
    prune(root, cfg.recording)
    started = time.time()
    request: dict[str, Any] = {
        "session_id": session_id,
        "source": source,
        "policy": policy,
        "max_moves": int(max_moves),
        "seed": int(seed),
        "object": object_name,
        "horizon": int(cfg.planner.horizon),
        "simulations": int(cfg.planner.simulations),
        "model": str(model_dir) if model_dir is not None else "",
        "model_checksum": model.dataset_checksum,
        "class_names": list(model.class_names),
        "recognition": dataclasses.asdict(cfg.recognition),
        "session": dataclasses.asdict(cfg.session),
        "started": started,
        **(extra or {}),
    }
    if placement is not None:
        request["placement"] = np.asarray(placement, dtype=np.float64).tolist()
    path = new_recording_path(root, session_id, started)
    try:
        writer = RecordingWriter(path, request)
    except Exception as e:
        log.warning("cannot record to %s: %s: %s", path, type(e).__name__, e)
        return None
    return SafeRecorder(writer)


def close_recorder(
    recorder: SafeRecorder | None,
    root: Path,
    cfg: Any,
    result: dict[str, Any] | None = None,
    error: BaseException | None = None,
) -> Path | None:
    """Finish `recorder` (if any) with the result or error, then apply the limits."""
    if recorder is None:
        return None

    path = recorder.path
    recorder.finish(result=result, error=error)
    try:
        prune(root, cfg.recording, keep=path)
    except Exception as e:
        log.warning("recordings: cannot apply the limits: %s", e)
    return path
