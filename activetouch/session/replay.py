"""`activetouch replay FILE`: the classifier and belief re-run on a recording's grasps, offline.

Each recorded grasp (as the session observed it: hand frame, table contacts dropped, at its
recorded wrist pose) goes through the same `BeliefTracker` as a live session, with the
recorded belief settings (`recognition.*` of the request) and the trained model. With the
model that recognised it, the labels and probabilities equal the recorded ones.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from activetouch.config import RecognitionConfig
from activetouch.errors import DataError
from activetouch.interfaces import Grasp, Pose
from activetouch.model import TrainedModel
from activetouch.objects.library import ObjectLibrary
from activetouch.recordings.reader import Recording
from activetouch.session.loop import (
    NO_LABEL,
    BeliefTracker,
    grasp_likelihood_of,
    pose_belief_of,
)


@dataclass
class Replay:
    labels: list[str] = field(default_factory=list)
    probabilities: list[list[float]] = field(default_factory=list)
    recorded_labels: list[str] = field(default_factory=list)
    recorded_probabilities: list[list[float]] = field(default_factory=list)
    max_abs_diff: float = 0.0  # largest |replayed - recorded| probability

    @property
    def same_labels(self) -> bool:
        return self.labels == self.recorded_labels


def recorded_recognition(rec: Recording) -> RecognitionConfig:
    known = {f.name for f in dataclasses.fields(RecognitionConfig)}
    saved = rec.request.get("recognition") or {}
    return RecognitionConfig(**{k: v for k, v in saved.items() if k in known})


def recorded_model_dir(rec: Recording) -> Path | None:
    m = rec.request.get("model") or ""
    return Path(m) if m else None


def check_model(rec: Recording, model: TrainedModel) -> None:
    names = list(rec.request.get("class_names") or [])
    if names and names != list(model.class_names):
        raise DataError(
            f"{rec.path}: recorded with classes {names}, the model has {list(model.class_names)}: "
            "replay it with the model that recognised it (--model DIR)"
        )


def replay(rec: Recording, model: TrainedModel, library: ObjectLibrary | None = None) -> Replay:
    """`library`: the classes' meshes for a recording made with the pose belief (default:
    the library beside the recorded model, ``<data>/objects`` for ``<data>/models/NAME``)."""
    check_model(rec, model)
    rc = recorded_recognition(rec)
    if library is None and (md := recorded_model_dir(rec)) is not None:
        library = ObjectLibrary(md.parent.parent / "objects")
    # The table the session stood each class on (recordings from before it was kept: none).
    support_z = rec.grasps[0].get("support_z") if rec.grasps else None
    belief = BeliefTracker(
        model, grasp_likelihood_of(model, rc), pose_belief_of(model, rc, library)(support_z)
    )
    out = Replay()
    names = model.class_names
    for g in rec.grasps:
        grasp = Grasp(
            sensor_ids=np.asarray(g["sensor_ids"], dtype=np.int64),
            xyz=np.asarray(g["xyz"], dtype=np.float64).reshape(-1, 3),
            pressures=np.asarray(g["pressures"], dtype=np.float64),
            finger_angles=np.asarray(g["finger_angles"], dtype=np.float64),
            preshape=float(g.get("preshape", 0.0)),
        )
        ignore = np.asarray(g.get("ignored_sensors") or [], dtype=np.int64)
        p, felt, _ = belief.update(grasp, Pose.from_array(np.asarray(g["pose"])), ignore)
        out.labels.append(names[int(np.argmax(p))] if felt else NO_LABEL)
        out.probabilities.append([float(v) for v in p])
    for b in rec.beliefs[: len(rec.grasps)]:
        out.recorded_labels.append(b["label"])
        out.recorded_probabilities.append([float(v) for v in b["probabilities"]])
    diffs = [
        float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
        for a, b in zip(out.probabilities, out.recorded_probabilities, strict=False)
        if len(a) == len(b)
    ]
    out.max_abs_diff = max(diffs, default=0.0)
    return out
