"""Train in the twin (paper Alg. 1): collect the missing grasps of each object, in parallel
processes (one twin per process) or Ray tasks, then fit the model and save it."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import logging
import multiprocessing as mp
import os
import queue as queue_mod
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from activetouch.config import SIM_ERROR_SETTINGS, Config
from activetouch.device_types import DEFAULT_ARM as FLOATING_ARM
from activetouch.errors import ConfigError
from activetouch.model import TrainedModel, train_model
from activetouch.objects.library import ObjectLibrary
from activetouch.pipelines.collect import CollectStats, collect_object, pending_poses
from activetouch.pipelines.executors import check_executor, exit_with_parent, ray_map
from activetouch.planning.grid import GridPoses, object_grids
from activetouch.recognition.dataset import Dataset, GraspRecord
from activetouch.session.local import placed_devices
from activetouch.session.loop import belief_table_of
from activetouch.storage import locked

log = logging.getLogger(__name__)

Progress = Callable[[str, int, int], None]  # object, poses done, poses in its grid


def dataset_meta(cfg: Config) -> dict:
    """Settings a dataset is bound to: resuming with other settings would mix two datasets."""
    grid = dataclasses.asdict(cfg.grid)
    if grid["layout"] == "per_object":
        del grid["layout"]  # datasets made before the setting existed were per-object
    sim = dataclasses.asdict(cfg.sim)
    for key in SIM_TIMING_KEYS:  # robot-time model only: the grasps are the same
        del sim[key]
    if sim["sensing"] == "tactile":  # keeps datasets made before the setting valid
        del sim["sensing"], sim["stall_contact_site"]
    # A dataset is bound to the real robot's errors only when they are set (collected with
    # them): nominal datasets made before these settings existed stay valid.
    if not any(sim[k] for k in SIM_ERROR_SETTINGS):
        for k in SIM_ERROR_SETTINGS:
            del sim[k]
    meta = {
        "source": "twin",
        "grid": grid,
        "support_margin_m": cfg.recognition.support_margin_m,
        "sim": sim,
        "table": {"center": cfg.workcell.table_center, "size": cfg.workcell.table_size},
    }
    if cfg.hand.family != "reflex":  # another hand's grasps (ReFlex datasets stay valid)
        meta["hand"] = dataclasses.asdict(cfg.hand) | {"type": cfg.hand.type}
    if cfg.arm.type != FLOATING_ARM:
        # Which poses were reached depends on the arm and where the object stood.
        meta["arm"] = {
            "type": cfg.arm.type,
            "object_xyz": cfg.workcell.object_xyz,
            "object_yaw_deg": cfg.workcell.object_yaw_deg,
        }
    return meta


def dataset_variant(cfg: Config) -> str:
    """The default dataset's variant for `cfg` (paths.default_dataset): "" for the floating
    twin's tactile grasps, else what differs (e.g. "baxter", "stall", "baxter-stall")."""
    parts = []
    if cfg.hand.family != "reflex":
        parts.append(cfg.hand.family)
    if cfg.arm.type != FLOATING_ARM:
        parts.append(cfg.arm.type.removeprefix("twin-"))
    if cfg.sim.sensing != "tactile":
        parts.append(cfg.sim.sensing)
    return "-".join(parts)


SIM_TIMING_KEYS = ("hand_period_s", "finger_speed_rad_s")


def _collect_one(
    library_root: str,
    dataset_path: str,
    name: str,
    grid: GridPoses,
    cfg: Config,
    queue: object | None,
) -> CollectStats:
    # Runs in a worker process: it opens its own simulator client and dataset handle.
    ds = Dataset.open(dataset_path)

    sink = queue if queue is not None else _worker_queue

    def report(done: int, total: int) -> None:
        if sink is not None:
            sink.put((name, done, total))  # type: ignore[attr-defined]

    return _collect_into(library_root, ds, name, grid, cfg, report)


def _collect_into(
    library_root: str,
    ds: Dataset | Grasped,
    name: str,
    grid: GridPoses,
    cfg: Config,
    report: Callable[[int, int], None] | None,
) -> CollectStats:
    """Grasp `name` at its pending poses of `grid` in a twin of its own, into `ds`."""
    # deferred: loads pybullet
    from activetouch.sim.twin import open_twin

    spec = ObjectLibrary(library_root).get(name)
    attrs = {"extents": [float(v) for v in spec.extents], "set": spec.set}
    if cfg.arm.type != FLOATING_ARM:
        return _collect_on_devices(library_root, ds, name, grid, cfg, attrs, report)
    with open_twin(spec, cfg.sim, seed=cfg.sim.seed, workcell=cfg.workcell, hand=cfg.hand) as twin:
        return collect_object(
            twin.hand,
            twin.wrist,
            ds,
            name,
            grid,
            attrs=attrs,
            on_grasp=report,
            support_z=twin.support_z,
            support_margin_m=cfg.recognition.support_margin_m,
        )


