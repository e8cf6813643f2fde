from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from activetouch.errors import DataError
from activetouch.interfaces import Grasp, Pose
from activetouch.recognition import dataset as dsmod
from activetouch.recognition.dataset import (
    FORMAT_VERSION,
    Dataset,
    GraspRecord,
    validate_object_name,
)


def make_record(
    pose_id: int, rng: np.random.Generator, n_contacts: int | None = None
) -> GraspRecord:
    n = int(rng.integers(0, 8)) if n_contacts is None else n_contacts
    quat = rng.normal(size=4)
    return GraspRecord(
        pose_id=pose_id,
        pose=Pose(rng.normal(size=3) * 0.1, quat),
        preshape=float(rng.choice([0.0, 0.8])),
        grasp=Grasp(
            sensor_ids=rng.choice(38, size=n, replace=False),
            xyz=rng.normal(size=(n, 3)) * 0.05,
            pressures=rng.random(n),
            finger_angles=rng.random(3),
        ),
    )


def assert_same(rec: GraspRecord, got_pose: np.ndarray, got_preshape: float, got: Grasp) -> None:
    np.testing.assert_array_equal(got_pose, rec.pose.as_array())
    assert got_preshape == rec.preshape
    assert got.preshape == rec.preshape
    np.testing.assert_array_equal(got.sensor_ids, rec.grasp.sensor_ids)
    np.testing.assert_array_equal(got.xyz, rec.grasp.xyz)
    np.testing.assert_array_equal(got.pressures, rec.grasp.pressures)
    np.testing.assert_array_equal(got.finger_angles, rec.grasp.finger_angles)


def test_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    ds = Dataset.create_or_open(tmp_path / "d", meta={"grid_step_deg": 25})
    recs = [make_record(i, rng) for i in (5, 1, 3)]
    recs[1] = make_record(1, rng, n_contacts=0)  # an empty grasp must survive too
    ds.append("mug", recs, attrs={"set": "sim"})
    ds.append("cup", [make_record(0, rng)])

    again = Dataset.open(tmp_path / "d")
    assert again.object_names() == ["cup", "mug"]
    assert again.meta == {"grid_step_deg": 25}
    og = again.read("mug")
    assert og.attrs == {"set": "sim"}
    assert og.pose_ids.tolist() == [1, 3, 5]  # stored in pose_id order
    by_id = {r.pose_id: r for r in recs}
    for g, pid in enumerate(og.pose_ids):
        assert_same(by_id[int(pid)], og.poses[g], og.preshapes[g], og.grasps[g])
    assert again.done_pose_ids("mug") == {1, 3, 5}
    assert again.done_pose_ids("bowl") == set()
    assert again.checksum() == ds.checksum()


def test_plain_numpy_reads_the_files(tmp_path: Path) -> None:
    # The documented layout, read without this package (docs/dataset.md).
    rng = np.random.default_rng(1)
    recs = [make_record(i, rng, n_contacts=4) for i in range(3)]
    Dataset.create_or_open(tmp_path).append("bowl", recs)
    m = json.loads((tmp_path / "manifest.json").read_text())
    assert m["format"] == "activetouch-dataset" and m["format_version"] == FORMAT_VERSION
    entry = m["objects"]["bowl"]
    z = np.load(tmp_path / entry["file"], allow_pickle=False)
    assert entry["n_grasps"] == len(z["pose_ids"]) == 3
    ptr = z["grasp_ptr"]
    np.testing.assert_array_equal(z["xyz"][ptr[2] : ptr[3]], recs[2].grasp.xyz)


