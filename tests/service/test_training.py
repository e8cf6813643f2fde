from __future__ import annotations

import json

import pytest

from activetouch import paths
from activetouch.errors import DataError
from activetouch.model import train_model
from activetouch.planning.grid import object_grids
from activetouch.recognition.dataset import Dataset
from activetouch.service.cli import main
from activetouch.service.collect import SKIPPED_ATTR, collect_object
from activetouch.service.training import collect, dataset_meta, fit_and_save, grid_pose_ids
from activetouch.sim.objects import ObjectLibrary
from activetouch.sim.twin import open_twin
from tests.conftest import small_config


class CrashError(Exception):
    pass


def test_interrupted_collection_resumes_without_repeating(tmp_path):
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(tmp_path))
    lib.ensure_builtins(["sphere"])
    spec = lib.get("sphere")
    grid = object_grids({"sphere": spec.extents}, cfg.grid)["sphere"]
    ds = Dataset.create_or_open(tmp_path / "ds", dataset_meta(cfg))

    def crash_after_20(done: int, total: int) -> None:
        if done == 20:
            raise CrashError

    with open_twin(spec, cfg.sim) as twin, pytest.raises(CrashError):
        collect_object(twin.hand, twin.wrist, ds, "sphere", grid, batch=8, on_grasp=crash_after_20)
    ds = Dataset.open(tmp_path / "ds")
    saved = ds.done_pose_ids("sphere") | set(ds.attrs("sphere")[SKIPPED_ATTR])
    assert 0 < len(saved) <= 20  # whole batches before the crash are durable

    with open_twin(spec, cfg.sim) as twin:
        stats = collect_object(twin.hand, twin.wrist, ds, "sphere", grid, batch=8)
    assert stats.already_done == len(saved)
    assert stats.grasped + stats.skipped == len(grid) - len(saved)
    final = ds.done_pose_ids("sphere") | set(ds.attrs("sphere")[SKIPPED_ATTR])
    assert final == set(int(i) for i in grid.pose_ids)

    # A complete object needs nothing more.
    again = collect(lib, tmp_path / "ds", ["sphere"], cfg, workers=1)
    assert again[0].grasped == 0


def test_resuming_with_other_settings_is_refused(tmp_path):
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(tmp_path))
    lib.ensure_builtins(["sphere"])
    Dataset.create_or_open(tmp_path / "ds", dataset_meta(cfg))
    cfg.grid.step_deg = 30.0
    with pytest.raises(DataError, match="different settings"):
        collect(lib, tmp_path / "ds", ["sphere"], cfg, workers=1)


def test_train_command_end_to_end_in_two_processes(tmp_path, capsys):
    rc = main(
        [
            "train",
            "--objects",
            "sphere,cup",
            "--data",
            str(tmp_path),
            "--workers",
            "2",
            "--set",
            "grid.step_deg=45",
        ]
    )
    assert rc == 0
    model_dir = paths.default_model(tmp_path)
    doc = json.loads((model_dir / "model.json").read_text())
    assert doc["class_names"] == ["sphere", "cup"]
    ds = Dataset.open(paths.default_dataset(tmp_path))
    assert sorted(ds.object_names()) == ["cup", "sphere"]
    assert "model written to" in capsys.readouterr().out


def test_train_command_user_mistakes_are_one_line_errors(tmp_path, capsys):
    assert main(["train", "--objects", "unicorn", "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "unicorn" in err and "Traceback" not in err
    assert main(["train", "--objects", " , ", "--data", str(tmp_path)]) == 2
    assert main(["train", "--data", str(tmp_path), "--set", "grid.step_deg=abc"]) == 2


def test_fit_uses_only_the_grid_of_the_objects_trained(trained_home, tmp_path):
    # The shared dataset of the service tests holds cup, sphere and bottle at the union of
    # their three grids; a model of cup and sphere learns from the union of those two only.
    cfg = small_config()
    ds = Dataset.open(paths.default_dataset(trained_home))
    ids = grid_pose_ids(ds, ["cup", "sphere"], cfg)
    assert ids is not None
    ext = {n: ds.attrs(n)["extents"] for n in ("cup", "sphere")}
    want = object_grids(ext, cfg.grid)["cup"].pose_ids
    assert set(ids["cup"].tolist()) == set(want.tolist())
    stored = set(ds.read("cup").pose_ids.tolist())
    assert set(want.tolist()) < stored | set(ds.attrs("cup")[SKIPPED_ATTR])
    model = fit_and_save(paths.default_dataset(trained_home), ["cup", "sphere"], cfg, tmp_path)
    assert model.class_names == ("cup", "sphere")
    every = train_model(ds, cfg, objects=["cup", "sphere"])
    assert model.observation.n_poses < every.observation.n_poses


def test_per_object_meta_matches_datasets_made_before_layouts(tmp_path):
    cfg = small_config()
    cfg.grid.layout = "per_object"
    assert "layout" not in dataset_meta(cfg)["grid"]
    cfg.grid.layout = "shared"
    assert dataset_meta(cfg)["grid"]["layout"] == "shared"