def _collect_on_devices(
    library_root: str,
    ds: Dataset | Grasped,
    name: str,
    grid: GridPoses,
    cfg: Config,
    attrs: dict,
    report: Callable[[int, int], None] | None,
) -> CollectStats:
    """Collect on the configured simulated devices (e.g. the Baxter twin): the object placed
    through their ``sim/place``, the arm moving between grasps, only the poses its wrist
    `reachable()` allows grasped (the rest recorded as skipped, as on the robot)."""

    data = Path(library_root).parent
    with placed_devices(cfg, data, name, cfg.sim.seed, "train") as (devices, placement):
        return collect_object(
            devices.hand,
            devices.wrist,
            ds,
            name,
            grid,
            attrs=attrs,
            on_grasp=report,
            support_z=placement.support_z(cfg.workcell.table_top_z),
            support_margin_m=cfg.recognition.support_margin_m,
        )


def collect(
    library: ObjectLibrary,
    dataset_path: Path,
    names: list[str],
    cfg: Config,
    workers: int | None = None,
    progress: Progress | None = None,
    executor: str = "local",
    address: str | None = None,
) -> list[CollectStats]:
    """Collect every missing grasp of `names` into the dataset at `dataset_path`, one object
    per worker: `workers` processes here (executor "local") or Ray tasks (`_collect_ray`)."""
    check_executor(executor, address)
    specs = {n: library.get(n) for n in names}  # unknown names fail here, before any work
    ds = Dataset.create_or_open(dataset_path, dataset_meta(cfg))
    grids = object_grids({n: specs[n].extents for n in names}, cfg.grid)
    todo = [n for n in names if pending_poses(ds, n, grids[n])]
    stats = [CollectStats(name=n, already_done=len(grids[n])) for n in names if n not in todo]
    if not todo:
        return stats
    if executor == "ray":
        with run_lock(dataset_path):
            ds = Dataset.open(dataset_path)
            stats.extend(_collect_ray(library, ds, todo, grids, cfg, workers, address, progress))
        return stats
    workers = max(1, min(workers or os.cpu_count() or 1, len(todo)))
    with run_lock(dataset_path):
        if workers == 1:
            for n in todo:
                q = _CallbackQueue(progress)
                root = str(library.root)
                stats.append(_collect_one(root, str(dataset_path), n, grids[n], cfg, q))
            return stats
        stats.extend(_collect_parallel(library, dataset_path, todo, grids, cfg, workers, progress))
    return stats


def _collect_parallel(
    library: ObjectLibrary,
    dataset_path: Path,
    todo: list[str],
    grids: dict[str, GridPoses],
    cfg: Config,
    workers: int,
    progress: Progress | None,
) -> list[CollectStats]:
    # Spawn, not fork: PyBullet and Zenoh keep threads and state that do not survive fork().
    # No Manager process: the progress queue reaches the workers at their start, and every
    # worker exits when this process dies (even by kill -9), so none collects on unwatched.
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    with cf.ProcessPoolExecutor(
        workers, mp_context=ctx, initializer=_worker_init, initargs=(queue, os.getpid())
    ) as pool:
        futures = [
            pool.submit(_collect_one, str(library.root), str(dataset_path), n, grids[n], cfg, None)
            for n in todo
        ]
        pending = set(futures)
        try:
            while pending:
                _, pending = cf.wait(pending, timeout=0.1)
                _drain(queue, progress)
        except KeyboardInterrupt:
            # Objects not started are dropped; those running save their batches and end.
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        _drain(queue, progress)
        return [f.result() for f in futures]


class Grasped:
    """A dataset stand-in for collecting one object away from the dataset (a Ray task, maybe
    on another machine): it knows what the dataset held for the object when the collection
    started (so collect_object resumes the same way) and keeps what collect_object appends,
    for the process that owns the dataset to write (`write_to`)."""

    def __init__(self, ds: Dataset, name: str) -> None:
        self.path = ds.path  # for messages
        self.name = name
        self.known = name in ds.object_names()
        self._attrs = ds.attrs(name) if self.known else {}
        self._done = ds.done_pose_ids(name) if self.known else set()
        self.batches: list[tuple[list[GraspRecord], dict]] = []

    def object_names(self) -> list[str]:
        return [self.name] if self.known or self.batches else []

    def attrs(self, name: str) -> dict:
        out = dict(self._attrs)
        for _, attrs in self.batches:
            out.update(attrs)
        return out

    def done_pose_ids(self, name: str) -> set[int]:
        return self._done | {r.pose_id for records, _ in self.batches for r in records}

    def append(self, name: str, records: list[GraspRecord], attrs: dict | None = None) -> None:
        self.batches.append((list(records), dict(attrs or {})))

    def write_to(self, ds: Dataset) -> None:
        """One append of every batch: the content the batches' own appends would have made
        (records merge by pose id, the later winning; attrs merge, the later winning)."""
        if self.batches:
            records = [r for batch, _ in self.batches for r in batch]
            ds.append(self.name, records, attrs=self.attrs(self.name))


