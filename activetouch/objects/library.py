"""The object library: procedurally generated household objects and meshes a user imports.

Layout of a library directory (``<data>/objects``)::

    <name>/visual.obj          the watertight (or imported) surface, in the object frame
    <name>/collision_NNN.obj   convex parts whose union covers the object
    <name>/compound.obj        the same parts as one OBJ with one ``o`` group each
                               (PyBullet makes one convex hull per group: a compound shape)
    <name>/object.json         name, source, set, scale, extents, sha256, ...

The object frame has its origin at the bounding-box centre, axes parallel to the world; the
object stands upright on the table (z = 0) at (0, 0, extents[2] / 2).

Builtins are the 7 simulated objects and the 5 real ones of Zhang et al. (IROS 2017)
(`library/paper.py`); generated sets such as the hard library are in `library/` too, all
built from `library/shapes.py`, whose convex parts are exact. Imported meshes are decomposed
with CoACD (or PyBullet's V-HACD).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import shutil
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from activetouch import paths
from activetouch.errors import ActiveTouchError, DataError
from activetouch.objects import hard
from activetouch.objects.hard import HARD_OBJECTS
from activetouch.objects.paper import BUILDERS, COLOURS
from activetouch.objects.shapes import Shape, mesh_manifold
from activetouch.storage import locked, replace_dir

PAPER_SIM_OBJECTS: tuple[str, ...] = (
    "cup",
    "teapot",
    "bowl",
    "bottle",
    "mug",
    "toilet_paper",
    "sphere",
)
PAPER_REAL_OBJECTS: tuple[str, ...] = (
    "mug_real",
    "bottle_real",
    "jar_real",
    "bowl_real",
    "glass_real",
)
BUILTIN_OBJECTS: tuple[str, ...] = PAPER_SIM_OBJECTS + PAPER_REAL_OBJECTS
GENERATED_SETS: tuple[str, ...] = ("hard",)  # generated on request (sim/library/)


def generated_set(name: str) -> tuple[str, ...]:
    """The object names of a generated set (`GENERATED_SETS`)."""
    if name != "hard":
        raise DataError(f"no generated set {name!r}; sets: {', '.join(GENERATED_SETS)}")

    return HARD_OBJECTS


def _generated_objects() -> tuple[str, ...]:
    return tuple(n for s in GENERATED_SETS for n in generated_set(s))


# Bump when a builtin's geometry changes: libraries regenerate builtins of an older version.
GENERATOR_VERSION = 1
FORMAT_VERSION = 1
MESH_SUFFIXES = (".obj", ".stl", ".urdf")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")

# Imports: sizes outside this range are probably in the wrong unit (mm, inches).
PLAUSIBLE_SIZE_M = (0.01, 1.0)


@dataclass
class ObjectSpec:
    """One object of the library; all meshes are in the object frame, in metres."""

    name: str
    source: str  # "builtin" | "imported"
    visual_mesh: Path
    collision_meshes: list[Path]
    scale: float
    extents: np.ndarray  # (3,) bounding-box size
    set: str  # "sim" | "real" (the paper's sets) | "user"
    rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)
    compound_mesh: Path | None = None  # all parts in one OBJ (what spawn_object loads)
    meta: dict = field(default_factory=dict)  # the rest of object.json

    @property
    def directory(self) -> Path:
        return self.visual_mesh.parent

    @property
    def height(self) -> float:
        return float(self.extents[2])

    @property
    def support_z(self) -> float:
        """The table plane in the object frame: the object stands on it, centred."""
        return -self.height / 2


# --------------------------------------------------------------------------------------------
# Mesh I/O (our own OBJ writer: fixed formatting, so generation is byte-for-byte repeatable)
# --------------------------------------------------------------------------------------------


def convex_hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward-oriented triangles of the convex hull of `points`."""
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial import ConvexHull

    hull = ConvexHull(np.asarray(points, dtype=np.float64))
    faces = hull.simplices.copy()
    v = hull.points
    n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    flip = np.einsum("ij,ij->i", n, hull.equations[:, :3]) < 0
    faces[flip] = faces[flip][:, ::-1]
    used = np.unique(faces)
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[faces]


