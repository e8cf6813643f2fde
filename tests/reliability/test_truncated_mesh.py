"""Finding 9: a truncated mesh is refused with one line, not half imported."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from activetouch.errors import DataError
from activetouch.objects.library import load_mesh

CUBE_OBJ = "".join(
    f"v {x} {y} {z}\n" for x in (0, 0.1) for y in (0, 0.1) for z in (0, 0.1)
) + "".join(
    f"f {a} {b} {c}\n"
    for a, b, c in [(1, 2, 4), (1, 4, 3), (5, 7, 8), (5, 8, 6), (1, 5, 6), (1, 6, 2),
                    (3, 4, 8), (3, 8, 7), (1, 3, 7), (1, 7, 5), (2, 6, 8), (2, 8, 4)]
)  # fmt: skip


def _binary_stl(n_announced: int, n_present: int) -> bytes:
    tri = struct.pack("<12fH", *([0.0] * 3), 0, 0, 0, 0.1, 0, 0, 0, 0.1, 0, 0)
    return b"\0" * 80 + struct.pack("<I", n_announced) + tri * n_present


def test_a_whole_cube_loads(tmp_path: Path) -> None:
    p = tmp_path / "cube.obj"
    p.write_text(CUBE_OBJ)
    assert len(load_mesh(p).faces) == 12


def _ascii_stl(n_facets: int, end: bool) -> bytes:
    """The cube's first `n_facets` triangles as ASCII STL, with or without 'endsolid'."""
    v = [tuple(map(float, line.split()[1:])) for line in CUBE_OBJ.splitlines() if line[0] == "v"]
    faces = [tuple(int(i) - 1 for i in line.split()[1:]) for line in CUBE_OBJ.splitlines()
             if line[0] == "f"]  # fmt: skip
    out = ["solid cube"]
    for f in faces[:n_facets]:
        out += ["facet normal 0 0 0", " outer loop"]
        out += [f"  vertex {v[i][0]} {v[i][1]} {v[i][2]}" for i in f]
        out += [" endloop", "endfacet"]
    if end:
        out.append("endsolid cube")
    return ("\n".join(out) + "\n").encode()


@pytest.mark.parametrize(
    ("name", "content", "why"),
    [
        # Read as a smaller mesh by the reader, before this check: now refused.
        ("cut_line.obj", CUBE_OBJ[: len(CUBE_OBJ) - 4], "last line is incomplete"),
        # Checked before any reader sees them (trimesh read the binary one as text and failed
        # on a missing text-encoding module: a one-line DataError, but not the reason).
        ("cut_ascii.stl", _ascii_stl(9, end=False), "ASCII STL without 'endsolid'"),
        ("cut.stl", _binary_stl(12, 7), "12 triangles announced, 7 present"),
    ],
)
def test_a_truncated_mesh_is_refused(tmp_path: Path, name: str, content, why: str) -> None:
    p = tmp_path / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(DataError, match=why):
        load_mesh(p)


def test_a_whole_ascii_stl_loads(tmp_path: Path) -> None:
    p = tmp_path / "cube.stl"
    p.write_bytes(_ascii_stl(12, end=True))
    assert len(load_mesh(p).faces) == 12
