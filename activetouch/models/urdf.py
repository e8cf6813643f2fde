"""URDF text for the hands the twin builds from their dimensions (boxes, site links, joints)
and the private cache PyBullet loads them from. Shared by the ReFlex (`models.reflex`) and the
BarrettHand (`models.bh8`) models."""

from __future__ import annotations

import hashlib
import os
import stat
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from activetouch.storage import atomic_write_text


@dataclass(frozen=True, eq=False)
class Box:
    """An oriented box: centre `position` and `rotation` (3x3, its axes as columns) in the
    frame it is given in (its link's for `link_boxes`, the hand's for `collision_boxes`).
    `name` is the box's own (e.g. the ReFlex's housing, proximal_0), `link` the URDF link that
    carries it."""

    name: str
    link: str
    half: np.ndarray  # (3,) half extents along the box's axes
    position: np.ndarray
    rotation: np.ndarray

    @classmethod
    def from_bounds(
        cls,
        name: str,
        link: str,
        lo: np.ndarray | Sequence[float],
        hi: np.ndarray | Sequence[float],
    ) -> Box:
        """The axis-aligned box between corners `lo` and `hi`."""
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        return cls(name, link, (hi - lo) / 2, (hi + lo) / 2, np.eye(3))

    @property
    def size(self) -> np.ndarray:
        return 2 * self.half

    @property
    def pose(self) -> np.ndarray:
        """4x4 pose of the box's centre frame."""
        t = np.eye(4)
        t[:3, :3], t[:3, 3] = self.rotation, self.position
        return t

    def moved(self, t: np.ndarray) -> Box:
        """This box in the frame where `t` (4x4) is the pose of the frame it is given in."""
        r = t[:3, :3]
        return Box(self.name, self.link, self.half, r @ self.position + t[:3, 3], r @ self.rotation)

    def corners(self) -> np.ndarray:
        """(8, 3) corners, x slowest: (-, -, -), (-, -, +), (-, +, -), ..."""
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        return (signs * self.half) @ self.rotation.T + self.position


def fmt(v: float) -> str:
    return f"{float(v):.6g}"


def xyz_text(v: np.ndarray | tuple[float, ...]) -> str:
    return " ".join(fmt(x) for x in v)


def _box_inertia(mass: float, size: np.ndarray | tuple[float, ...]) -> str:
    x, y, z = (float(v) for v in size)
    ixx = mass * (y * y + z * z) / 12
    iyy = mass * (x * x + z * z) / 12
    izz = mass * (x * x + y * y) / 12
    return f'<inertia ixx="{fmt(ixx)}" ixy="0" ixz="0" iyy="{fmt(iyy)}" iyz="0" izz="{fmt(izz)}"/>'


def rpy_of(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (fixed-axis x, y, z) of a rotation matrix (pitch within +-pi/2)."""
    return (
        float(np.arctan2(r[2, 1], r[2, 2])),
        float(np.arctan2(-r[2, 0], np.hypot(r[0, 0], r[1, 0]))),
        float(np.arctan2(r[1, 0], r[0, 0])),
    )


def _box_shape(tag: str, box: Box) -> str:
    # rpy only for a turned box: the axis-aligned ones print as they always have.
    turned = not np.array_equal(box.rotation, np.eye(3))
    rpy = f' rpy="{xyz_text(rpy_of(box.rotation))}"' if turned else ""
    return (
        f'    <{tag}><origin xyz="{xyz_text(box.position)}"{rpy}/><geometry><box '
        f'size="{xyz_text(box.size)}"/></geometry></{tag}>\n'
    )


def box_link(name: str, mass: float, boxes: list[Box]) -> str:
    """A link of boxes, its inertia that of the first (a fingertip adds shape, not mass)."""
    body = boxes[0]
    shapes = "".join(_box_shape(tag, b) for b in boxes for tag in ("visual", "collision"))
    return (
        f'  <link name="{name}">\n'
        f'    <inertial><origin xyz="{xyz_text(body.position)}"/><mass value="{fmt(mass)}"/>'
        f"{_box_inertia(mass, body.size)}</inertial>\n"
        f"{shapes}"
        f"  </link>\n"
    )


def site_link(name: str) -> str:
    # Tiny inertia so the loader does not invent a 1 kg default; no geometry.
    return (
        f'  <link name="{name}"><inertial><mass value="1e-6"/>'
        f'<inertia ixx="1e-12" ixy="0" ixz="0" iyy="1e-12" iyz="0" izz="1e-12"/>'
        f"</inertial></link>\n"
    )


def urdf_joint(
    name: str,
    kind: str,
    parent: str,
    child: str,
    xyz: tuple[float, ...] | np.ndarray,
    rpy: tuple[float, ...] = (0.0, 0.0, 0.0),
    axis: tuple[float, float, float] | None = None,
    limits: tuple[float, float] | None = None,
) -> str:
    s = f'  <joint name="{name}" type="{kind}">\n'
    s += f'    <parent link="{parent}"/><child link="{child}"/>\n'
    s += f'    <origin xyz="{xyz_text(xyz)}" rpy="{xyz_text(rpy)}"/>\n'
    if axis is not None:
        s += f'    <axis xyz="{xyz_text(axis)}"/>\n'
    if limits is not None:
        s += (
            f'    <limit lower="{fmt(limits[0])}" upper="{fmt(limits[1])}" effort="10" '
            f'velocity="5"/>\n'
        )
    return s + "  </joint>\n"


def private_cache_dir() -> Path:
    """``/tmp/activetouch-<uid>``, made 0700 by this user; if someone else made it first (a
    predictable name in a shared directory), or others may write to it, a fresh private one
    instead: a planted URDF must never be loaded."""
    root = Path(tempfile.gettempdir()) / f"activetouch-{os.getuid()}"
    try:
        root.mkdir(mode=0o700, exist_ok=True)
        st = root.lstat()
        if (
            not stat.S_ISDIR(st.st_mode)
            or st.st_uid != os.getuid()
            or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
        ):
            raise PermissionError(f"{root} is not a private directory of this user")
    except OSError:
        return Path(tempfile.mkdtemp(prefix="activetouch-"))
    return root


def cached_urdf(text: str, stem: str, cache_dir: Path | None = None) -> Path:
    """Write URDF `text` to ``<stem>_<content hash>.urdf`` in the private cache (pybullet loads
    from files); atomically (temp file + rename), so concurrent worlds and processes are safe."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    root = cache_dir or private_cache_dir()
    root.mkdir(parents=True, exist_ok=True)
    path = root / f"{stem}_{digest}.urdf"
    if not path.exists() or path.read_text() != text:
        atomic_write_text(path, text)
    return path
