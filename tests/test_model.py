from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from activetouch.config import Config, GridConfig
from activetouch.errors import DataError
from activetouch.interfaces import Grasp, Pose
from activetouch.model import MODEL_FORMAT_VERSION, load_model, train_model
from activetouch.planning.grid import training_grid
from activetouch.recognition.dataset import Dataset, GraspRecord
from activetouch.recognition.synthetic import synthetic_grasp

SHAPES = {"cube": "box_cube", "rod": "cylinder_thin", "ball": "sphere_large"}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Dataset:
    rng = np.random.default_rng(0)
    ds = Dataset.create_or_open(tmp_path_factory.mktemp("data") / "ds", meta={"synthetic": True})
    grid = training_grid(np.array([0.1, 0.1, 0.12]), GridConfig(step_deg=45.0))
    for name, shape in SHAPES.items():
        records = []
        for pid, pose, pre in zip(grid.pose_ids, grid.poses, grid.preshapes, strict=True):
            xyz = synthetic_grasp(shape, rng, (2, 7))  # some grasps have too few contacts
            n = len(xyz)
            g = Grasp(np.arange(n), xyz, np.ones(n), np.zeros(3), float(pre))
            records.append(GraspRecord(int(pid), Pose.from_array(pose), float(pre), g))
        ds.append(name, records)
    return ds


def small_config(granularity: str = "triangle", classifier: str = "svm") -> Config:
    cfg = Config()
    cfg.recognition.partial_samples_per_object = 30
    cfg.recognition.classifier = classifier
    cfg.observation.granularity = granularity
    return cfg


@pytest.mark.parametrize(
    ("granularity", "classifier"), [("triangle", "svm"), ("grasp", "nn_inner")]
)
def test_train_save_load_round_trip(
    dataset: Dataset, tmp_path: Path, granularity: str, classifier: str
) -> None:
    model = train_model(dataset, small_config(granularity, classifier))
    assert model.class_names == ("ball", "cube", "rod")
    assert model.dataset_checksum == dataset.checksum()
    assert model.observation.granularity == granularity
    assert model.observation.n_bins == model.spec.n_bins == 1000
    assert model.meta["grasps"]["cube"] == dataset.n_grasps("cube")

    out = model.save(tmp_path / "model")
    again = load_model(out)
    assert again.class_names == model.class_names
    assert again.spec == model.spec
    assert again.config == model.config
    assert again.format_version == MODEL_FORMAT_VERSION
    assert again.created == model.created and again.meta == model.meta
    rng = np.random.default_rng(1)
    H = rng.random((20, 1000)) * (rng.random((20, 1000)) < 0.05)
    np.testing.assert_array_equal(again.classifier.proba_many(H), model.classifier.proba_many(H))
    assert again.observation.scalars() == model.observation.scalars()
    assert model.class_histograms is not None
    assert model.class_histograms.shape == (3, 1000)
    np.testing.assert_allclose(model.class_histograms.sum(axis=1), 1.0)
    np.testing.assert_array_equal(again.class_histograms, model.class_histograms)
    for k, v in model.observation.arrays().items():
        np.testing.assert_array_equal(getattr(again.observation, k), v)
        assert getattr(again.observation, k).dtype == v.dtype
    # The grasp likelihood holds every training grasp, classes in order.
    assert model.likelihood is not None and again.likelihood is not None
    assert len(model.likelihood.labels) == sum(model.meta["grasps"].values())
    for k, v in model.likelihood.to_arrays().items():
        np.testing.assert_array_equal(again.likelihood.to_arrays()[k], v)
    obs = model.observation
    if granularity == "grasp":
        # Each outcome adds the triangle bins of the training grasp it names.
        og = obs.out_grasp
        assert og.shape == (obs.n_outcomes,)
        ds_grasps = [g for n in model.class_names for g in dataset.read(n).grasps]
        for o in range(0, obs.n_outcomes, max(1, obs.n_outcomes // 25)):
            tris = model.triangles(ds_grasps[og[o]].xyz)
            want = np.sort(model.spec.bin_index(tris))
            got = np.sort(obs.out_bin[obs.out_ptr[o] : obs.out_ptr[o + 1]])
            np.testing.assert_array_equal(got, want)
    else:
        assert len(obs.out_grasp) == 0  # a triangle outcome is no one grasp

    # Saving again replaces the model in place; no temp directories are left behind.
    model.save(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]
    load_model(out)


def test_train_subset_and_bad_objects(dataset: Dataset) -> None:
    model = train_model(dataset, small_config(), objects=["rod", "cube"])
    assert model.class_names == ("rod", "cube")
    assert model.classifier.n_classes == 2
    with pytest.raises(DataError, match="no object"):
        train_model(dataset, small_config(), objects=["cube", "teapot"])
    with pytest.raises(DataError, match="at least 2 objects"):
        train_model(dataset, small_config(), objects=["cube"])


@pytest.fixture(scope="module")
def saved(dataset: Dataset, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return train_model(dataset, small_config()).save(tmp_path_factory.mktemp("m") / "model")


def copy_model(src: Path, dst: Path) -> Path:
    dst.mkdir()
    for f in src.iterdir():
        (dst / f.name).write_bytes(f.read_bytes())
    return dst


def test_wrong_version_rejected(saved: Path, tmp_path: Path) -> None:
    m = copy_model(saved, tmp_path / "m")
    doc = json.loads((m / "model.json").read_text())
    doc["format_version"] = 3
    (m / "model.json").write_text(json.dumps(doc))
    with pytest.raises(
        DataError,
        match=r"has format version 3, this activetouch reads version 1: retrain with "
        r"`activetouch train`",
    ):
        load_model(m)


@pytest.mark.parametrize("victim", ["observation.npz", "classifier.npz"])
def test_truncated_file_rejected(saved: Path, tmp_path: Path, victim: str) -> None:
    m = copy_model(saved, tmp_path / "m")
    data = (m / victim).read_bytes()
    (m / victim).write_bytes(data[: len(data) // 3])
    with pytest.raises(DataError, match=rf"{victim}: sha256 mismatch"):
        load_model(m)
    (m / victim).unlink()
    with pytest.raises(DataError, match=rf"{victim}: file missing"):
        load_model(m)


def test_missing_and_corrupt_model(saved: Path, tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no model at"):
        load_model(tmp_path / "nothing")
    m = copy_model(saved, tmp_path / "m")
    (m / "model.json").write_text("{")
    with pytest.raises(DataError, match="not a readable model file"):
        load_model(m)
    (tmp_path / "occupied").mkdir()
    (tmp_path / "occupied" / "notes.txt").write_text("mine")
    with pytest.raises(DataError, match="not a model directory"):
        load_model(saved).save(tmp_path / "occupied")
