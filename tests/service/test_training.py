from __future__ import annotations

import json
import sys

import pytest

from activetouch import paths
from activetouch.cli.main import main
from activetouch.errors import DataError
from activetouch.model import train_model
from activetouch.objects.library import ObjectLibrary
from activetouch.pipelines.collect import SKIPPED_ATTR, collect_object
from activetouch.pipelines.executors import RAY_LOCAL_ONLY_ENV
from activetouch.pipelines.training import (
    Grasped,
    _collect_into,
    _collect_remote,
    collect,
    dataset_meta,
    fit_and_save,
    grid_pose_ids,
)
from activetouch.planning.grid import object_grids
from activetouch.recognition.dataset import Dataset
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
    out = capsys.readouterr().out
    assert "model written to" in out
    # The cell the library's sizes chose is the one the model keeps and the line names.
    cell = doc["config"]["observation"]["translation_cell_m"]
    assert cell <= 0.06 and doc["config"]["observation"]["cells_from"] == "library"
    assert f"pooled poses ({cell * 100:g} cm cells chosen for the library's sizes)" in " ".join(
        out.split()
    )


def test_train_command_user_mistakes_are_one_line_errors(tmp_path, capsys):
    assert main(["train", "--objects", "unicorn", "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "unicorn" in err and "Traceback" not in err
    assert main(["train", "--objects", " , ", "--data", str(tmp_path)]) == 2
    assert main(["train", "--data", str(tmp_path), "--set", "grid.step_deg=abc"]) == 2


def test_train_executor_mistakes_are_one_line_errors(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # Ray not installed: import ray fails
    monkeypatch.delenv(RAY_LOCAL_ONLY_ENV, raising=False)
    base = ["train", "--objects", "sphere", "--data", str(tmp_path)]
    assert main([*base, "--executor", "ray"]) == 2
    assert main([*base, "--address", "auto"]) == 2  # a cluster, but the local executor
    err = capsys.readouterr().err
    assert "pip install 'activetouch[ray]'" in err and "only with --executor ray" in err
    assert "Traceback" not in err
    with pytest.raises(SystemExit) as e:
        main([*base, "--executor", "dask"])
    assert e.value.code == 2 and "invalid choice: 'dask'" in capsys.readouterr().err
    assert not paths.default_dataset(tmp_path).exists()  # refused before any work


class StopCollectingError(Exception):
    pass


def test_collecting_away_from_the_dataset_writes_what_collecting_into_it_writes(tmp_path):
    """A Ray task's collection (training.Grasped), run here: from a dataset holding part of an
    object, the task resumes where the dataset stands, and what it hands back, written to the
    dataset, is the content a collection straight into the dataset leaves."""
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(tmp_path))
    lib.ensure_builtins(["sphere"])
    spec = lib.get("sphere")
    grid = object_grids({"sphere": spec.extents}, cfg.grid)["sphere"]

    def stop_after_20(done: int, total: int) -> None:
        if done == 20:
            raise StopCollectingError

    for name in ("direct", "away"):  # the same interrupted start in both
        ds = Dataset.create_or_open(tmp_path / name, dataset_meta(cfg))
        with open_twin(spec, cfg.sim) as twin, pytest.raises(StopCollectingError):
            collect_object(
                twin.hand, twin.wrist, ds, "sphere", grid, batch=8, on_grasp=stop_after_20
            )
    root = str(lib.root)
    direct = _collect_into(root, Dataset.open(tmp_path / "direct"), "sphere", grid, cfg, None)

    away = Dataset.open(tmp_path / "away")
    stats, grasped = _collect_remote(root, Grasped(away, "sphere"), grid, cfg)
    assert stats.already_done == direct.already_done > 0 and stats.skipped == direct.skipped > 0
    assert (
        len(grasped.batches) > 1 and away.checksum() != Dataset.open(tmp_path / "direct").checksum()
    )
    grasped.write_to(away)
    assert (
        Dataset.open(tmp_path / "away").checksum() == Dataset.open(tmp_path / "direct").checksum()
    )


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


def test_the_error_settings_bind_a_dataset_only_when_set(tmp_path):
    """A nominal dataset made before sim's error settings existed stays valid; one collected
    with an error set is bound to it."""
    from activetouch.config import SIM_ERROR_SETTINGS

    cfg = small_config()
    nominal = dataset_meta(cfg)
    assert not set(SIM_ERROR_SETTINGS) & set(nominal["sim"])
    ds = Dataset.create_or_open(tmp_path / "ds", nominal)
    cfg.sim.placement_error_m = 0.02
    assert dataset_meta(cfg)["sim"]["placement_error_m"] == 0.02
    with pytest.raises(DataError, match="different settings"):
        Dataset.create_or_open(ds.path, dataset_meta(cfg))


class ReachingWrist:
    """The twin's wrist with a `reachable()` (as Baxter's motion layer has): poses whose index
    in the asked array is in `out` are unreachable; records the asks and the moves."""

    def __init__(self, wrist, out_ids, grid, fail_ids=()):
        self.wrist, self.grid = wrist, grid
        self.out_ids = set(out_ids)
        self.fail_ids = set(fail_ids)  # said reachable, then the move fails
        self.asked: list[int] = []
        self.moved: list = []

    def reachable(self, poses):
        self.asked.append(len(poses))
        ids = [self._id(p) for p in poses]
        return [i not in self.out_ids for i in ids]

    def _id(self, p) -> int:
        import numpy as np

        i = int(np.argmin(np.linalg.norm(self.grid.poses - np.asarray(p), axis=1)))
        return int(self.grid.pose_ids[i])

    def move_to(self, pose) -> None:
        from activetouch.errors import UnreachableError

        pid = self._id(pose.as_array())
        self.moved.append(pid)
        if pid in self.fail_ids:
            raise UnreachableError(f"arm trajectory blocked at t = {pid / 7:.3f} s: the table")
        self.wrist.move_to(pose)


def test_collection_skips_the_poses_the_arm_cannot_reach_without_moving(tmp_path):
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(tmp_path))
    lib.ensure_builtins(["sphere"])
    spec = lib.get("sphere")
    grid = object_grids({"sphere": spec.extents}, cfg.grid)["sphere"]
    ds = Dataset.create_or_open(tmp_path / "ds", dataset_meta(cfg))
    out = {int(p) for p in grid.pose_ids[::3]}
    fail = {int(p) for p in grid.pose_ids[1::3][:2]}
    with open_twin(spec, cfg.sim) as twin:
        wrist = ReachingWrist(twin.wrist, out, grid, fail)
        stats = collect_object(twin.hand, wrist, ds, "sphere", grid, batch=4)  # type: ignore[arg-type]
    assert wrist.asked == [len(grid)]  # once, for every pending pose
    # Moves that failed after the arm accepted the pose: counted by kind, numbers left out.
    assert stats.failed["arm trajectory blocked at t = # s: the table"] == len(fail)
    assert sum(stats.failed.values()) == stats.skipped - len(out)  # the twin's own too
    assert stats.checked == len(grid) and stats.reachable == len(grid) - len(out)
    assert not set(wrist.moved) & out and len(wrist.moved) == len(grid) - len(out)
    skipped = set(Dataset.open(tmp_path / "ds").attrs("sphere")[SKIPPED_ATTR])
    assert out <= skipped and stats.skipped == len(skipped)
    assert stats.grasped + stats.skipped == len(grid)

    # Nothing pending: the arm is not asked again.
    with open_twin(spec, cfg.sim) as twin:
        again = ReachingWrist(twin.wrist, out, grid)
        stats = collect_object(twin.hand, again, ds, "sphere", grid)  # type: ignore[arg-type]
    assert again.asked == [] and stats.reachable is None and stats.already_done == len(grid)


def test_train_prints_how_many_grid_poses_the_arm_reaches(tmp_path, capsys, monkeypatch):
    from activetouch.pipelines import training

    real = training.collect

    def collect_with_an_arm(*args, **kwargs):  # as a collection with reachable() reports it
        stats = real(*args, **kwargs)
        stats[0].reachable, stats[0].checked = 5, 9
        stats[0].failed = {"no path within # s": 2}
        return stats

    monkeypatch.setattr(training, "collect", collect_with_an_arm)
    args = ["train", "--objects", "sphere,cup", "--data", str(tmp_path), "--workers", "1"]
    assert main([*args, "--set", "grid.step_deg=60"]) == 0
    out = capsys.readouterr().out
    assert "sphere: the arm reaches 5 of the 9 grid poses checked" in out
    assert "cup: the arm reaches" not in out
    assert "sphere: 2 moves failed (most: 2 x no path within # s)" in out
    assert "arm grasped at" in out and "138 actions of 1063" in out