def _obj_text(groups: list[tuple[str, np.ndarray, np.ndarray]]) -> str:
    lines = ["# activetouch object mesh (metres, object frame)"]
    base = 1
    for name, verts, faces in groups:
        if name:
            lines.append(f"o {name}")
        lines.extend(f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(verts))
        lines.extend(f"f {a} {b} {c}" for a, b, c in (np.asarray(faces, dtype=np.int64) + base))
        base += len(verts)
    return "\n".join(lines) + "\n"


def write_obj(path: Path, verts: np.ndarray, faces: np.ndarray) -> None:
    path.write_text(_obj_text([("", verts, faces)]))


def read_obj_groups(path: Path) -> list[np.ndarray]:
    """Vertex arrays of each ``o``/``g`` group of an OBJ (what a decomposer writes)."""
    groups: list[list[list[float]]] = []
    cur: list[list[float]] | None = None
    with open(path) as f:
        for line in f:
            if line.startswith(("o ", "g ")):
                cur = []
                groups.append(cur)
            elif line.startswith("v "):
                if cur is None:
                    cur = []
                    groups.append(cur)
                cur.append([float(x) for x in line.split()[1:4]])
    return [np.asarray(g, dtype=np.float64) for g in groups if len(g) >= 4]


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# Writing an object directory
# --------------------------------------------------------------------------------------------


@dataclass
class _Built:
    verts: np.ndarray
    faces: np.ndarray
    parts: list[tuple[np.ndarray, np.ndarray]]  # convex (verts, faces)
    axis_xy: np.ndarray | None = None  # where a builtin's lathe axis is in the object frame


def shape_to_meshes(shape: Shape) -> _Built:
    """Visual mesh and convex parts of a generated shape, moved into the object frame."""
    mesh = shape.solid.simplify(1e-6).to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = (lo + hi) / 2.0
    parts = [convex_hull_mesh(h - centre) for h in shape.hulls]
    return _Built(verts - centre, faces, parts, axis_xy=-centre[:2])


def _write_object_dir(d: Path, built: _Built, meta: dict) -> None:
    write_obj(d / "visual.obj", built.verts, built.faces)
    for i, (v, f) in enumerate(built.parts):
        write_obj(d / f"collision_{i:03d}.obj", v, f)
    (d / "compound.obj").write_text(
        _obj_text([(f"part_{i:03d}", v, f) for i, (v, f) in enumerate(built.parts)])
    )
    ext = built.verts.max(axis=0) - built.verts.min(axis=0)
    meta = {
        "format": FORMAT_VERSION,
        **meta,
        "extents": [round(float(e), 6) for e in ext],
        "n_parts": len(built.parts),
        "n_triangles": len(built.faces),
    }
    (d / "object.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")


# --------------------------------------------------------------------------------------------
# Importing a user's mesh
# --------------------------------------------------------------------------------------------


