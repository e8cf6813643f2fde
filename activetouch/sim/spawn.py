"""The object library's objects as PyBullet bodies: one fixed multibody per object, standing on
the table, its collision shape the decomposition's convex parts."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from activetouch.errors import DataError
from activetouch.objects.library import ObjectSpec
from activetouch.sim.pybullet import pb as p


def spawn_object(
    client_id: int,
    spec: ObjectSpec,
    *,
    visual: bool = True,
    position: tuple[float, float, float] | None = None,
) -> int:
    """Create the object as a fixed body standing on the table: its centre at
    (0, 0, extents[2] / 2) unless `position` is given. Returns the body id."""
    compound = spec.compound_mesh
    tmp: str | None = None
    if compound is None:
        # PyBullet's shape arrays stop at 16 children; one OBJ with a group per part does not.
        fd, tmp = tempfile.mkstemp(suffix=".obj")
        os.close(fd)
        Path(tmp).write_text("".join(_regroup(spec.collision_meshes)))
        compound = Path(tmp)
    try:
        col = p.createCollisionShape(p.GEOM_MESH, fileName=str(compound), physicsClientId=client_id)
    finally:
        if tmp:
            os.unlink(tmp)
    if col < 0:
        raise DataError(f"{compound}: PyBullet could not load the collision mesh")
    vis = -1
    if visual:
        vis = p.createVisualShape(
            p.GEOM_MESH,
            fileName=str(spec.visual_mesh),
            rgbaColor=list(spec.rgba),
            physicsClientId=client_id,
        )
    pos = (0.0, 0.0, spec.height / 2.0) if position is None else tuple(position)
    return p.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=col,
        baseVisualShapeIndex=vis,
        basePosition=pos,
        physicsClientId=client_id,
    )


def _regroup(files: list[Path]) -> Iterator[str]:
    base = 0
    for i, fpath in enumerate(files):
        yield f"o part_{i:03d}\n"
        n = 0
        for line in Path(fpath).read_text().splitlines():
            if line.startswith("v "):
                n += 1
                yield line + "\n"
            elif line.startswith("f "):
                idx = [int(t.split("/")[0]) + base for t in line.split()[1:]]
                yield "f " + " ".join(map(str, idx)) + "\n"
        base += n
