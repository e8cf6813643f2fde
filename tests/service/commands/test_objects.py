"""`activetouch objects list|add|render` through the CLI entry point."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from activetouch import paths
from activetouch.cli.main import main
from activetouch.interfaces import Grasp, Pose
from activetouch.objects.library import BUILTIN_OBJECTS, ObjectLibrary


@pytest.fixture(scope="module")
def first_list(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """`objects list --json` on an empty data directory (it generates the builtins)."""
    root = tmp_path_factory.mktemp("fresh")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["objects", "list", "--json", "--data", str(root)]) == 0
    return root / "objects", out.getvalue()


@pytest.fixture
def data(tmp_path: Path, first_list: tuple[Path, str]) -> Path:
    """A data directory whose library already holds the generated builtins."""
    root = tmp_path / "data"
    shutil.copytree(first_list[0], root / "objects")
    return root


def _list(data: Path, capsys: pytest.CaptureFixture[str]) -> list[dict]:
    assert main(["objects", "list", "--json", "--data", str(data)]) == 0
    return json.loads(capsys.readouterr().out)


def test_list_generates_builtins_on_first_use(first_list: tuple[Path, str]) -> None:
    rows = json.loads(first_list[1])
    from activetouch.objects.hard import HARD_OBJECTS

    assert [r["name"] for r in rows] == list(BUILTIN_OBJECTS + HARD_OBJECTS)
    assert ObjectLibrary(first_list[0]).names() == list(BUILTIN_OBJECTS + HARD_OBJECTS)
    hard = [r for r in rows if r["set"] == "hard"]
    assert len(hard) >= 30 and len({r["family"] for r in hard}) >= 6
    for r in hard:  # 5-25 cm, and every family has look-alikes
        assert min(r["extents"]) >= 0.05 and max(r["extents"]) <= 0.25, r
    assert all(sum(x["family"] == r["family"] for x in hard) >= 2 for r in hard)
    cup = rows[0]
    assert cup["set"] == "sim" and cup["source"] == "builtin" and cup["parts"] > 1
    assert len(cup["extents"]) == 3 and min(cup["extents"]) > 0.05
    assert Path(cup["visual_mesh"]).is_file()


def test_list_table(data: Path, capsys) -> None:
    assert main(["objects", "list", "--data", str(data)]) == 0
    out = capsys.readouterr().out
    for name in ("teapot", "toilet_paper", "glass_real"):
        assert name in out


def test_add_then_list(data: Path, tmp_path: Path, capsys) -> None:
    trimesh.creation.box((100.0, 60.0, 40.0)).export(tmp_path / "brick.stl")  # millimetres
    rc = main(
        [
            "objects",
            "add",
            "brick",
            str(tmp_path / "brick.stl"),
            "--scale",
            "0.001",
            "--data",
            str(data),
        ]
    )
    assert rc == 0
    assert "added brick" in capsys.readouterr().out
    rows = {r["name"]: r for r in _list(data, capsys)}
    assert rows["brick"]["source"] == "imported" and rows["brick"]["set"] == "user"
    np.testing.assert_allclose(rows["brick"]["extents"], [0.1, 0.06, 0.04], atol=1e-6)
    assert rows["brick"]["scale"] == 0.001


def test_add_mistakes_are_one_line_errors(data: Path, tmp_path: Path, capsys) -> None:
    before = sorted(p.name for p in (data / "objects").iterdir())
    cases = [
        (["brick", str(tmp_path / "missing.obj")], "not found"),
        (["mug", str(tmp_path / "missing.obj")], "builtin"),
        (["bad name", str(tmp_path / "missing.obj")], "invalid object name"),
    ]
    (tmp_path / "empty.obj").write_bytes(b"")
    cases.append((["brick", str(tmp_path / "empty.obj")], "empty file"))
    for args, message in cases:
        assert main(["objects", "add", *args, "--data", str(data)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error:") and message in " ".join(err.split()), err
        assert "Traceback" not in err
    assert sorted(p.name for p in (data / "objects").iterdir()) == before


def test_render_mesh_and_dataset(data: Path, tmp_path: Path, capsys) -> None:
    from activetouch.recognition.dataset import Dataset, GraspRecord

    # Two grasps of the cup: hand frames looking at the centre, contacts in the hand frame.
    ds = Dataset.create_or_open(paths.default_dataset(data))
    recs = []
    for i, quat in enumerate([[1.0, 0.0, 0.0, 0.0], [0.0, 0.7071068, 0.0, 0.7071068]]):
        pose = Pose(np.array([0.0, 0.0, 0.15]) if i == 0 else np.array([-0.15, 0.0, 0.0]), quat)
        xyz = np.array([[0.01, 0.0, 0.1], [-0.01, 0.02, 0.11], [0.0, -0.02, 0.1]])
        grasp = Grasp(np.array([0, 9, 18]), xyz, np.ones(3), np.zeros(3))
        recs.append(GraspRecord(i, pose, 0.0, grasp))
    ds.append("cup", recs)

    out = tmp_path / "png"
    assert main(["objects", "render", "cup", "sphere", "--out", str(out), "--data", str(data)]) == 0
    text = capsys.readouterr().out
    assert "2 poses, 6 contacts" in text and "mesh only" in text
    for name in ("cup", "sphere"):
        assert (out / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["objects", "render", "jar_real", "--parts", "--data", str(data)]) == 0
    assert (data / "renders" / "jar_real_parts.png").is_file()
    assert main(["objects", "render", "unicorn", "--data", str(data)]) == 2
    assert "unknown object 'unicorn'" in capsys.readouterr().err
