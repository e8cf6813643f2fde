"""Object library: builtins, determinism, imports, errors, spawning, rendering."""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import manifold3d
import numpy as np
import pybullet as pb
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from activetouch.errors import ActiveTouchError, DataError
from activetouch.objects import library as obj
from activetouch.objects import paper
from activetouch.objects.library import (
    BUILTIN_OBJECTS,
    PAPER_REAL_OBJECTS,
    PAPER_SIM_OBJECTS,
    ObjectLibrary,
    read_obj_groups,
)
from activetouch.sim.render import contacts_in_object_frame, read_obj, render_object_png
from activetouch.sim.spawn import spawn_object

HOLLOW = ("cup", "mug", "bowl", "toilet_paper", "mug_real", "bowl_real", "glass_real")


@pytest.fixture(scope="session")
def library(tmp_path_factory: pytest.TempPathFactory) -> ObjectLibrary:
    lib = ObjectLibrary(tmp_path_factory.mktemp("data") / "objects")
    lib.ensure_builtins()
    return lib


@pytest.fixture
def client():
    cid = pb.connect(pb.DIRECT)
    yield cid
    pb.disconnect(physicsClientId=cid)


def _tree(root: Path) -> dict[str, str]:
    """Every file under root with its content hash: to check nothing changed."""
    if not root.exists():
        return {}
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _manifold(path: Path) -> manifold3d.Manifold:
    v, f = read_obj(path)
    return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=v, tri_verts=f.astype(np.uint32)))