def _urdf_mesh(path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """(mesh file, per-axis scale, 4x4 origin) of the first link's collision (else visual) mesh."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as e:
        raise DataError(f"{path}: not a readable URDF ({e})") from e
    if root.tag != "robot":
        raise DataError(f"{path}: not a URDF (root element <{root.tag}>, expected <robot>)")
    for link in root.findall("link"):
        for kind in ("collision", "visual"):
            for el in link.findall(kind):
                mesh = el.find("geometry/mesh")
                if mesh is None or not mesh.get("filename"):
                    continue
                scale = np.ones(3)
                if mesh.get("scale"):
                    try:
                        scale = np.array([float(s) for s in mesh.get("scale", "").split()])
                    except ValueError as e:
                        raise DataError(f"{path}: bad mesh scale {mesh.get('scale')!r}") from e
                    if scale.size == 1:
                        scale = np.repeat(scale, 3)
                    if scale.size != 3:
                        raise DataError(f"{path}: bad mesh scale {mesh.get('scale')!r}")
                origin = np.eye(4)
                o = el.find("origin")
                if o is not None:
                    origin = _urdf_origin(path, o)
                return _resolve_urdf_file(path, mesh.get("filename", "")), scale, origin
        raise DataError(f"{path}: link {link.get('name')!r} has no collision or visual mesh")
    raise DataError(f"{path}: URDF has no <link>")


def _urdf_origin(path: Path, o: ET.Element) -> np.ndarray:
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial.transform import Rotation

    try:
        xyz = [float(v) for v in o.get("xyz", "0 0 0").split()]
        rpy = [float(v) for v in o.get("rpy", "0 0 0").split()]
        if len(xyz) != 3 or len(rpy) != 3:
            raise ValueError("need 3 numbers")
    except ValueError as e:
        raise DataError(f"{path}: bad <origin> ({e})") from e
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF rpy: fixed axes x, y, z
    T[:3, 3] = xyz
    return T


def _resolve_urdf_file(urdf: Path, filename: str) -> Path:
    tried = []
    if filename.startswith("file://"):
        tried.append(Path(filename[len("file://") :]))
    elif filename.startswith("package://"):
        rest = filename[len("package://") :]
        _pkg, _, inner = rest.partition("/")
        # Without ROS we cannot look packages up: try the URDF's folder and its parents.
        for base in [urdf.parent, *list(urdf.parent.parents)[:3]]:
            tried += [base / rest, base / inner]
    else:
        p = Path(filename)
        tried.append(p if p.is_absolute() else urdf.parent / p)
    for p in tried:
        if p.is_file():
            return p
    raise DataError(
        f"{urdf}: mesh file {filename!r} not found (looked at {', '.join(map(str, tried))})"
    )


def load_mesh(path: Path, scale: float = 1.0):
    """Read an OBJ/STL/URDF as one trimesh.Trimesh in metres; errors -> DataError."""
    # deferred: trimesh takes 0.8 s to import
    import trimesh

    path = Path(path)
    if not path.exists():
        raise DataError(f"mesh file not found: {path}")
    if not path.is_file():
        raise DataError(f"not a file: {path}")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise DataError(f"{path}: unsupported mesh format {suffix!r} (use .obj, .stl or .urdf)")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: empty file")
    if not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
        raise ActiveTouchError(f"scale must be a positive number, got {scale!r}")
    axis_scale, T = np.ones(3), np.eye(4)
    mesh_path = path
    if suffix == ".urdf":
        mesh_path, axis_scale, T = _urdf_mesh(path)
        if mesh_path.suffix.lower() not in (".obj", ".stl"):
            raise DataError(f"{path}: mesh {mesh_path.name} is not OBJ or STL")
        if mesh_path.stat().st_size == 0:
            raise DataError(f"{mesh_path}: empty file")
    # Before reading: a reader may choke on a cut file with an unrelated message, or keep
    # what it could parse of it and look whole.
    _check_not_truncated(mesh_path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = trimesh.load(str(mesh_path), force="mesh", process=True)
    except Exception as e:  # trimesh raises many types for malformed files
        raise DataError(f"{mesh_path}: cannot read mesh ({type(e).__name__}: {e})") from e
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or len(mesh.vertices) < 4:
        raise DataError(f"{mesh_path}: no triangles found (malformed or empty mesh)")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise DataError(f"{mesh_path}: vertices are not finite numbers")
    v = v * axis_scale
    v = v @ T[:3, :3].T + T[:3, 3]
    mesh = trimesh.Trimesh(v * float(scale), np.asarray(mesh.faces), process=True)
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise DataError(f"{mesh_path}: all triangles are degenerate")
    return mesh


def _check_not_truncated(path: Path) -> None:
    """DataError if the file was cut short (a copy that stopped, a download that broke): mesh
    readers keep what they could parse and say nothing, which would import half an object."""
    data = path.read_bytes()
    suffix = path.suffix.lower()
    cut = f"{path}: the file is truncated"
    if suffix == ".stl":
        if data[:5].lower() == b"solid" and b"facet" in data[:1000]:
            if b"endsolid" not in data[-1000:].lower():
                raise DataError(f"{cut} (ASCII STL without 'endsolid')")
        elif len(data) >= 84:
            n = int.from_bytes(data[80:84], "little")
            if len(data) < 84 + 50 * n:
                have = (len(data) - 84) // 50
                raise DataError(f"{cut} ({n} triangles announced, {have} present)")
        else:
            raise DataError(f"{cut} (shorter than a binary STL header)")
    elif suffix == ".obj":
        n_vertices, max_index = 0, 0
        for line in data.decode("utf-8", errors="replace").splitlines():
            if line.startswith("v "):
                n_vertices += 1
            elif line.startswith("f "):
                for token in line.split()[1:]:
                    head = token.split("/")[0]
                    if head.lstrip("-").isdigit():
                        max_index = max(max_index, int(head))
        if max_index > n_vertices:
            raise DataError(
                f"{path}: a face uses vertex {max_index} of {n_vertices} (the file is truncated "
                "or malformed)"
            )
        last = data.rstrip(b"\r\n").rsplit(b"\n", 1)[-1].split()
        if last[:1] in ([b"v"], [b"f"]) and len(last) < 4:
            raise DataError(f"{cut} (its last line is incomplete: {b' '.join(last).decode()!r})")


def decompose(verts: np.ndarray, faces: np.ndarray, method: str = "coacd") -> list[np.ndarray]:
    """Convex parts (as point sets) of a concave mesh, with CoACD or PyBullet's V-HACD."""
    if method == "coacd":
        return _decompose_coacd(verts, faces)
    if method == "vhacd":
        return _decompose_vhacd(verts, faces)
    raise ActiveTouchError(f"unknown decomposition {method!r} (use coacd or vhacd)")


def _decompose_coacd(verts: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    try:
        # deferred: CoACD only for this decomposition
        import coacd
    except ImportError as e:
        raise ActiveTouchError(
            "coacd is not installed (pip install coacd), or use the vhacd decomposition"
        ) from e

    coacd.set_log_level("error")
    # Tuned for speed (a few seconds for a mug-like mesh); ~1 mm surface error at 0.1 m.
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(verts, dtype=np.float64), np.asarray(faces, dtype=np.int64)),
        threshold=0.05,
        preprocess_mode="auto",
        preprocess_resolution=40,
        resolution=1000,
        mcts_nodes=10,
        mcts_iterations=60,
        mcts_max_depth=2,
        max_convex_hull=-1,
        seed=0,
    )
    return [np.asarray(v, dtype=np.float64) for v, _f in parts if len(v) >= 4]


