"""The versioned on-disk training dataset: what the training grasps recorded, per object.

Layout (documented for readers without this package in docs/dataset.md)::

    DIR/manifest.json                 format name + version, creation time, meta, object entries
    DIR/objects/<name>.<gen>.npz      one file per object, flat arrays (CSR for the contacts)

The manifest is the commit point: an append writes the object's new arrays to a fresh file
(`<gen>` counts the object's writes), makes it durable, then atomically replaces the manifest
that names it, then removes the superseded file. A crash at any step leaves the previous,
valid dataset (plus at most one stray file that the next append removes). Nothing is pickled:
the arrays are plain ``.npy`` members of a zip, written with fixed timestamps so equal
contents give equal bytes (and an equal `Dataset.checksum`).

Writers in several processes (e.g. one collector per object) are serialised by an flock on
``DIR/.lock``; each append re-reads the manifest under the lock, so none loses another's object.
A reader sees the dataset as of its `open` or its own last append (reopen to see others').
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import io
import json
import os
import re
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from activetouch.errors import DataError
from activetouch.interfaces import Grasp, Pose
from activetouch.storage import atomic_write_bytes, locked

FORMAT_NAME = "activetouch-dataset"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
LOCK_FILE = ".lock"  # empty; writers hold an flock on it while they update the manifest
OBJECTS_DIR = "objects"

# Safe, portable file names: no dots (they separate the generation), no separators.
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
_FILE_RE = re.compile(r"^(?P<name>[A-Za-z0-9][A-Za-z0-9_-]{0,63})\.(?P<gen>[0-9]+)\.npz$")

# name -> (dtype, shape with -1 for "any"; "G"/"N"/"G+1" resolved in _check_arrays)
_ARRAYS: dict[str, tuple[type, tuple[str | int, ...]]] = {
    "pose_ids": (np.int64, ("G",)),
    "poses": (np.float64, ("G", 7)),
    "preshapes": (np.float64, ("G",)),
    "grasp_ptr": (np.int64, ("G+1",)),
    "sensor_ids": (np.int64, ("N",)),
    "xyz": (np.float64, ("N", 3)),
    "pressures": (np.float64, ("N",)),
    "finger_angles": (np.float64, ("G", 3)),
}


@dataclass
class GraspRecord:
    """One training grasp: where the hand was (hand frame in the object frame) and what it felt."""

    pose_id: int  # id of the pose in the collection grid (GridPoses.pose_ids); unique per object
    pose: Pose
    preshape: float
    grasp: Grasp


@dataclass
class ObjectGrasps:
    """Every stored grasp of one object, in ascending pose_id order."""

    name: str
    pose_ids: np.ndarray  # (G,) int64
    poses: np.ndarray  # (G, 7) float64: x y z qx qy qz qw
    preshapes: np.ndarray  # (G,) float64
    grasps: list[Grasp]
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def n_grasps(self) -> int:
        return len(self.pose_ids)


def validate_object_name(name: str) -> str:
    """Return `name` if it is a safe object (file) name, else raise DataError."""
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise DataError(
            f"invalid object name {name!r}: use 1-64 letters, digits, '_' or '-', "
            "starting with a letter or digit"
        )
    return name


def _utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def _json_roundtrip(value: Any, what: str) -> Any:
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError) as e:
        raise DataError(f"{what} must be JSON-serialisable: {e}") from None


def npz_bytes(arrays: Mapping[str, np.ndarray]) -> bytes:
    """An ``.npz`` (zip of ``.npy``) of `arrays`, byte-identical for equal contents."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key in sorted(arrays):
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arrays[key]), allow_pickle=False)
    return buf.getvalue()