def _inside_parts(spec: obj.ObjectSpec, pts: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """Which points lie inside (or within tol of) at least one convex collision part."""
    from scipy.spatial import ConvexHull

    inside = np.zeros(len(pts), dtype=bool)
    for f in spec.collision_meshes:
        v, _ = read_obj(f)
        eq = ConvexHull(v).equations
        inside |= np.max(pts @ eq[:, :3].T + eq[:, 3], axis=1) <= tol
    return inside


def _box_obj(path: Path, size=(0.05, 0.06, 0.07), offset=(0.3, -0.2, 1.0)) -> Path:
    m = trimesh.creation.box(size)
    m.apply_translation(offset)  # not centred: the import must recentre
    m.export(path)
    return path


# --- builtins -----------------------------------------------------------------------------


def test_builtin_sets() -> None:
    assert len(PAPER_SIM_OBJECTS) == 7 and len(PAPER_REAL_OBJECTS) == 5
    assert set(BUILTIN_OBJECTS) == set(paper.BUILDERS) == set(paper.COLOURS)


def test_builtins_watertight_plausible_sizes(library: ObjectLibrary) -> None:
    assert library.names() == list(BUILTIN_OBJECTS)
    for name in BUILTIN_OBJECTS:
        spec = library.get(name)
        assert spec.source == "builtin"
        assert spec.set == ("sim" if name in PAPER_SIM_OBJECTS else "real")
        mesh = trimesh.load(spec.visual_mesh, process=True)
        assert mesh.is_watertight, name
        assert mesh.volume > 1e-5, name
        # Object frame: bounding-box centre at the origin; extents as stored.
        np.testing.assert_allclose(mesh.bounds.mean(axis=0), 0.0, atol=1e-5)
        np.testing.assert_allclose(mesh.extents, spec.extents, atol=2e-6)
        assert spec.extents.min() >= 0.05 and spec.extents.max() <= 0.25, (name, spec.extents)
        assert len(spec.collision_meshes) >= 1
        assert spec.compound_mesh is not None
        assert len(read_obj_groups(spec.compound_mesh)) == len(spec.collision_meshes)


def test_cup_and_mug_differ(library: ObjectLibrary) -> None:
    cup, mug = library.get("cup"), library.get("mug")
    assert cup.extents[2] < mug.extents[2]
    v_cup = trimesh.load(cup.visual_mesh).volume
    v_mug = trimesh.load(mug.visual_mesh).volume
    assert v_cup < v_mug

    # The cup tapers (wider at the rim); the mug is a straight cylinder.
    def radius_at(spec: obj.ObjectSpec, frac: float) -> float:
        section = _manifold(spec.visual_mesh).slice(-spec.height / 2 + frac * spec.height)
        lo, hi = np.asarray(section.bounds()).reshape(2, 2)
        return float(hi[1] - lo[1]) / 2  # across y: the handle is in the xz plane

    assert radius_at(cup, 0.9) - radius_at(cup, 0.2) > 0.006
    assert abs(radius_at(mug, 0.9) - radius_at(mug, 0.3)) < 0.001
    assert radius_at(mug, 0.5) > radius_at(cup, 0.5) + 0.005


def test_handles_spout_hollows(library: ObjectLibrary) -> None:
    for name in ("cup", "mug", "mug_real", "teapot"):
        spec = library.get(name)
        # A handle makes the object wider along x than along y.
        assert spec.extents[0] > spec.extents[1] + 0.02, name
    for name in HOLLOW:
        spec = library.get(name)
        h = spec.height
        # Points on the axis in the upper half are empty: in the mesh and in the parts.
        ax, ay = spec.meta["axis_xy"]
        pts = np.array([[ax, ay, z] for z in np.linspace(0.1 * h, 0.45 * h, 5)])
        vis = _manifold(spec.visual_mesh)
        for p in pts:
            probe = manifold3d.Manifold.cube((0.002, 0.002, 0.002), True).translate(tuple(p))
            assert (vis ^ probe).volume() < 1e-12, (name, p)
        assert not _inside_parts(spec, pts, tol=0.001).any(), name
    for name in ("bottle", "jar_real", "sphere", "teapot"):
        spec = library.get(name)
        ax, ay = spec.meta["axis_xy"]
        assert _inside_parts(spec, np.array([[ax, ay, 0.0]])).all(), name


def test_parts_cover_the_surface(library: ObjectLibrary) -> None:
    for name in BUILTIN_OBJECTS:
        spec = library.get(name)
        mesh = trimesh.load(spec.visual_mesh, process=False)
        pts, _ = trimesh.sample.sample_surface(mesh, 1500, seed=0)
        covered = _inside_parts(spec, pts, tol=0.0005)
        assert covered.mean() > 0.995, (name, covered.mean())


def test_generation_is_deterministic(tmp_path: Path, library: ObjectLibrary) -> None:
    a = ObjectLibrary(tmp_path / "a")
    assert a.ensure_builtins(["teapot", "cup"]) == ["teapot", "cup"]
    for name in ("teapot", "cup"):
        ours = _tree(a.root / name)
        theirs = _tree(library.root / name)
        assert ours == theirs, name
        meta = json.loads((a.root / name / "object.json").read_text())
        assert (
            meta["sha256"]
            == hashlib.sha256((a.root / name / "visual.obj").read_bytes()).hexdigest()
        )


def test_ensure_builtins_is_lazy_and_upgrades(tmp_path: Path) -> None:
    lib = ObjectLibrary(tmp_path / "objects")
    assert lib.names() == []
    assert lib.ensure_builtins(["sphere", "jar_real"]) == ["sphere", "jar_real"]
    before = _tree(lib.root)
    assert lib.ensure_builtins(["sphere", "jar_real"]) == []
    assert _tree(lib.root) == before
    # An object from an older generator is rebuilt.
    f = lib.root / "sphere" / "object.json"
    meta = json.loads(f.read_text())
    meta["generator_version"] = obj.GENERATOR_VERSION - 1
    f.write_text(json.dumps(meta))
    assert lib.ensure_builtins(["sphere", "jar_real"]) == ["sphere"]
    assert _tree(lib.root) == before
    assert not [p for p in lib.root.iterdir() if p.name.startswith(".") and p.name != ".lock"]
    with pytest.raises(DataError, match="no builtin"):
        lib.ensure_builtins(["unicorn"])


def test_get_unknown(library: ObjectLibrary) -> None:
    with pytest.raises(DataError, match="unknown object 'unicorn'"):
        library.get("unicorn")
    with pytest.raises(DataError):
        library.get("../objects")


# --- imports ------------------------------------------------------------------------------


def test_import_obj_and_stl_then_spawn(tmp_path: Path, client: int) -> None:
    lib = ObjectLibrary(tmp_path / "objects")
    spec = lib.add("box", _box_obj(tmp_path / "box.obj"), scale=2.0)
    assert spec.source == "imported" and spec.set == "user" and spec.scale == 2.0
    np.testing.assert_allclose(spec.extents, [0.1, 0.12, 0.14], atol=1e-6)
    v, _ = read_obj(spec.visual_mesh)
    np.testing.assert_allclose((v.min(0) + v.max(0)) / 2, 0.0, atol=1e-6)
    assert spec.meta["sha256"] == hashlib.sha256((tmp_path / "box.obj").read_bytes()).hexdigest()
    assert len(spec.collision_meshes) == 1  # convex: no decomposition needed

    cyl = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=32)
    cyl.export(tmp_path / "cyl.stl")
    spec2 = lib.add("can", tmp_path / "cyl.stl")
    np.testing.assert_allclose(spec2.extents, [0.06, 0.06, 0.1], atol=1e-3)
    assert lib.names() == ["box", "can"]

    for s in (spec, spec2):
        body = spawn_object(client, s)
        lo, hi = pb.getAABB(body, physicsClientId=client)
        assert abs(lo[2]) < 0.003 and abs(hi[2] - s.height) < 0.003  # stands on the table
        hit = pb.rayTest((0, 0, 1), (0, 0, -1), physicsClientId=client)[0]
        assert hit[0] == body and abs(hit[3][2] - s.height) < 0.002
        pb.removeBody(body, physicsClientId=client)