def test_append_merges_and_replaces(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    ds = Dataset.create_or_open(tmp_path)
    first = [make_record(i, rng) for i in range(4)]
    ds.append("cup", first, attrs={"a": 1})
    replacement = make_record(2, rng, n_contacts=5)
    ds.append("cup", [replacement, make_record(7, rng)], attrs={"b": 2})
    og = ds.read("cup")
    assert og.pose_ids.tolist() == [0, 1, 2, 3, 7]
    assert og.attrs == {"a": 1, "b": 2}
    assert_same(replacement, og.poses[2], og.preshapes[2], og.grasps[2])
    assert_same(first[3], og.poses[3], og.preshapes[3], og.grasps[3])
    # Exactly one data file per object remains.
    assert sorted(p.name for p in (tmp_path / "objects").iterdir()) == ["cup.1.npz"]


def test_checksum_depends_on_contents_only(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    recs = [make_record(i, rng) for i in range(3)]
    a = Dataset.create_or_open(tmp_path / "a")
    a.append("cup", recs)
    b = Dataset.create_or_open(tmp_path / "b")
    b.append("cup", recs[:1])
    b.append("cup", recs[1:])
    assert a.checksum() == b.checksum()
    b.append("cup", [make_record(9, rng)])
    assert a.checksum() != b.checksum()


def test_interrupted_append_leaves_previous_state(tmp_path: Path, monkeypatch) -> None:
    rng = np.random.default_rng(4)
    ds = Dataset.create_or_open(tmp_path)
    ds.append("cup", [make_record(i, rng) for i in range(3)])
    before = ds.checksum()
    real_replace = os.replace
    calls = {"n": 0}

    def crash_on_manifest(src, dst):  # the data file lands, the commit does not
        calls["n"] += 1
        if Path(dst).name == "manifest.json":
            raise OSError("simulated crash")
        return real_replace(src, dst)

    monkeypatch.setattr(dsmod.os, "replace", crash_on_manifest)
    with pytest.raises(OSError, match="simulated crash"):
        ds.append("cup", [make_record(i, rng) for i in range(3, 6)])
    assert calls["n"] == 2
    monkeypatch.setattr(dsmod.os, "replace", real_replace)

    reopened = Dataset.open(tmp_path)
    reopened.verify()
    assert reopened.checksum() == before
    assert reopened.done_pose_ids("cup") == {0, 1, 2}
    assert not [p for p in (tmp_path).iterdir() if p.name.endswith(".tmp")]

    # Resume: the collector skips what is done and appends the rest.
    todo = [i for i in range(6) if i not in reopened.done_pose_ids("cup")]
    reopened.append("cup", [make_record(i, rng) for i in todo])
    assert Dataset.open(tmp_path).done_pose_ids("cup") == set(range(6))
    assert sorted(p.name for p in (tmp_path / "objects").iterdir()) == ["cup.1.npz"]


def test_crash_before_data_file_lands(tmp_path: Path, monkeypatch) -> None:
    rng = np.random.default_rng(5)
    ds = Dataset.create_or_open(tmp_path)
    ds.append("cup", [make_record(0, rng)])

    def crash(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(dsmod.os, "replace", crash)
    with pytest.raises(OSError):
        ds.append("cup", [make_record(1, rng)])
    monkeypatch.undo()
    assert Dataset.open(tmp_path).done_pose_ids("cup") == {0}
    assert sorted(p.name for p in (tmp_path / "objects").iterdir()) == ["cup.0.npz"]


def test_truncated_file_rejected(tmp_path: Path) -> None:
    rng = np.random.default_rng(6)
    ds = Dataset.create_or_open(tmp_path)
    ds.append("cup", [make_record(i, rng, n_contacts=6) for i in range(5)])
    entry = json.loads((tmp_path / "manifest.json").read_text())["objects"]["cup"]
    f = tmp_path / entry["file"]
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match=r"cup\.0\.npz.*sha256 mismatch"):
        Dataset.open(tmp_path).read("cup")
    # Truncated and the manifest updated to match: still caught, as a corrupt zip.
    m = json.loads((tmp_path / "manifest.json").read_text())
    import hashlib

    m["objects"]["cup"]["sha256"] = hashlib.sha256(f.read_bytes()).hexdigest()
    (tmp_path / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(DataError, match=r"cup\.0\.npz: corrupt or truncated"):
        Dataset.open(tmp_path).read("cup")


def test_inconsistent_arrays_rejected(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    ds = Dataset.create_or_open(tmp_path)
    ds.append("cup", [make_record(i, rng, n_contacts=4) for i in range(3)])
    m = json.loads((tmp_path / "manifest.json").read_text())
    f = tmp_path / m["objects"]["cup"]["file"]
    with np.load(f) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["pressures"] = arrays["pressures"][:-1]
    data = dsmod.npz_bytes(arrays)
    f.write_bytes(data)
    import hashlib

    m["objects"]["cup"]["sha256"] = hashlib.sha256(data).hexdigest()
    (tmp_path / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(DataError, match=r"cup\.0\.npz: inconsistent array lengths: pressures"):
        Dataset.open(tmp_path).read("cup")


def test_missing_file_and_wrong_version_rejected(tmp_path: Path) -> None:
    rng = np.random.default_rng(8)
    ds = Dataset.create_or_open(tmp_path)
    ds.append("cup", [make_record(0, rng)])
    (tmp_path / "objects" / "cup.0.npz").unlink()
    with pytest.raises(DataError, match=r"cup\.0\.npz: file missing"):
        Dataset.open(tmp_path).read("cup")

    m = json.loads((tmp_path / "manifest.json").read_text())
    m["format_version"] = FORMAT_VERSION + 2
    (tmp_path / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(
        DataError, match=rf"manifest\.json: dataset format version {FORMAT_VERSION + 2}"
    ):
        Dataset.open(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(DataError, match=r"manifest\.json: not a readable"):
        Dataset.open(tmp_path)
    with pytest.raises(DataError, match="no dataset at"):
        Dataset.open(tmp_path / "nowhere")


def test_object_names_validated(tmp_path: Path) -> None:
    ds = Dataset.create_or_open(tmp_path)
    for bad in ("", "../x", "a/b", "a.b", ".hidden", "x" * 65, "sp ace"):
        with pytest.raises(DataError, match="invalid object name"):
            ds.append(bad, [])
    assert validate_object_name("toilet_paper") == "toilet_paper"
    with pytest.raises(DataError, match="no object 'mug'"):
        ds.read("mug")


def test_meta_conflict_on_resume(tmp_path: Path) -> None:
    Dataset.create_or_open(tmp_path, meta={"step": 25})
    ds = Dataset.create_or_open(tmp_path, meta={"step": 25, "arm": "sim"})
    assert ds.meta == {"step": 25, "arm": "sim"}
    with pytest.raises(DataError, match=r"different settings.*step"):
        Dataset.create_or_open(tmp_path, meta={"step": 45})


def _append_many(path: str, name: str, n: int) -> None:
    ds = Dataset.open(path)
    rng = np.random.default_rng(len(name))
    for i in range(n):
        ds.append(name, [make_record(i, rng)])


def test_parallel_processes_appending_different_objects_lose_nothing(tmp_path: Path) -> None:
    import multiprocessing as mp

    Dataset.create_or_open(tmp_path)
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_append_many, args=(str(tmp_path), n, 8)) for n in ("a", "b")]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    ds = Dataset.open(tmp_path)
    assert sorted(ds.object_names()) == ["a", "b"]
    assert ds.done_pose_ids("a") == ds.done_pose_ids("b") == set(range(8))


def _create_and_append(path: str, name: str) -> None:
    ds = Dataset.create_or_open(path, meta={"step": 25})
    ds.append(name, [make_record(0, np.random.default_rng(0))])


def test_parallel_creation_of_a_new_dataset_loses_nothing(tmp_path: Path) -> None:
    import multiprocessing as mp

    ctx = mp.get_context("fork")  # cheap to start; the lock is per open file, not per process
    names = ["c0", "c1", "c2", "c3"]
    procs = [ctx.Process(target=_create_and_append, args=(str(tmp_path / "d"), n)) for n in names]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    ds = Dataset.open(tmp_path / "d")
    assert ds.object_names() == names
    assert ds.meta == {"step": 25}
