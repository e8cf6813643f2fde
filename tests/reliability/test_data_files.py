"""Hand-edited or damaged dataset files give one-line DataErrors (issue 16, finding 9)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from activetouch.errors import DataError
from activetouch.interfaces import Grasp, Pose
from activetouch.pipelines.collect import SKIPPED_ATTR, pending_poses
from activetouch.recognition.dataset import MANIFEST, Dataset, GraspRecord


def _record(pose_id: int) -> GraspRecord:
    return GraspRecord(
        pose_id=pose_id,
        pose=Pose(np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, 0.0, 1.0])),
        preshape=0.0,
        grasp=Grasp(
            sensor_ids=np.array([1, 2]),
            xyz=np.zeros((2, 3)),
            pressures=np.ones(2),
            finger_angles=np.zeros(3),
        ),
    )


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    ds = Dataset.create_or_open(tmp_path / "ds", {"grid": 1})
    ds.append("cup", [_record(0)], attrs={SKIPPED_ATTR: [3]})
    return tmp_path / "ds"


GRID = SimpleNamespace(pose_ids=np.arange(5))  # pending_poses reads only pose_ids


def test_valid_skipped_ids_are_used(dataset: Path) -> None:
    assert pending_poses(Dataset.open(dataset), "cup", GRID) == [1, 2, 4]


@pytest.mark.parametrize("bad", [5, ["x"], [-1], [True], {"a": 1}, "12"])
def test_malformed_skipped_ids_give_one_line_data_error(dataset: Path, bad: object) -> None:
    mp = dataset / MANIFEST
    m = json.loads(mp.read_text())
    m["objects"]["cup"]["attrs"][SKIPPED_ATTR] = bad
    mp.write_text(json.dumps(m))
    with pytest.raises(DataError, match=SKIPPED_ATTR) as info:
        pending_poses(Dataset.open(dataset), "cup", GRID)
    assert "\n" not in str(info.value) and "cup" in str(info.value)


def test_deleted_manifest_next_to_object_files_is_refused(dataset: Path) -> None:
    files = sorted((dataset / "objects").glob("*.npz"))
    assert files
    before = files[0].read_bytes()
    (dataset / MANIFEST).unlink()
    with pytest.raises(DataError, match=r"manifest\.json is missing"):
        Dataset.create_or_open(dataset, {"grid": 1})
    assert not (dataset / MANIFEST).exists()  # nothing recreated ...
    assert files[0].read_bytes() == before  # ... nor overwritten


def test_new_dataset_in_empty_directory_still_works(tmp_path: Path) -> None:
    (tmp_path / "ds" / "objects").mkdir(parents=True)  # an empty objects dir is fine
    assert Dataset.create_or_open(tmp_path / "ds", {}).object_names() == []