@pytest.mark.parametrize("method", ["coacd", "vhacd"])
def test_import_concave_mesh_is_decomposed(tmp_path: Path, client: int, method: str) -> None:
    # A U shape: its convex hull would fill the slot, the decomposition must not.
    u = trimesh.boolean.difference(
        [
            trimesh.creation.box((0.08, 0.04, 0.06)),
            trimesh.creation.box(
                (0.04, 0.05, 0.05),
                transform=trimesh.transformations.translation_matrix((0, 0, 0.02)),
            ),
        ],
        engine="manifold",
    )
    u.export(tmp_path / "u.stl")
    lib = ObjectLibrary(tmp_path / "objects")
    spec = lib.add("u", tmp_path / "u.stl", decomposition=method)
    assert spec.meta["decomposition"] == method
    assert len(spec.collision_meshes) >= 2
    # The slot (centre, upper part) is free, the base and the side posts are solid.
    assert not _inside_parts(spec, np.array([[0.0, 0.0, 0.02]])).any()
    assert _inside_parts(spec, np.array([[0.0, 0.0, -0.025], [0.03, 0.0, 0.01]]), 0.002).all()
    body = spawn_object(client, spec)
    hit = pb.rayTest((0, 0, 1), (0, 0, -1), physicsClientId=client)[0]
    # Into the slot, onto the base: its top is 0.025 m above the table (not the 0.06 rim).
    assert hit[0] == body and abs(hit[3][2] - 0.025) < 0.003


def test_import_urdf(tmp_path: Path) -> None:
    (tmp_path / "meshes").mkdir()
    _box_obj(tmp_path / "meshes" / "part.obj", size=(0.1, 0.2, 0.3), offset=(0, 0, 0))
    (tmp_path / "robot.urdf").write_text(
        """<robot name="thing">
  <link name="base">
    <visual><geometry><mesh filename="meshes/part.obj"/></geometry></visual>
    <collision>
      <origin xyz="0 0 0" rpy="0 0 1.5707963267948966"/>
      <geometry><mesh filename="package://thing/meshes/part.obj" scale="0.5 0.5 0.5"/></geometry>
    </collision>
  </link>
</robot>"""
    )
    lib = ObjectLibrary(tmp_path / "objects")
    spec = lib.add("thing", tmp_path / "robot.urdf", scale=2.0)
    # URDF scale 0.5 times our 2.0, then the 90° yaw swaps x and y.
    np.testing.assert_allclose(spec.extents, [0.2, 0.1, 0.3], atol=1e-6)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (None, "not found"),
        (b"", "empty file"),
        (b"this is not a mesh\nv 1 2\nf 9 9 9\n", "vertex 9 of 1 .the file is truncated or"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n", "flat|zero volume"),
    ],
)
def test_bad_obj_leaves_library_unchanged(
    tmp_path: Path, library: ObjectLibrary, content: bytes | None, match: str
) -> None:
    lib = ObjectLibrary(tmp_path / "objects")
    lib.add("good", _box_obj(tmp_path / "good.obj"))
    before = _tree(lib.root)
    path = tmp_path / "bad.obj"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(DataError, match=match) as e:
        lib.add("bad", path)
    assert str(path) in str(e.value)
    assert _tree(lib.root) == before
    assert lib.names() == ["good"]


