"""Pictures of library objects: the mesh, training wrist poses and contact clouds.

In the style of the paper's figures: a shaded mesh, each wrist pose drawn as a short arrow
along the hand's +z axis (the direction the fingers extend), contacts as dots. Everything is
in the object frame. Headless (matplotlib's Agg backend).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from activetouch.errors import DataError
from activetouch.objects.library import ObjectSpec, read_obj_groups

LIGHT = np.array([0.35, -0.45, 0.82])  # from the upper front-left, like a desk lamp
VIEWS = ((18.0, -58.0), (62.0, 32.0))  # (elevation, azimuth) of the two panels


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and triangles (m, 3) of a plain OBJ (as this package writes them)."""
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(t.split("/")[0]) for t in line.split()[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not verts or not faces:
        raise DataError(f"{path}: no triangles")
    return np.asarray(verts, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def shade(tris: np.ndarray, rgb: np.ndarray, light: np.ndarray = LIGHT) -> np.ndarray:
    """Per-triangle colours: ambient plus two-sided Lambert (walls are seen from inside too)."""
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    lam = np.abs(n @ (light / np.linalg.norm(light)))
    k = 0.38 + 0.62 * lam
    return np.clip(rgb[None, :3] * k[:, None], 0.0, 1.0)


def pose_axes(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (N, 3) and hand +z axes (N, 3) of wrist poses (N, 7: xyz, quat xyzw)."""
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial.transform import Rotation

    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
    if len(poses) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    R = Rotation.from_quat(poses[:, 3:]).as_matrix()
    return poses[:, :3], R[:, :, 2]


def contacts_in_object_frame(poses: np.ndarray, xyz_hand: list[np.ndarray]) -> np.ndarray:
    """Contact points of each grasp (hand frame) moved into the object frame by its wrist pose."""
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial.transform import Rotation

    out = []
    for pose, pts in zip(np.asarray(poses).reshape(-1, 7), xyz_hand, strict=True):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        if len(pts):
            out.append(Rotation.from_quat(pose[3:]).apply(pts) + pose[:3])
    return np.vstack(out) if out else np.zeros((0, 3))


def render_object_png(
    spec: ObjectSpec,
    out_path: Path | str,
    poses: np.ndarray | None = None,
    contacts: np.ndarray | None = None,
    *,
    parts: bool = False,
    title: str | None = None,
    arrow_m: float = 0.03,
    dpi: int = 110,
) -> Path:
    """Draw `spec` (its visual mesh, or its convex collision parts if `parts`) with wrist
    `poses` (N, 7) as arrows and `contacts` (M, 3) as dots, all in the object frame; two
    views side by side. Returns the PNG path."""
    # deferred: matplotlib (0.8 s) only for figures
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib (0.8 s) only for figures
    import matplotlib.pyplot as plt

    # deferred: matplotlib (0.8 s) only for figures
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    rgb = np.asarray(spec.rgba[:3], dtype=np.float64)
    if parts:
        groups = []
        for i, f in enumerate(spec.collision_meshes):
            v, fc = read_obj(f)
            hue = np.array([0.3 + 0.6 * ((i * 0.37) % 1.0), 0.45 + 0.4 * ((i * 0.61) % 1.0), 0.8])
            groups.append((v[fc], hue))
        tris = np.concatenate([g[0] for g in groups])
        colours = np.concatenate([shade(t, c) for t, c in groups])
    else:
        v, fc = read_obj(spec.visual_mesh)
        tris = v[fc]
        colours = shade(tris, rgb)

    pos, axis = pose_axes(poses if poses is not None else np.zeros((0, 7)))
    con = (
        np.zeros((0, 3))
        if contacts is None
        else np.asarray(contacts, dtype=np.float64).reshape(-1, 3)
    )
    pts = [tris.reshape(-1, 3), pos, pos + arrow_m * axis, con]
    allp = np.vstack([p for p in pts if len(p)])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    centre, half = (lo + hi) / 2.0, max(float((hi - lo).max()) / 2.0, 1e-3) * 1.05
    z_table = -spec.height / 2.0

    fig = plt.figure(figsize=(9.0, 4.6))
    for k, (elev, azim) in enumerate(VIEWS):
        ax = fig.add_subplot(1, len(VIEWS), k + 1, projection="3d")
        # Fixed draw order (table, mesh, poses, contacts): depth-sorting whole collections
        # would put the table over the object's foot.
        ax.computed_zorder = False
        t = half * 0.95
        table = np.array(
            [
                [centre[0] - t, centre[1] - t, z_table],
                [centre[0] + t, centre[1] - t, z_table],
                [centre[0] + t, centre[1] + t, z_table],
                [centre[0] - t, centre[1] + t, z_table],
            ]
        )
        ax.add_collection3d(
            Poly3DCollection([table], facecolors=(0.85, 0.82, 0.75, 0.35), zorder=0)
        )
        ax.add_collection3d(
            Poly3DCollection(
                tris,
                facecolors=colours,
                edgecolors="none",
                linewidths=0.0,
                alpha=1.0 if spec.rgba[3] >= 0.99 else 0.75,
                zorder=1,
            )
        )
        if len(pos):
            ax.quiver(
                pos[:, 0],
                pos[:, 1],
                pos[:, 2],
                axis[:, 0],
                axis[:, 1],
                axis[:, 2],
                length=arrow_m,
                normalize=True,
                color="tab:blue",
                linewidth=0.7,
                arrow_length_ratio=0.3,
                zorder=2,
            )
            ax.scatter(
                pos[:, 0], pos[:, 1], pos[:, 2], s=3, color="tab:blue", depthshade=False, zorder=2
            )
        if len(con):
            ax.scatter(
                con[:, 0], con[:, 1], con[:, 2], s=4, color="crimson", depthshade=False, zorder=3
            )
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_box_aspect((1.0, 1.0, 1.0))
        ax.view_init(elev=elev, azim=azim)
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.set_zlabel("z (m)", fontsize=7)
        ax.tick_params(labelsize=6)
    ext = " x ".join(f"{e * 100:.1f}" for e in spec.extents)
    extra = []
    if len(pos):
        extra.append(f"{len(pos)} poses")
    if len(con):
        extra.append(f"{len(con)} contacts")
    head = title or f"{spec.name} ({spec.set}, {ext} cm{', convex parts' if parts else ''})"
    fig.suptitle(head + (": " + ", ".join(extra) if extra else ""), fontsize=10)
    fig.tight_layout()
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out


__all__ = [
    "contacts_in_object_frame",
    "pose_axes",
    "read_obj",
    "read_obj_groups",
    "render_object_png",
    "shade",
]
