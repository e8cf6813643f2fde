"""Training collection (paper Alg. 1): grasp an object at every pose of its grid, store contacts.

Runs on any `Hand` + `WristMotion` pair. Progress is saved in batches to the dataset, so an
interrupted collection resumes where it stopped: poses already grasped, or found unreachable,
are skipped.

A wrist that can say which poses it reaches (`reachable(poses) -> bool array`, e.g. Baxter's
motion layer) is asked once per object for the pending grid poses; the unreachable ones are
recorded as skipped without moving, and the count is logged and returned (`CollectStats`).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from activetouch.errors import ActiveTouchError, DataError, UnreachableError
from activetouch.interfaces import Hand, Pose
from activetouch.planning.grid import GridPoses
from activetouch.planning.motion.base import WristMotion
from activetouch.recognition.contacts import drop_support_contacts
from activetouch.recognition.dataset import MANIFEST, Dataset, GraspRecord

log = logging.getLogger(__name__)

SKIPPED_ATTR = "skipped_pose_ids"  # unreachable poses, kept in the object's attrs for resuming


@dataclass
class CollectStats:
    name: str
    grasped: int = 0
    skipped: int = 0
    already_done: int = 0
    seconds: float = 0.0
    # With a wrist that has `reachable()`: how many of the `checked` pending grid poses it
    # reaches (None: the wrist cannot tell; every pose was tried).
    reachable: int | None = None
    checked: int = 0
    # Moves that failed at poses the wrist had said it reaches (or could not tell), by reason.
    failed: dict[str, int] = field(default_factory=dict)


def _skipped(dataset: Dataset, name: str) -> set[int]:
    """The object's unreachable pose ids; DataError (one line) when the manifest holds
    anything but a list of non-negative integers there (a hand-edited `5` or `["x"]`)."""
    value = dataset.attrs(name).get(SKIPPED_ATTR, [])
    if not isinstance(value, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value
    ):
        raise DataError(
            f"{dataset.path / MANIFEST}: object {name!r}: attrs.{SKIPPED_ATTR} must be a list "
            f"of pose ids (non-negative integers), got {str(value)[:80]}"
        )
    return set(value)


def pending_poses(dataset: Dataset, name: str, grid: GridPoses) -> list[int]:
    """Indices into `grid` of poses not yet grasped nor known to be unreachable."""
    done: set[int] = set()
    if name in dataset.object_names():
        done = dataset.done_pose_ids(name) | _skipped(dataset, name)
    return [i for i, pid in enumerate(grid.pose_ids) if int(pid) not in done]


def collect_object(
    hand: Hand,
    wrist: WristMotion,
    dataset: Dataset,
    name: str,
    grid: GridPoses,
    attrs: dict | None = None,
    batch: int = 16,
    on_grasp: Callable[[int, int], None] | None = None,
    support_z: float | None = None,
    support_margin_m: float = 0.005,
) -> CollectStats:
    """Grasp `name` at every pending pose of `grid`, appending to `dataset` every `batch` poses.

    `on_grasp(done, total)` is called after each pose (for progress bars). With `support_z`
    (the table plane in the object frame) contacts on the table are not stored."""
    t0 = time.perf_counter()
    todo = pending_poses(dataset, name, grid)
    stats = CollectStats(name=name, already_done=len(grid) - len(todo))
    known = name in dataset.object_names()
    skipped = list(dataset.attrs(name).get(SKIPPED_ATTR, [])) if known else []
    base_attrs = dict(attrs or {})
    records: list[GraspRecord] = []

    def flush() -> None:
        a = {**base_attrs, SKIPPED_ATTR: sorted(set(skipped))}
        dataset.append(name, records, attrs=a)
        records.clear()

    out_of_reach = _out_of_reach(wrist, name, grid, todo, stats)
    for n, i in enumerate(todo, start=1):
        pid = int(grid.pose_ids[i])
        pose = Pose.from_array(grid.poses[i])
        if i in out_of_reach:  # known unreachable: recorded as skipped, nothing moves
            skipped.append(pid)
            stats.skipped += 1
            if n % batch == 0 or n == len(todo):
                flush()
            if on_grasp is not None:
                on_grasp(stats.already_done + n, len(grid))
            continue
        hand.open()
        hand.preshape(float(grid.preshapes[i]))
        try:
            wrist.move_to(pose)
        except UnreachableError as e:
            skipped.append(pid)
            stats.skipped += 1
            why = failure_kind(str(e))
            stats.failed[why] = stats.failed.get(why, 0) + 1
            log.debug("%s: pose %d not reached: %s", name, pid, e)
        else:
            grasp = hand.guarded_close()
            if support_z is not None:
                grasp = drop_support_contacts(grasp, pose, support_z, support_margin_m)
            records.append(GraspRecord(pid, pose, float(grid.preshapes[i]), grasp))
            stats.grasped += 1
            hand.open()
        if n % batch == 0 or n == len(todo):  # skipped poses count too: they are progress
            flush()
        if on_grasp is not None:
            on_grasp(stats.already_done + n, len(grid))
    if not todo and name not in dataset.object_names():
        flush()  # an empty grid still registers the object
    stats.seconds = time.perf_counter() - t0
    return stats


def failure_kind(message: str) -> str:
    """A failed move's reason without its numbers (times, depths, counts), to count by kind."""
    return re.sub(r"[-+]?\d+(\.\d+)?", "#", message)[:120]


def _out_of_reach(
    wrist: WristMotion, name: str, grid: GridPoses, todo: list[int], stats: CollectStats
) -> set[int]:
    """Indices (into `grid`) among `todo` that the wrist's `reachable()` rules out, asked once
    for all of them; empty when the wrist has no `reachable`."""
    reachable = getattr(wrist, "reachable", None)
    if reachable is None or not todo:
        return set()
    t = time.perf_counter()
    ok = np.asarray(reachable(grid.poses[todo]), dtype=bool).reshape(-1)
    if ok.shape != (len(todo),):
        raise ActiveTouchError(
            f"the wrist's reachable() gave {ok.shape[0]} verdicts for {len(todo)} poses"
        )
    stats.checked = len(todo)
    stats.reachable = int(ok.sum())
    log.info(
        "%s: the arm reaches %d of %d pending grid poses (checked in %.1f s)",
        name,
        stats.reachable,
        stats.checked,
        time.perf_counter() - t,
    )
    return {i for i, good in zip(todo, ok, strict=True) if not good}