def test_bad_stl_and_urdf(tmp_path: Path) -> None:
    lib = ObjectLibrary(tmp_path / "objects")
    (tmp_path / "junk.stl").write_bytes(
        b"solid junk\nfacet normal oops\nendsolid\n" + bytes(range(256))
    )
    with pytest.raises(DataError):
        lib.add("junk", tmp_path / "junk.stl")
    (tmp_path / "a.urdf").write_text("<robot><link name='x'/></robot>")
    with pytest.raises(DataError, match="no collision or visual mesh"):
        lib.add("a", tmp_path / "a.urdf")
    (tmp_path / "b.urdf").write_text(
        "<robot><link name='x'><visual><geometry><mesh filename='nope.obj'/></geometry>"
        "</visual></link></robot>"
    )
    with pytest.raises(DataError, match=r"nope\.obj"):
        lib.add("b", tmp_path / "b.urdf")
    (tmp_path / "c.urdf").write_text("<robot><link")
    with pytest.raises(DataError, match="URDF"):
        lib.add("c", tmp_path / "c.urdf")
    (tmp_path / "d.ply").write_text("ply\n")
    with pytest.raises(DataError, match="unsupported"):
        lib.add("d", tmp_path / "d.ply")
    assert lib.names() == []


def test_names_builtins_and_overwrite(tmp_path: Path) -> None:
    lib = ObjectLibrary(tmp_path / "objects")
    box = _box_obj(tmp_path / "box.obj")
    for bad in ("", "-x", "a b", "../up", "x" * 65, "é"):
        with pytest.raises(ActiveTouchError, match="invalid object name"):
            lib.add(bad, box)
    with pytest.raises(ActiveTouchError, match="builtin"):
        lib.add("mug", box)
    with pytest.raises(ActiveTouchError, match="scale"):
        lib.add("box", box, scale=0.0)
    lib.add("box", box)
    with pytest.raises(ActiveTouchError, match="already exists"):
        lib.add("box", box, scale=2.0)
    spec = lib.add("box", box, scale=2.0, overwrite=True)
    np.testing.assert_allclose(spec.extents, [0.1, 0.12, 0.14], atol=1e-6)
    assert sorted(p.name for p in lib.root.iterdir() if p.is_dir()) == ["box"]


def test_open_mesh_warns_but_imports(tmp_path: Path) -> None:
    m = trimesh.creation.box((0.05, 0.05, 0.05))
    m.update_faces(np.arange(len(m.faces)) != 0)  # drop one triangle: a hole
    m.export(tmp_path / "open.obj")
    lib = ObjectLibrary(tmp_path / "objects")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spec = lib.add("open", tmp_path / "open.obj")
    assert any("not watertight" in str(w.message) for w in caught)
    assert spec.meta["watertight"] is False


# --- spawning and rendering ---------------------------------------------------------------


def test_spawn_builtins_stand_on_table_and_are_hollow(library: ObjectLibrary, client: int) -> None:
    for name in BUILTIN_OBJECTS:
        spec = library.get(name)
        body = spawn_object(client, spec, visual=(name == "cup"))
        lo, hi = pb.getAABB(body, physicsClientId=client)
        assert abs(lo[2]) < 0.003 and abs(hi[2] - spec.height) < 0.003, name
        pos, _orn = pb.getBasePositionAndOrientation(body, physicsClientId=client)
        np.testing.assert_allclose(pos, [0, 0, spec.height / 2], atol=1e-9)
        ax, ay = spec.meta["axis_xy"]
        hit = pb.rayTest((ax, ay, 1), (ax, ay, -1), physicsClientId=client)[0]
        if name in HOLLOW:  # down the axis the ray passes the rim and meets the floor
            assert hit[3][2] < 0.35 * spec.height or hit[0] != body, name
        else:
            assert hit[0] == body and hit[3][2] > 0.9 * spec.height, name
        pb.removeBody(body, physicsClientId=client)


def test_render_png(tmp_path: Path, library: ObjectLibrary) -> None:
    spec = library.get("cup")
    rng = np.random.default_rng(0)
    d = rng.normal(size=(12, 3))
    d[:, 2] = np.abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    quats = [Rotation.align_vectors([-v], [[0, 0, 1]])[0].as_quat() for v in d]
    poses = np.hstack([0.15 * d, np.array(quats)])
    # Hand +z of every pose points at the object centre.
    z_axes = Rotation.from_quat(poses[:, 3:]).apply([0, 0, 1])
    np.testing.assert_allclose(z_axes, -d, atol=1e-9)
    contacts_hand = [rng.normal(scale=0.02, size=(3, 3)) for _ in poses]
    contacts = contacts_in_object_frame(poses, contacts_hand)
    back = Rotation.from_quat(poses[0, 3:]).inv().apply(contacts[:3] - poses[0, :3])
    np.testing.assert_allclose(back, contacts_hand[0], atol=1e-12)
    out = render_object_png(spec, tmp_path / "cup.png", poses, contacts)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000
    out2 = render_object_png(spec, tmp_path / "parts.png", parts=True)
    assert out2.stat().st_size > 20_000
