"""The trained model artifact: histogram ranges + classifier + observation model + metadata.

`train_model` turns a training dataset into a `TrainedModel` (paper Alg. 1 after collection):
triangles of every grasp, histogram ranges from all of them, the classifier p(y | h) on partial
and full histograms, and the observation model p(z' | z, a, y).

On disk (no pickle; `TrainedModel.save` writes a temp directory and renames it into place)::

    DIR/model.json        format name + version, creation time, class names, histogram spec,
                          configuration, dataset checksum, the array files and their sha256
    DIR/classifier.npz    the classifier's `to_arrays()`
    DIR/observation.npz   the observation model's arrays (its scalars are in model.json)
    DIR/likelihood.npz    the training grasps the per-grasp likelihood weighs (models saved
                          before it was added have none: recognition.belief=histogram only)
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from activetouch.config import Config, as_dict
from activetouch.errors import DataError
from activetouch.planning.observation_builder import build_observation_model, cells_for_library
from activetouch.planning.observation_model import ObservationModel
from activetouch.recognition.classifiers import (
    Classifier,
    classifier_from_arrays,
    make_classifier,
)
from activetouch.recognition.dataset import Dataset, ObjectGrasps, load_npz_bytes, npz_bytes
from activetouch.recognition.grasp_likelihood import GraspLikelihood
from activetouch.recognition.histogram import HistogramSpec
from activetouch.recognition.training import grasp_triangles, partial_histograms
from activetouch.recognition.triangles import triangle_params
from activetouch.storage import replace_dir

MODEL_FORMAT_NAME = "activetouch-model"
MODEL_FORMAT_VERSION = 1
MODEL_JSON = "model.json"
CLASSIFIER_FILE = "classifier.npz"
OBSERVATION_FILE = "observation.npz"
HISTOGRAMS_FILE = "class_histograms.npz"
LIKELIHOOD_FILE = "likelihood.npz"


@dataclass
class TrainedModel:
    spec: HistogramSpec
    classifier: Classifier
    observation: ObservationModel
    class_names: tuple[str, ...]
    config: dict[str, Any]  # the Config it was trained with, as a dict
    dataset_checksum: str
    format_version: int = MODEL_FORMAT_VERSION
    created: str = ""
    meta: dict[str, Any] = field(default_factory=dict)  # e.g. grasps per object, dataset path
    # (K, n_bins) L1-normalised histogram of all training grasps per class: the "true"
    # histograms the paper measures test-time distances against.
    class_histograms: np.ndarray | None = None
    likelihood: GraspLikelihood | None = None

    @property
    def n_classes(self) -> int:
        return len(self.class_names)

    def triangles(self, xyz: np.ndarray) -> np.ndarray:
        """Triangle parameters (m, 3) of one grasp's contacts, with the training settings."""
        rc = self.config.get("recognition", {})
        return triangle_params(
            xyz,
            rc.get("parameterisation", "l0,l1,a0"),
            min_side_m=rc.get("min_side_m", 1e-4),
            min_angle_deg=rc.get("min_angle_deg", 1.0),
        )

    def proba(self, counts: np.ndarray) -> np.ndarray:
        """p(y | h) for histogram counts (n_bins,)."""
        return self.classifier.proba(counts)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the model to directory `path` atomically (replacing a model already there)."""
        dest = Path(path)
        foreign = dest.exists() and not (dest / MODEL_JSON).is_file()
        if foreign and (not dest.is_dir() or any(dest.iterdir())):
            raise DataError(f"{dest} exists and is not a model directory: not overwriting it")
        dest.parent.mkdir(parents=True, exist_ok=True)
        files = {
            CLASSIFIER_FILE: npz_bytes(self.classifier.to_arrays()),
            OBSERVATION_FILE: npz_bytes(self.observation.arrays()),
        }
        if self.class_histograms is not None:
            files[HISTOGRAMS_FILE] = npz_bytes({"H": np.asarray(self.class_histograms)})
        if self.likelihood is not None:
            files[LIKELIHOOD_FILE] = npz_bytes(self.likelihood.to_arrays())
        doc = {
            "format": MODEL_FORMAT_NAME,
            "format_version": MODEL_FORMAT_VERSION,
            "created": self.created,
            "class_names": list(self.class_names),
            "spec": self.spec.to_dict(),
            "config": self.config,
            "dataset_checksum": self.dataset_checksum,
            "meta": self.meta,
            "classifier": {
                "file": CLASSIFIER_FILE,
                "sha256": hashlib.sha256(files[CLASSIFIER_FILE]).hexdigest(),
            },
            "observation": {
                "file": OBSERVATION_FILE,
                "sha256": hashlib.sha256(files[OBSERVATION_FILE]).hexdigest(),
                "scalars": self.observation.scalars(),
            },
        }
        if self.class_histograms is not None:
            doc["class_histograms"] = {
                "file": HISTOGRAMS_FILE,
                "sha256": hashlib.sha256(files[HISTOGRAMS_FILE]).hexdigest(),
            }
        if self.likelihood is not None:
            doc["likelihood"] = {
                "file": LIKELIHOOD_FILE,
                "sha256": hashlib.sha256(files[LIKELIHOOD_FILE]).hexdigest(),
            }
        try:
            files[MODEL_JSON] = (json.dumps(doc, indent=2, sort_keys=True) + "\n").encode()
        except (TypeError, ValueError) as e:
            raise DataError(f"model metadata is not JSON-serialisable: {e}") from None

        def fill(tmp: Path) -> None:
            for name, data in files.items():
                (tmp / name).write_bytes(data)

        replace_dir(dest, fill)
        return dest


def _utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def train_model(
    dataset: Dataset,
    cfg: Config,
    objects: list[str] | None = None,
    pose_ids: Mapping[str, np.ndarray] | None = None,
) -> TrainedModel:
    """Fit histogram ranges, classifier and observation model on `objects` of `dataset` (all by
    default, in name order). `pose_ids`: per object, the grid pose ids to learn from (others
    stored in the dataset, e.g. from a grid that had more objects, are left out)."""
    names = list(objects) if objects is not None else dataset.object_names()
    known = set(dataset.object_names())
    unknown = [n for n in names if n not in known]
    if unknown:
        raise DataError(
            f"dataset at {dataset.path} has no object(s) {', '.join(unknown)} "
            f"(has: {', '.join(sorted(known)) or 'none'})"
        )
    if len(set(names)) != len(names):
        raise DataError(f"objects listed twice: {names}")
    if len(names) < 2:
        raise DataError(f"training needs at least 2 objects, got {len(names)}: {names}")
    rc = cfg.recognition
    per_object: list[tuple[str, np.ndarray, list[np.ndarray]]] = []
    grasps: list[tuple[np.ndarray, list]] = []
    for name in names:
        og = dataset.read(name)
        if pose_ids is not None and name in pose_ids:
            keep = np.isin(og.pose_ids, pose_ids[name])
            og = ObjectGrasps(
                og.name,
                og.pose_ids[keep],
                og.poses[keep],
                og.preshapes[keep],
                [g for g, k in zip(og.grasps, keep, strict=True) if k],
                og.attrs,
            )
        tris = grasp_triangles(
            [g.xyz for g in og.grasps],
            rc.parameterisation,
            min_side_m=rc.min_side_m,
            min_angle_deg=rc.min_angle_deg,
        )
        if not any(len(t) for t in tris):
            raise DataError(
                f"object {name!r} in {dataset.path} has no grasp with 3 or more contacts: "
                "nothing to learn from (recollect it)"
            )
        per_object.append((name, og.poses, tris))
        grasps.append((og.poses, og.grasps))

    spec = HistogramSpec.fit(np.concatenate([t for _, _, ts in per_object for t in ts]), rc.bins)
    H, y = partial_histograms(
        [ts for _, _, ts in per_object],
        spec,
        n_samples=rc.partial_samples_per_object,
        min_grasps=rc.partial_min_grasps,
        max_grasps=rc.partial_max_grasps,
        rng=np.random.default_rng(rc.seed),
    )
    classifier = make_classifier(rc.classifier, random_state=rc.seed).fit(H, y)
    class_histograms = np.stack([spec.histogram(np.concatenate(ts)) for _, _, ts in per_object])
    # Pooling cells that follow the library's sizes; the model keeps the cell it used.
    all_poses = np.concatenate([p for _, p, _ in per_object]).reshape(-1, 7)
    cell = cells_for_library(all_poses, cfg.observation)
    if cell != cfg.observation.translation_cell_m:
        cfg = dataclasses.replace(
            cfg, observation=dataclasses.replace(cfg.observation, translation_cell_m=cell)
        )
    observation = build_observation_model(per_object, spec, cfg.observation)
    return TrainedModel(
        spec=spec,
        classifier=classifier,
        observation=observation,
        class_names=tuple(names),
        config=as_dict(cfg),
        dataset_checksum=dataset.checksum(),
        format_version=MODEL_FORMAT_VERSION,
        created=_utc_now(),
        meta={
            "dataset": str(dataset.path),
            "grasps": {n: len(p) for n, p, _ in per_object},
            "triangles": {n: int(sum(len(t) for t in ts)) for n, _, ts in per_object},
        },
        class_histograms=class_histograms,
        likelihood=GraspLikelihood.fit(grasps),
    )


def _read_checked(root: Path, entry: Any, what: str) -> dict[str, np.ndarray]:
    if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
        raise DataError(f"{root / MODEL_JSON}: malformed {what} entry")
    fp = root / entry["file"]
    if fp.parent != root:
        raise DataError(f"{root / MODEL_JSON}: {what} file {entry['file']!r} is outside the model")
    try:
        data = fp.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{fp}: file missing (the model at {root} is incomplete)") from None
    except OSError as e:
        raise DataError(f"{fp}: cannot read ({e})") from None
    if hashlib.sha256(data).hexdigest() != entry.get("sha256"):
        raise DataError(f"{fp}: sha256 mismatch: the file is truncated or was modified")
    return load_npz_bytes(data, fp)


def load_model(path: str | os.PathLike) -> TrainedModel:
    """Read a model saved by `TrainedModel.save`; DataError if missing, corrupt or of another
    format version."""
    root = Path(path)
    mj = root / MODEL_JSON
    if not mj.is_file():
        raise DataError(
            f"no model at {root} ({MODEL_JSON} missing): train one with `activetouch train`"
        )
    try:
        doc = json.loads(mj.read_bytes())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"{mj}: not a readable model file ({e})") from None
    if not isinstance(doc, dict) or doc.get("format") != MODEL_FORMAT_NAME:
        raise DataError(f"{mj}: not an activetouch model (format != {MODEL_FORMAT_NAME!r})")
    version = doc.get("format_version")
    if version != MODEL_FORMAT_VERSION:
        raise DataError(
            f"model at {root} has format version {version}, this activetouch reads version "
            f"{MODEL_FORMAT_VERSION}: retrain with `activetouch train`"
        )
    try:
        spec = HistogramSpec.from_dict(doc["spec"])
        class_names = tuple(str(c) for c in doc["class_names"])
        obs_entry = doc["observation"]
        scalars = obs_entry["scalars"]
        config = doc["config"]
        checksum = str(doc["dataset_checksum"])
    except (KeyError, TypeError) as e:
        raise DataError(f"{mj}: malformed model file (missing {e})") from None
    if not isinstance(scalars, dict) or not isinstance(config, dict):
        raise DataError(f"{mj}: malformed model file (observation scalars / config)")
    classifier = classifier_from_arrays(_read_checked(root, doc.get("classifier"), "classifier"))
    observation = ObservationModel.from_parts(
        scalars, _read_checked(root, obs_entry, "observation")
    )
    class_histograms = None
    if "class_histograms" in doc:
        class_histograms = _read_checked(root, doc["class_histograms"], "class histograms").get("H")
    likelihood = None
    if "likelihood" in doc:
        likelihood = GraspLikelihood.from_arrays(
            _read_checked(root, doc["likelihood"], "grasp likelihood")
        )
    if likelihood is not None:
        likelihood.table_dir = root  # its derived tables are kept beside it
    problems = []
    if likelihood is not None and likelihood.n_classes != len(class_names):
        problems.append(f"grasp likelihood has {likelihood.n_classes} classes")
    if class_histograms is not None and class_histograms.shape != (len(class_names), spec.n_bins):
        problems.append(f"class histograms of shape {class_histograms.shape}")
    if classifier.n_classes != len(class_names):
        problems.append(f"classifier has {classifier.n_classes} classes")
    if observation.class_names != class_names:
        problems.append(f"observation model classes {observation.class_names}")
    if classifier.n_features != spec.n_bins or observation.n_bins != spec.n_bins:
        problems.append(
            f"histogram sizes differ (spec {spec.n_bins}, classifier {classifier.n_features}, "
            f"observation {observation.n_bins})"
        )
    if problems:
        raise DataError(
            f"{mj}: inconsistent model for classes {class_names}: {'; '.join(problems)}"
        )
    return TrainedModel(
        spec=spec,
        classifier=classifier,
        observation=observation,
        class_names=class_names,
        config=config,
        dataset_checksum=checksum,
        format_version=int(version),
        created=str(doc.get("created", "")),
        meta=doc.get("meta", {}) if isinstance(doc.get("meta", {}), dict) else {},
        class_histograms=class_histograms,
        likelihood=likelihood,
    )
