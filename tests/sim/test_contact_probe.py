"""Counting grasps with fewer than 3 contacts, the advice given, and the probe in the twin."""

from __future__ import annotations

import numpy as np
import pytest

from activetouch.config import load_config
from activetouch.interfaces import Grasp
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.grid import small_object_overrides
from activetouch.sim.contact_probe import (
    FEW_CONTACTS_WARN,
    advice,
    grid_is_small_object,
    probe_object,
    share_of,
)


def _grasp(n: int) -> Grasp:
    return Grasp(
        sensor_ids=np.arange(n),
        xyz=np.zeros((n, 3)),
        pressures=np.ones(n),
        finger_angles=np.zeros(3),
        preshape=0.0,
    )


def test_share_counts_grasps_under_three_contacts() -> None:
    s = share_of("x", [_grasp(n) for n in (0, 1, 2, 3, 7)], unreachable=4)
    assert (s.grasps, s.few, s.unreachable) == (5, 3, 4)
    assert s.share == pytest.approx(0.6) and s.high
    assert s.mean_contacts == pytest.approx(13 / 5)
    assert not share_of("y", [_grasp(3)] * 9 + [_grasp(2)]).high  # 10 % is at target
    assert share_of("none", []).share == 1.0  # no reachable grasp at all is the worst case


def test_advice_names_the_fix_or_says_it_is_in_use() -> None:
    bad = share_of("slab", [_grasp(0)] * 3 + [_grasp(5)])
    good = share_of("ball", [_grasp(5)] * 10)
    default = load_config(None, [])
    lines = advice([bad, good], default)
    assert len(lines) == 1 and lines[0].startswith("slab: 75%")
    for o in small_object_overrides():
        assert o in lines[0]
    small = load_config(None, small_object_overrides())
    assert grid_is_small_object(small) and not grid_is_small_object(default)
    (line,) = advice([bad], small)
    assert "in use already" in line and "--set" not in line
    assert pytest.approx(0.15) == FEW_CONTACTS_WARN


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> ObjectLibrary:
    lib = ObjectLibrary(tmp_path_factory.mktemp("lib"))
    lib.ensure_builtins(["sphere", "cup"])
    return lib


def test_probe_small_object_grid_feels_the_cup(library: ObjectLibrary) -> None:
    """The cup (10.7 x 8.2 x 7.2 cm) is felt with >= 3 contacts in >= 85 % of its grasps on
    the small-object grid; the probe counts every pose, reachable or not."""
    from activetouch.planning.grid import training_grid

    cfg = load_config(None, small_object_overrides())
    spec = library.get("cup")
    s = probe_object(spec, cfg)
    assert s.grasps + s.unreachable == len(training_grid(spec.extents, cfg.grid))
    assert s.grasps > 5 and s.share <= 0.15, s
