"""`objects add` and `train` report the share of grasps with fewer than 3 contacts and warn,
with what to do, when it is high."""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh

from activetouch.cli.main import main
from activetouch.planning.grid import small_object_overrides


def _sets(overrides: list[str]) -> list[str]:
    return [a for o in overrides for a in ("--set", o)]


@pytest.fixture(scope="module")
def builtins(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from activetouch.objects.library import ObjectLibrary

    root = tmp_path_factory.mktemp("objects")
    ObjectLibrary(root).ensure_builtins()
    return root


@pytest.fixture
def data(tmp_path: Path, builtins: Path) -> Path:
    import shutil

    shutil.copytree(builtins, tmp_path / "data" / "objects")
    return tmp_path / "data"


@pytest.fixture
def slab(tmp_path: Path) -> Path:
    """A 12 x 12 x 2.5 cm slab: a finger meets the table before it meets the slab."""
    path = tmp_path / "slab.stl"
    trimesh.creation.box((0.12, 0.12, 0.025)).export(path)
    return path


def test_objects_add_warns_for_a_flat_object_with_the_fix(data: Path, slab: Path, capsys):
    assert main(["objects", "add", "slab", str(slab), "--data", str(data)]) == 0
    out, err = capsys.readouterr()
    assert "test grasps felt fewer than 3 contacts" in out
    err = " ".join(err.split())
    assert "warning: slab:" in err and "grid.center_offset_m=0.015" in err


def test_objects_add_small_grid_in_use_says_so(data: Path, slab: Path, capsys):
    args = ["objects", "add", "slab", str(slab), "--data", str(data)]
    assert main([*args, *_sets(small_object_overrides())]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "in use already" in err and "--set grid" not in err


def test_objects_add_no_probe(data: Path, slab: Path, capsys):
    assert main(["objects", "add", "slab", str(slab), "--data", str(data), "--no-probe"]) == 0
    out, err = capsys.readouterr()
    assert "fewer than 3" not in out + err


@pytest.mark.slow
def test_train_reports_the_share_per_object(data: Path, capsys):
    rc = main(
        [
            *["train", "--objects", "sphere,toilet_paper", "--data", str(data)],
            *["--workers", "1", "--set", "grid.step_deg=45"],
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "< 3 contacts" in out
    import re

    for name in ("sphere", "toilet_paper"):
        row = next(line for line in out.splitlines() if name in line and "% of" in line)
        cells = [c.strip() for c in row.strip("│ ").split("│")]
        share, grasps = re.fullmatch(r"(\d+)% of (\d+)", cells[-1]).groups()
        assert int(grasps) == int(cells[1])  # every new grasp counted
        # Warned exactly when over 15 % (the shared grid holds the other object's poses too).
        assert (f"warning: {name}:" in " ".join(out.split())) == (int(share) > 15)