@contextlib.contextmanager
def _quiet_fds() -> Iterator[None]:
    """Silence C-level stdout/stderr (V-HACD prints its progress there)."""
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)


def _decompose_vhacd(verts: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    # deferred: PyBullet only for its V-HACD here
    import pybullet as p

    with tempfile.TemporaryDirectory() as td:
        src, dst, log = Path(td) / "in.obj", Path(td) / "out.obj", Path(td) / "log.txt"
        write_obj(src, verts, faces)
        with _quiet_fds():
            cid = p.connect(p.DIRECT)  # a fresh client, so no simulation state is touched
            try:
                p.vhacd(
                    str(src),
                    str(dst),
                    str(log),
                    resolution=200000,
                    concavity=0.001,
                    physicsClientId=cid,
                )
            finally:
                p.disconnect(cid)
        if not dst.exists():
            raise DataError("V-HACD produced no output")
        return read_obj_groups(dst)


# --------------------------------------------------------------------------------------------
# The library
# --------------------------------------------------------------------------------------------


class ObjectLibrary:
    """Objects stored under `root` (normally ``paths.objects_dir(paths.data_dir())``)."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)

    @classmethod
    def in_data_dir(cls, data: Path | str | None = None) -> ObjectLibrary:

        return cls(paths.objects_dir(paths.data_dir(data)))

    # -- queries -----------------------------------------------------------------------------

    def names(self) -> list[str]:
        """Objects present: builtins in the paper's order, then imported ones by name."""
        if not self.root.is_dir():
            return []
        have = {
            p.name
            for p in self.root.iterdir()
            if p.is_dir() and not p.name.startswith(".") and (p / "object.json").is_file()
        }
        ordered = BUILTIN_OBJECTS + _generated_objects()
        return [n for n in ordered if n in have] + sorted(have - set(ordered))

    def __contains__(self, name: str) -> bool:
        return (self.root / name / "object.json").is_file()

    def get(self, name: str) -> ObjectSpec:
        d = self.root / name
        if not NAME_RE.match(name) or not (d / "object.json").is_file():
            known = ", ".join(self.names()) or "none"
            hint = (
                " (run ensure_builtins / `activetouch objects list`)"
                if name in BUILTIN_OBJECTS
                else ""
            )
            raise DataError(f"unknown object {name!r} in {self.root}{hint}; known: {known}")
        return _read_spec(d)

    def specs(self) -> list[ObjectSpec]:
        return [self.get(n) for n in self.names()]

    # -- builtins ----------------------------------------------------------------------------

    def ensure_builtins(self, names: list[str] | tuple[str, ...] | None = None) -> list[str]:
        """Generate the builtins that are missing or from an older generator; returns the
        names (re)generated. Safe to call from several processes at once."""
        wanted = list(BUILTIN_OBJECTS if names is None else names)
        for n in wanted:
            if n not in BUILDERS and n not in _generated_objects():
                raise DataError(f"no builtin object {n!r}; builtins: {', '.join(BUILTIN_OBJECTS)}")
        todo = [n for n in wanted if not self._builtin_current(n)]
        if not todo:
            return []
        made = []
        with self._lock():
            for n in todo:
                if self._builtin_current(n):  # another process made it meanwhile
                    continue
                self._install(n, lambda d, n=n: _build_builtin(n, d))
                made.append(n)
        return made

    def ensure_set(self, name: str) -> list[str]:
        """Generate a generated set (e.g. "hard") like the builtins; returns the names made."""
        return self.ensure_builtins(generated_set(name))

    def _builtin_current(self, name: str) -> bool:
        f = self.root / name / "object.json"
        if not f.is_file():
            return False
        try:
            meta = json.loads(f.read_text())
        except (OSError, ValueError):
            return False
        return (
            meta.get("source") == "builtin" and meta.get("generator_version") == GENERATOR_VERSION
        )

    # -- imports -----------------------------------------------------------------------------

    def add(
        self,
        name: str,
        path: Path | str,
        scale: float = 1.0,
        *,
        overwrite: bool = False,
        decomposition: str = "coacd",
    ) -> ObjectSpec:
        """Import a mesh (OBJ, STL or URDF) scaled by `scale` into the library as `name`.

        The object frame is put at its bounding-box centre. Concave meshes are split into
        convex parts. On any error the library is left as it was.
        """
        if not isinstance(name, str) or not NAME_RE.match(name):
            raise ActiveTouchError(
                f"invalid object name {name!r}: use 1-64 letters, digits, '_' or '-', "
                "starting with a letter or digit"
            )
        if name in BUILTIN_OBJECTS or name in _generated_objects():
            raise ActiveTouchError(f"{name!r} is a builtin object and cannot be replaced")
        if name in self and not overwrite:
            raise ActiveTouchError(
                f"object {name!r} already exists in {self.root} (replace it with --force)"
            )
        if decomposition not in ("coacd", "vhacd"):
            raise ActiveTouchError(f"unknown decomposition {decomposition!r} (use coacd or vhacd)")
        src = Path(path)
        mesh = load_mesh(src, scale)
        built, info = _import_meshes(mesh, src, decomposition)
        meta = {
            "name": name,
            "source": "imported",
            "set": "user",
            "scale": float(scale),
            "source_file": str(src.resolve()),
            "sha256": _sha256(src),
            "rgba": [0.7, 0.7, 0.75, 1.0],
            **info,
        }
        with self._lock():
            self._install(name, lambda d: _write_object_dir(d, built, meta))
        return self.get(name)

    def remove(self, name: str) -> None:
        if name in BUILTIN_OBJECTS or name in _generated_objects():
            raise ActiveTouchError(f"{name!r} is a builtin object and cannot be removed")
        if name not in self:
            raise DataError(f"unknown object {name!r} in {self.root}")
        with self._lock():
            shutil.rmtree(self.root / name)

    # -- plumbing ----------------------------------------------------------------------------

    @contextlib.contextmanager
    def _lock(self) -> Iterator[None]:
        self.root.mkdir(parents=True, exist_ok=True)
        with locked(self.root / ".lock"):
            yield

    def _install(self, name: str, fill: Callable[[Path], None]) -> None:
        """Build an object directory in a temporary place, then swap it in by renames."""
        replace_dir(self.root / name, fill)


def _build_builtin(name: str, d: Path) -> None:
    if name in BUILDERS:
        shape, set_name, rgba = BUILDERS[name](), None, COLOURS[name]
    else:
        shape, set_name, rgba = hard.HARD_BUILDERS[name][1](), hard.HARD_SET, hard.colour(name)
    built = shape_to_meshes(shape)
    write_obj(d / "visual.obj", built.verts, built.faces)
    meta = {
        "name": name,
        "source": "builtin",
        "set": set_name or ("sim" if name in PAPER_SIM_OBJECTS else "real"),
        "scale": 1.0,
        "generator_version": GENERATOR_VERSION,
        "decomposition": "lathe",
        "rgba": list(rgba),
        **({"family": hard.family(name)} if set_name else {}),
        # A builtin's source is its generated surface: the hash pins the geometry.
        "sha256": _sha256(d / "visual.obj"),
        # The body's axis of revolution (off the bbox centre when there is a handle/spout).
        "axis_xy": [round(float(a), 6) for a in built.axis_xy],
    }
    _write_object_dir(d, built, meta)


def fill_holes(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Close each boundary loop of a consistently wound mesh with a fan around its centroid.

    Returns (verts, faces, number of holes closed); the input unchanged if the open edges do
    not form loops (then the caller sees the mesh is still open)."""
    f = np.asarray(faces, dtype=np.int64)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    have = {(int(a), int(b)) for a, b in directed}
    boundary = [(a, b) for a, b in map(tuple, directed.tolist()) if (b, a) not in have]
    nxt: dict[int, list[int]] = {}
    for a, b in sorted(boundary):
        nxt.setdefault(a, []).append(b)
    v = [np.asarray(verts, dtype=np.float64)]
    new_faces = [f]
    n_v = len(verts)
    holes = 0
    # Open edges of a consistently wound surface form cycles (in = out at every vertex, also
    # where two holes touch), so walking from any open edge comes back to its start.
    while nxt:
        start = min(nxt)
        loop = [start]
        while True:
            outs = nxt.get(loop[-1])
            if not outs:
                return verts, faces, 0
            b = outs.pop(0)
            if not outs:
                del nxt[loop[-1]]
            if b == start:
                break
            loop.append(b)
        ring = np.asarray(loop)
        v.append(v[0][ring].mean(axis=0, keepdims=True))
        # Each open edge a->b belongs to a face; the patch face runs b->a to match it.
        new_faces.append(np.stack([np.roll(ring, -1), ring, np.full(len(ring), n_v)], axis=1))
        n_v += 1
        holes += 1
    return np.vstack(v), np.vstack(new_faces), holes


def _simplified_for_decomposition(verts: np.ndarray, faces: np.ndarray):
    """Large meshes slow the decomposition down: merge edges shorter than 0.5 mm first."""
    if len(faces) <= 20000:
        return verts, faces
    try:
        m = mesh_manifold(verts, faces).simplify(5e-4)
    except ValueError:
        return verts, faces
    mesh = m.to_mesh64()
    return np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def _import_meshes(mesh, src: Path, method: str) -> tuple[_Built, dict]:
    # deferred: trimesh takes 0.8 s to import
    import trimesh

    lo, hi = mesh.bounds
    ext = hi - lo
    if float(ext.min()) < 1e-6:
        raise DataError(
            f"{src}: the mesh is flat (extents {np.round(ext, 6).tolist()} m): zero volume"
        )
    if not (PLAUSIBLE_SIZE_M[0] <= float(ext.max()) <= PLAUSIBLE_SIZE_M[1]):
        warnings.warn(
            f"{src}: object is {float(ext.max()):.4g} m across after scaling; "
            "is the unit right (e.g. --scale 0.001 for millimetres)?",
            stacklevel=3,
        )
    centre = (lo + hi) / 2.0
    verts = np.asarray(mesh.vertices, dtype=np.float64) - centre
    faces = np.asarray(mesh.faces, dtype=np.int64)
    watertight = bool(mesh.is_watertight)
    solid, holes = mesh, 0
    if not watertight:
        fv, ff, holes = fill_holes(verts, faces)
        solid = trimesh.Trimesh(fv, ff, process=False)
        if holes and solid.is_watertight and solid.is_winding_consistent:
            warnings.warn(
                f"{src}: mesh is not watertight; closed {holes} hole(s) for its collision shape",
                stacklevel=3,
            )
        else:
            solid = None
            warnings.warn(
                f"{src}: mesh is not watertight and its holes could not be closed; "
                "its collision shape is its convex hull (repair the mesh for a faithful one)",
                stacklevel=3,
            )
    hull_vol = float(mesh.convex_hull.volume)
    if solid is None:
        volume = hull_vol
        clouds, used = [verts], "convex-hull"
    else:
        volume = abs(float(solid.volume))
        if volume < 1e-12:
            raise DataError(f"{src}: the mesh encloses zero volume")
        if hull_vol <= volume * 1.02:
            clouds, used = [verts], "convex"
        else:
            sv, sf = np.asarray(solid.vertices), np.asarray(solid.faces, dtype=np.int64)
            if float(solid.volume) < 0:
                sf = sf[:, ::-1]
            clouds, used = decompose(*_simplified_for_decomposition(sv, sf), method), method
            if not clouds:
                raise DataError(f"{src}: convex decomposition ({method}) produced no parts")
    parts = [convex_hull_mesh(c) for c in clouds]
    info = {
        "decomposition": used,
        "watertight": watertight,
        "holes_closed": holes,
        "volume": volume,
    }
    return _Built(verts, faces, parts), info


def _read_spec(d: Path) -> ObjectSpec:
    f = d / "object.json"
    try:
        meta = json.loads(f.read_text())
        ext = np.asarray(meta["extents"], dtype=np.float64).reshape(3)
        spec = ObjectSpec(
            name=str(meta["name"]),
            source=str(meta["source"]),
            visual_mesh=d / "visual.obj",
            collision_meshes=sorted(d.glob("collision_*.obj")),
            scale=float(meta["scale"]),
            extents=ext,
            set=str(meta["set"]),
            rgba=tuple(float(c) for c in meta.get("rgba", (0.8, 0.8, 0.8, 1.0))),  # type: ignore[arg-type]
            compound_mesh=(d / "compound.obj") if (d / "compound.obj").is_file() else None,
            meta=meta,
        )
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise DataError(f"{f}: unreadable object description ({e})") from e
    if meta.get("format") != FORMAT_VERSION:
        raise DataError(f"{f}: object format {meta.get('format')!r}, expected {FORMAT_VERSION}")
    if not spec.visual_mesh.is_file() or not spec.collision_meshes:
        raise DataError(f"{d}: object is incomplete (visual.obj or collision_*.obj missing)")
    return spec