def _collect_remote(
    library_root: str, grasped: Grasped, grid: GridPoses, cfg: Config
) -> tuple[CollectStats, Grasped]:
    # A Ray task: one object, as a local pool worker collects it, into `grasped`. Ray hands
    # numpy arguments over read-only (straight from its object store); the twin's maths
    # (scipy's rotations) wants writable ones.
    grid = GridPoses(*(np.array(a) for a in (grid.pose_ids, grid.poses, grid.preshapes)))
    stats = _collect_into(library_root, grasped, grasped.name, grid, cfg, None)
    return stats, grasped


def _collect_ray(
    library: ObjectLibrary,
    ds: Dataset,
    todo: list[str],
    grids: dict[str, GridPoses],
    cfg: Config,
    workers: int | None,
    address: str | None,
    progress: Progress | None,
) -> list[CollectStats]:
    """`collect` on Ray (executors.ray_map): one task per object, as the local pool spreads
    them. The tasks return their grasps and this process writes them to the dataset as each
    object finishes, so the workers need no shared disk for it (only the object library at
    the same path). An interrupted train keeps the objects finished; progress moves per
    object, not per grasp."""
    calls = []
    for n in todo:
        grasped = Grasped(ds, n)
        if progress is not None:
            progress(n, len(grids[n]) - len(pending_poses(grasped, n, grids[n])), len(grids[n]))
        calls.append((str(library.root), grasped, grids[n], cfg))
    out: list[CollectStats | None] = [None] * len(todo)
    for i, (stats, grasped) in ray_map(_collect_remote, calls, address, workers):
        grasped.write_to(ds)
        out[i] = stats
        if progress is not None:
            progress(todo[i], len(grids[todo[i]]), len(grids[todo[i]]))
    return [s for s in out if s is not None]


_worker_queue: object | None = None  # a worker's progress queue (set by `_worker_init`)


def _worker_init(queue: object, parent: int) -> None:
    """In each pool worker: keep the progress queue; exit as soon as the parent is gone."""
    global _worker_queue
    _worker_queue = queue
    exit_with_parent(parent)


@contextlib.contextmanager
def run_lock(dataset_path: Path) -> Iterator[None]:
    """One collection per dataset at a time: a second `train` on the same dataset waits for
    the first (saying so), rather than writing beside it. The lock is the kernel's (flock),
    so it goes with the process that held it, however it ended."""
    path = Path(dataset_path) / ".collect.lock"
    path.parent.mkdir(parents=True, exist_ok=True)

    def waiting(holder: str) -> None:
        log.warning(
            "another collection (pid %s) is writing to %s; waiting for it to finish",
            holder.strip() or "?",
            dataset_path,
        )

    with locked(path, on_wait=waiting, note=str(os.getpid())):
        yield


class _CallbackQueue:
    """A queue-like sink that calls the progress callback directly (single-process case)."""

    def __init__(self, progress: Progress | None) -> None:
        self.progress = progress

    def put(self, item: tuple[str, int, int]) -> None:
        if self.progress is not None:
            self.progress(*item)


def _drain(queue: object, progress: Progress | None) -> None:

    while True:
        try:
            item = queue.get_nowait()  # type: ignore[attr-defined]
        except queue_mod.Empty:
            return
        if progress is not None:
            progress(*item)


def grid_pose_ids(ds: Dataset, names: list[str], cfg: Config) -> dict[str, np.ndarray] | None:
    """Per object, the ids of the grid `names` are collected at now, from the extents the
    collection stored; None when some object has no stored extents (not collected here)."""
    extents = {}
    for n in names:
        ext = ds.attrs(n).get("extents") if n in ds.object_names() else None
        if ext is None:
            return None
        extents[n] = np.asarray(ext, dtype=np.float64)
    return {n: g.pose_ids for n, g in object_grids(extents, cfg.grid).items()}


def fit_and_save(dataset_path: Path, names: list[str], cfg: Config, out: Path) -> TrainedModel:
    """Fit on the grasps of `names` at the poses of their current grid (with the shared
    layout, grasps stored for a grid that had other objects are left out) and save."""
    ds = Dataset.open(dataset_path)
    model = train_model(ds, cfg, objects=names, pose_ids=grid_pose_ids(ds, names, cfg))
    model.save(out)
    keep_planner_table(model, cfg, out)
    return model


def keep_planner_table(model: TrainedModel, cfg: Config, out: Path) -> None:
    """Compute the planner's grasp-likelihood table now and keep it beside the model, so no
    later process (a daemon starting, each evaluation worker) spends its seconds on it."""
    if model.likelihood is None:
        return
    model.likelihood.table_dir = out
    with contextlib.suppress(ConfigError):  # a model that cannot give it: nothing to keep
        belief_table_of(model, cfg.recognition)
