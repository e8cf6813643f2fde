"""How well the hand feels an object: the share of grasps with fewer than 3 contacts.

A grasp with fewer than 3 contacts makes no triangle, so it tells the classifier nothing. Small
or irregular objects used to lose most of their grasps this way (docs/objects.md, "Small
objects"); `train` and `objects add` report the share per object and say what to do when it is
high. The counting is pure; `probe_object` grasps one object at every pose of its own grid in a
fresh twin (about 1-2 s for an object of 5-25 cm).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from activetouch.config import Config
from activetouch.errors import UnreachableError
from activetouch.interfaces import Grasp, Pose
from activetouch.planning.grid import SMALL_OBJECT_GRID, small_object_overrides, training_grid
from activetouch.recognition.contacts import drop_support_contacts

MIN_CONTACTS = 3  # a triangle needs three contacts
# Warn above this share of grasps with fewer than 3 contacts (issue 15's target: >= 85 % of
# an object's reachable grasps feel at least 3 contacts).
FEW_CONTACTS_WARN = 0.15


@dataclass(frozen=True)
class ContactShare:
    """Grasps of one object and how many of them felt fewer than `MIN_CONTACTS` contacts."""

    name: str
    grasps: int  # reachable grasps made
    few: int  # ... with fewer than 3 contacts
    unreachable: int = 0
    mean_contacts: float = 0.0

    @property
    def share(self) -> float:
        return self.few / self.grasps if self.grasps else 1.0

    @property
    def high(self) -> bool:
        return self.share > FEW_CONTACTS_WARN


def share_of(name: str, grasps: Iterable[Grasp], unreachable: int = 0) -> ContactShare:
    """Count the grasps of `name` with fewer than `MIN_CONTACTS` contacts."""
    n = np.array([len(g.sensor_ids) for g in grasps], dtype=np.int64)
    return ContactShare(
        name=name,
        grasps=len(n),
        few=int(np.sum(n < MIN_CONTACTS)),
        unreachable=unreachable,
        mean_contacts=float(n.mean()) if len(n) else 0.0,
    )


def grid_is_small_object(cfg: Config) -> bool:
    """True when the grid already uses the small-object settings."""

    return all(getattr(cfg.grid, k) == v for k, v in SMALL_OBJECT_GRID.items())


def advice(shares: Sequence[ContactShare], cfg: Config) -> list[str]:
    """One warning per object whose share is high, each saying what to do."""

    out = []
    for s in shares:
        if not s.high:
            continue
        head = (
            f"{s.name}: {s.share:.0%} of its {s.grasps} grasps felt fewer than "
            f"{MIN_CONTACTS} contacts (mean {s.mean_contacts:.1f}); such grasps make no "
            "triangle and teach the classifier nothing."
        )
        if cfg.hand.family != "reflex":
            out.append(
                f"{head} The small-object grid is the ReFlex's; for this hand bring the palm "
                f"closer (--set grid.margin_m=..., now {cfg.grid.margin_m}) or leave it out."
            )
        elif not grid_is_small_object(cfg):
            sets = " ".join(f"--set {o}" for o in small_object_overrides())
            out.append(
                f"{head} Use the small-object grid (palm closer, fingers off the table): {sets} "
                "(docs/objects.md, 'Small objects')."
            )
        else:
            out.append(
                f"{head} The small-object grid is in use already: the object is probably too "
                "small, flat or thin for the ReFlex (under ~6 cm, or a finger meets the table "
                "first); scale it up (`objects add --scale`) or leave it out."
            )
    return out


def probe_object(spec, cfg: Config, seed: int = 0) -> ContactShare:
    """Grasp `spec` (an ObjectSpec) at every pose of its own grid in a fresh twin, table
    contacts dropped as in training; the share of grasps with fewer than 3 contacts."""
    # deferred: loads pybullet
    from activetouch.sim.twin import open_twin

    grid = training_grid(spec.extents, cfg.grid)
    grasps: list[Grasp] = []
    unreachable = 0
    with open_twin(spec, cfg.sim, seed=seed, workcell=cfg.workcell, hand=cfg.hand) as twin:
        for i in range(len(grid)):
            pose = Pose.from_array(grid.poses[i])
            twin.hand.open()
            twin.hand.preshape(float(grid.preshapes[i]))
            try:
                twin.wrist.move_to(pose)
            except UnreachableError:
                unreachable += 1
                continue
            g = twin.hand.guarded_close()
            grasps.append(
                drop_support_contacts(g, pose, twin.support_z, cfg.recognition.support_margin_m)
            )
        twin.hand.open()
    return share_of(spec.name, grasps, unreachable)


def dataset_shares(
    dataset, names: Sequence[str], pose_ids: Mapping[str, np.ndarray] | None = None
) -> list[ContactShare]:
    """Shares from a training dataset (grasps stored with table contacts already dropped),
    limited to each object's current grid when `pose_ids` is given."""
    out = []
    for n in names:
        og = dataset.read(n)
        grasps = og.grasps
        if pose_ids is not None and n in pose_ids:
            keep = np.isin(og.pose_ids, pose_ids[n])
            grasps = [g for g, k in zip(grasps, keep, strict=True) if k]
        skipped = len(dataset.attrs(n).get("skipped_pose_ids", []))
        out.append(share_of(n, grasps, skipped))
    return out