def load_npz_bytes(data: bytes, path: Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` held in memory; DataError naming `path` when it is unreadable."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as e:
        raise DataError(f"{path}: corrupt or truncated file ({type(e).__name__}: {e})") from None


def _check_arrays(arrays: dict[str, np.ndarray], path: Path) -> tuple[int, int]:
    """Check names, dtypes and mutually consistent shapes; return (G, N)."""
    missing = sorted(set(_ARRAYS) - set(arrays))
    if missing:
        raise DataError(f"{path}: missing arrays {', '.join(missing)}")
    G = len(arrays["pose_ids"]) if arrays["pose_ids"].ndim == 1 else -1
    N = len(arrays["sensor_ids"]) if arrays["sensor_ids"].ndim == 1 else -1
    dims = {"G": G, "N": N, "G+1": G + 1}
    for key, (dtype, shape) in _ARRAYS.items():
        a = arrays[key]
        want = tuple(dims[s] if isinstance(s, str) else s for s in shape)
        if a.dtype != np.dtype(dtype):
            raise DataError(f"{path}: array {key} has dtype {a.dtype}, expected {np.dtype(dtype)}")
        if a.shape != want or G < 0 or N < 0:
            raise DataError(
                f"{path}: inconsistent array lengths: {key} has shape {a.shape}, expected {want}"
            )
    ptr = arrays["grasp_ptr"]
    if ptr[0] != 0 or ptr[-1] != N or np.any(np.diff(ptr) < 0):
        raise DataError(f"{path}: grasp_ptr is not a valid CSR index into {N} contacts")
    if len(np.unique(arrays["pose_ids"])) != G:
        raise DataError(f"{path}: duplicate pose_ids")
    for key in ("poses", "preshapes", "xyz", "pressures", "finger_angles"):
        if not np.all(np.isfinite(arrays[key])):
            raise DataError(f"{path}: array {key} holds NaN or infinite values")
    return G, N


def _pose_array(pose: Pose | np.ndarray) -> np.ndarray:
    return pose.as_array() if isinstance(pose, Pose) else Pose.from_array(pose).as_array()


def _records_to_arrays(records: list[GraspRecord]) -> dict[str, np.ndarray]:
    G = len(records)
    counts = np.array([r.grasp.n_contacts for r in records], dtype=np.int64)
    ptr = np.zeros(G + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    fa = np.zeros((G, 3))
    for g, r in enumerate(records):
        a = np.asarray(r.grasp.finger_angles, dtype=np.float64).reshape(-1)
        if a.shape != (3,):
            raise DataError(
                f"grasp at pose_id {r.pose_id}: finger_angles has {a.size} values, expected 3"
            )
        fa[g] = a
    cat = np.concatenate
    return {
        "pose_ids": np.array([int(r.pose_id) for r in records], dtype=np.int64),
        "poses": np.array([_pose_array(r.pose) for r in records], dtype=np.float64).reshape(G, 7),
        "preshapes": np.array([float(r.preshape) for r in records], dtype=np.float64),
        "grasp_ptr": ptr,
        "sensor_ids": cat([r.grasp.sensor_ids for r in records] + [np.zeros(0, np.int64)]),
        "xyz": cat([r.grasp.xyz for r in records] + [np.zeros((0, 3))]).astype(np.float64),
        "pressures": cat([r.grasp.pressures for r in records] + [np.zeros(0)]).astype(np.float64),
        "finger_angles": fa,
    }


def _select(arrays: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, np.ndarray]:
    """The grasps at indices `keep` (in that order), CSR re-packed."""
    ptr = arrays["grasp_ptr"]
    starts, ends = ptr[keep], ptr[keep + 1]
    lens = ends - starts
    new_ptr = np.zeros(len(keep) + 1, dtype=np.int64)
    np.cumsum(lens, out=new_ptr[1:])
    # Contact indices of the kept grasps, concatenated without a Python loop.
    idx = np.repeat(starts - new_ptr[:-1], lens) + np.arange(new_ptr[-1], dtype=np.int64)
    out = {k: arrays[k][keep] for k in ("pose_ids", "poses", "preshapes", "finger_angles")}
    out["grasp_ptr"] = new_ptr
    for k in ("sensor_ids", "xyz", "pressures"):
        out[k] = arrays[k][idx]
    return out


def _merge(old: dict[str, np.ndarray] | None, new: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Union of `old` and `new` by pose_id, `new` winning (last occurrence within `new` too)."""
    if old is None:
        both = new
    else:
        both = {k: np.concatenate([old[k], new[k]]) for k in _ARRAYS if k != "grasp_ptr"}
        both["grasp_ptr"] = np.concatenate(
            [old["grasp_ptr"], new["grasp_ptr"][1:] + old["grasp_ptr"][-1]]
        )
    ids = both["pose_ids"]
    # Last occurrence of each pose_id: unique over the reversed array gives first-in-reverse.
    _, first_rev = np.unique(ids[::-1], return_index=True)
    keep = np.sort(len(ids) - 1 - first_rev)
    keep = keep[np.argsort(ids[keep], kind="stable")]
    return _select(both, keep.astype(np.int64))


class Dataset:
    """A training dataset directory. Use `Dataset.create_or_open` or `Dataset.open`."""

    def __init__(self, path: Path, manifest: dict[str, Any]) -> None:
        self.path = path
        self._manifest = manifest

    # --- opening ------------------------------------------------------------------------------

    @classmethod
    def open(cls, path: str | os.PathLike) -> Dataset:
        """Open an existing dataset; DataError when it is missing or not a valid dataset."""
        p = Path(path)
        mp = p / MANIFEST
        if not mp.is_file():
            raise DataError(f"no dataset at {p}: {mp} is missing")
        return cls(p, cls._read_manifest(mp))

    @classmethod
    def create_or_open(cls, path: str | os.PathLike, meta: dict | None = None) -> Dataset:
        """Open the dataset at `path`, creating it (and the directory) when absent.

        `meta` (JSON-able, e.g. the collection settings) is stored on creation. When the dataset
        exists, new keys are added and a key whose stored value differs raises DataError, so a
        resumed collection cannot silently mix incompatible settings."""
        p = Path(path)
        meta = _json_roundtrip(meta or {}, "dataset meta")
        if not isinstance(meta, dict):
            raise DataError("dataset meta must be a dict")
        if p.exists() and not p.is_dir():
            raise DataError(f"cannot create a dataset at {p}: it is a file")
        try:
            (p / OBJECTS_DIR).mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise DataError(f"cannot create a dataset at {p}: {e}") from None
        # Parallel collectors may create or extend the same dataset at once.
        with locked(p / LOCK_FILE):
            return cls._create_or_open_locked(p, meta)

    @classmethod
    def _create_or_open_locked(cls, p: Path, meta: dict[str, Any]) -> Dataset:
        if (p / MANIFEST).is_file():
            ds = cls.open(p)
            stored = ds._manifest["meta"]
            clash = sorted(k for k in meta if k in stored and stored[k] != meta[k])
            if clash:
                details = "; ".join(f"{k}: stored {stored[k]!r}, given {meta[k]!r}" for k in clash)
                raise DataError(
                    f"dataset at {p} was created with different settings ({details}): "
                    "use another directory or the same settings"
                )
            added = {k: v for k, v in meta.items() if k not in stored}
            if added:
                manifest = dict(ds._manifest, meta={**stored, **added})
                ds._write_manifest(manifest)
            return ds
        # Object files without a manifest: the manifest was deleted or lost. Starting a new
        # one would re-collect and overwrite them silently (issue 16, finding 9).
        orphans = sorted((p / OBJECTS_DIR).glob("*.npz")) if (p / OBJECTS_DIR).is_dir() else []
        if orphans:
            raise DataError(
                f"{p / MANIFEST} is missing but {len(orphans)} object file(s) exist in "
                f"{p / OBJECTS_DIR} (e.g. {orphans[0].name}): restore the manifest, or move "
                "the files away to collect again"
            )
        manifest = {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "created": _utc_now(),
            "meta": meta,
            "objects": {},
        }
        ds = cls(p, manifest)
        ds._write_manifest(manifest)
        return ds

    @staticmethod
    def _read_manifest(mp: Path) -> dict[str, Any]:
        try:
            m = json.loads(mp.read_bytes())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise DataError(f"{mp}: not a readable dataset manifest ({e})") from None
        if not isinstance(m, dict) or m.get("format") != FORMAT_NAME:
            raise DataError(
                f"{mp}: not an activetouch dataset manifest (format != {FORMAT_NAME!r})"
            )
        version = m.get("format_version")
        if version != FORMAT_VERSION:
            raise DataError(
                f"{mp}: dataset format version {version!r}, this activetouch reads version "
                f"{FORMAT_VERSION}: collect the data again with this version"
            )
        objects = m.get("objects")
        if not isinstance(objects, dict) or not isinstance(m.get("meta"), dict):
            raise DataError(f"{mp}: malformed manifest (objects/meta missing)")
        for name, entry in objects.items():
            ok = (
                isinstance(entry, dict)
                and _NAME_RE.match(name) is not None
                and isinstance(entry.get("file"), str)
                and (fm := _FILE_RE.match(Path(entry["file"]).name)) is not None
                and fm.group("name") == name
                and entry["file"] == f"{OBJECTS_DIR}/{Path(entry['file']).name}"
                and isinstance(entry.get("n_grasps"), int)
                and isinstance(entry.get("sha256"), str)
                and isinstance(entry.get("attrs", {}), dict)
            )
            if not ok:
                raise DataError(f"{mp}: malformed entry for object {name!r}")
        return m

    def _write_manifest(self, manifest: dict[str, Any]) -> None:
        data = json.dumps(manifest, indent=2, sort_keys=True).encode() + b"\n"
        atomic_write_bytes(self.path / MANIFEST, data)
        self._manifest = manifest

    # --- reading ------------------------------------------------------------------------------

    @property
    def meta(self) -> dict[str, Any]:
        return dict(self._manifest["meta"])

    @property
    def created(self) -> str:
        return str(self._manifest.get("created", ""))

    def object_names(self) -> list[str]:
        return sorted(self._manifest["objects"])

    def n_grasps(self, name: str) -> int:
        entry = self._manifest["objects"].get(name)
        return 0 if entry is None else int(entry["n_grasps"])

    def attrs(self, name: str) -> dict[str, Any]:
        return dict(self._entry(name).get("attrs", {}))

    def _entry(self, name: str) -> dict[str, Any]:
        try:
            return self._manifest["objects"][name]
        except KeyError:
            known = ", ".join(self.object_names()) or "none"
            raise DataError(
                f"dataset at {self.path} has no object {name!r} (has: {known})"
            ) from None

    def _load_arrays(self, name: str) -> dict[str, np.ndarray]:
        entry = self._entry(name)
        fp = self.path / entry["file"]
        try:
            data = fp.read_bytes()
        except FileNotFoundError:
            raise DataError(f"{fp}: file missing (listed in {self.path / MANIFEST})") from None
        except OSError as e:
            raise DataError(f"{fp}: cannot read ({e})") from None
        sha = hashlib.sha256(data).hexdigest()
        if sha != entry["sha256"]:
            raise DataError(
                f"{fp}: sha256 mismatch (file {sha[:12]}..., manifest {entry['sha256'][:12]}...): "
                "the file was modified or damaged"
            )
        arrays = load_npz_bytes(data, fp)
        G, _ = _check_arrays(arrays, fp)
        if entry["n_grasps"] != G:
            raise DataError(f"{fp}: holds {G} grasps, the manifest says {entry['n_grasps']}")
        return arrays

    def read(self, name: str) -> ObjectGrasps:
        """All grasps of object `name`, validated."""
        a = self._load_arrays(name)
        ptr = a["grasp_ptr"]
        grasps = [
            Grasp(
                sensor_ids=a["sensor_ids"][ptr[g] : ptr[g + 1]],
                xyz=a["xyz"][ptr[g] : ptr[g + 1]],
                pressures=a["pressures"][ptr[g] : ptr[g + 1]],
                finger_angles=a["finger_angles"][g],
                preshape=float(a["preshapes"][g]),
            )
            for g in range(len(a["pose_ids"]))
        ]
        return ObjectGrasps(
            name=name,
            pose_ids=a["pose_ids"],
            poses=a["poses"],
            preshapes=a["preshapes"],
            grasps=grasps,
            attrs=self.attrs(name),
        )

    def done_pose_ids(self, name: str) -> set[int]:
        """Pose ids already stored for `name` (empty for an object not yet collected)."""
        validate_object_name(name)
        if name not in self._manifest["objects"]:
            return set()
        return {int(i) for i in self._load_arrays(name)["pose_ids"]}

    def checksum(self) -> str:
        """sha256 over the stored contents: object names, their file digests and attrs."""
        content = {
            name: {"sha256": e["sha256"], "attrs": e.get("attrs", {})}
            for name, e in sorted(self._manifest["objects"].items())
        }
        blob = json.dumps(content, sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).hexdigest()

    def verify(self) -> None:
        """Read every object file; DataError on the first problem."""
        for name in self.object_names():
            self._load_arrays(name)

    # --- writing ------------------------------------------------------------------------------

    def append(self, name: str, records: list[GraspRecord], attrs: dict | None = None) -> None:
        """Add `records` to object `name`; a record whose pose_id is stored already replaces it.

        Atomic: on return the new state is durable; if interrupted, the dataset is in its
        previous state. `attrs` (JSON-able) are merged into the object's attributes."""
        validate_object_name(name)
        attrs = _json_roundtrip(attrs or {}, "object attrs")
        if not isinstance(attrs, dict):
            raise DataError("object attrs must be a dict")
        # Collections of different objects run in parallel processes: serialise the
        # read-modify-write of the manifest, and start from what is on disk now.
        with locked(self.path / LOCK_FILE):
            self._manifest = self._read_manifest(self.path / MANIFEST)
            self._append_locked(name, records, attrs)

    def _append_locked(self, name: str, records: list[GraspRecord], attrs: dict) -> None:
        objects = self._manifest["objects"]
        entry = objects.get(name)
        old = self._load_arrays(name) if entry is not None else None
        merged = _merge(old, _records_to_arrays(list(records)))
        _check_arrays(merged, Path(f"<new data for {name}>"))
        data = npz_bytes(merged)

        gen = 0
        if entry is not None:
            fm = _FILE_RE.match(Path(entry["file"]).name)
            gen = int(fm.group("gen")) + 1 if fm else 0
        odir = self.path / OBJECTS_DIR
        odir.mkdir(exist_ok=True)
        self._remove_strays(name)
        rel = f"{OBJECTS_DIR}/{name}.{gen}.npz"
        atomic_write_bytes(self.path / rel, data)

        new_entry = {
            "file": rel,
            "n_grasps": len(merged["pose_ids"]),
            "sha256": hashlib.sha256(data).hexdigest(),
            "attrs": {**(entry or {}).get("attrs", {}), **attrs},
        }
        manifest = dict(self._manifest, objects={**objects, name: new_entry})
        self._write_manifest(manifest)  # the commit point
        if entry is not None and entry["file"] != rel:
            with contextlib.suppress(OSError):
                (self.path / entry["file"]).unlink()

    def _remove_strays(self, name: str) -> None:
        """Delete files of `name` the manifest does not name (left by an interrupted append)."""
        current = self._manifest["objects"].get(name, {}).get("file")
        odir = self.path / OBJECTS_DIR
        for f in odir.iterdir():
            fm = _FILE_RE.match(f.name)
            stray_data = fm is not None and fm.group("name") == name
            stray_tmp = f.name.startswith(f".{name}.") and f.name.endswith(".tmp")
            if (stray_data and f"{OBJECTS_DIR}/{f.name}" != current) or stray_tmp:
                with contextlib.suppress(OSError):
                    f.unlink()

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r}, objects={self.object_names()})"
