"""The ReFlex hand as a URDF built from the real hand's dimensions, plus its forward kinematics.

Numbers come from /work/shared/hardware-facts.md (reflex-ros-pkg's visualiser URDF and
tf_geometry.yaml, tactile_triangles' Gazebo model for masses and limits). Joint origins follow
the visualiser URDF (not tf_geometry.yaml, whose swivel y signs are mirrored): the visualiser is
what the authors' contact XYZ were expressed in.

Frames (all as in that URDF):
- hand / base frame: fingers 0 and 1 stand at +x, the thumb at -x, the palm pad faces +z
  (pad top at z = 0.0896); this is the wrist pose handed to the arm.
- proximal / distal link frames: the link extends along +x, the tactile face is +z, joints
  turn about -y, so a positive angle lifts the finger from lying flat (open, 0) towards +z and
  then over the palm (closed).
- finger f (message index 0 pointer, 1 middle, 2 thumb) is URDF finger f + 1; fingers 0 and 1
  sit on swivels that one motor turns by +preshape and -preshape about -z.

Sensor sites are sensor-frame origins (what the authors used as contact XYZ): 5 on the proximal
link, 4 on the distal link (the last one, the fingertip, tilted about y), 11 on the palm.
`sensor_positions` computes their hand-frame XYZ from the joint angles in numpy; the URDF also
carries them as massless fixed links so the two can be checked against each other.

Collision boxes: `link_boxes` (each in its URDF link's frame) is the one list the URDF, the
motion planner's collision model and the object calibration's hand all use; `collision_boxes`
poses them in the hand frame at given joint angles (`link_frames`).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from activetouch.interfaces import N_FINGERS, N_SENSORS, SENSORS_PER_FINGER
from activetouch.models.urdf import (
    Box,
    box_link,
    cached_urdf,
    site_link,
    urdf_joint,
)

N_PROXIMAL_SENSORS = 5
N_DISTAL_SENSORS = 4

# Palm sensor (x, y) in the base frame, ids 27..37 in this order (2014 visualiser).
PALM_SITES_XY: tuple[tuple[float, float], ...] = (
    (-0.0235, -0.0315),
    (-0.0235, -0.0275),
    (0.0045, -0.0315),
    (0.0045, -0.0275),
    (-0.0235, 0.0315),
    (-0.0235, 0.0275),
    (0.0045, 0.0315),
    (0.0045, 0.0275),
    (0.026, -0.002),
    (0.026, 0.002),
    (0.054, 0.0),
)

# Distal sensor sites: the visualiser URDF's, and tactile_triangles' Gazebo model's.
DISTAL_SENSOR_X_URDF = (0.0114, 0.0193, 0.0272, 0.0375)
DISTAL_SENSOR_Z_URDF = (0.0129, 0.0129, 0.0129, 0.0073)
DISTAL_SENSOR_X_GAZEBO = (0.0135, 0.0215, 0.0295, 0.0375)
DISTAL_SENSOR_Z_GAZEBO = (0.009, 0.009, 0.009, 0.009)


def _t3(v: tuple[float, ...] | list[float]) -> tuple[float, float, float]:
    a = tuple(float(x) for x in v)
    if len(a) != 3:
        raise ValueError(f"expected 3 numbers, got {v!r}")
    return a  # type: ignore[return-value]


@dataclass(frozen=True)
class ReflexGeometry:
    """Dimensions of the hand (metres, radians, kilograms)."""

    # Joint origins (visualiser URDF).
    swivel_origins: tuple[tuple[float, float, float], ...] = (
        (0.0504, -0.026, 0.063),
        (0.0504, 0.026, 0.063),
    )
    proximal_on_swivel: tuple[float, float, float] = (0.01, 0.0, 0.0186)
    thumb_origin: tuple[float, float, float] = (-0.03, 0.0, 0.0816)
    thumb_yaw: float = np.pi
    # Pitch of the proximal joint origins: 0 in hardware-facts.md and the older visualiser URDF
    # (used here); the newest visualiser URDF has 0.28 (open fingers tilted below the palm).
    proximal_zero_pitch: float = 0.0
    distal_on_proximal: tuple[float, float, float] = (0.076, 0.0, 0.0025)
    # Sensor sites.
    proximal_sensor_x: tuple[float, ...] = (0.0189, 0.0268, 0.0347, 0.0426, 0.0506)
    proximal_sensor_z: float = 0.0154
    distal_sensor_x: tuple[float, ...] = DISTAL_SENSOR_X_URDF
    distal_sensor_z: tuple[float, ...] = DISTAL_SENSOR_Z_URDF
    tip_sensor_tilt: float = 0.52  # fingertip sensor pitched towards +x about the link's y
    palm_sites_xy: tuple[tuple[float, float], ...] = PALM_SITES_XY
    palm_sensor_z: float = 0.082
    # Collision boxes: palm housing (below the pad) and the pad, from the mesh bounds
    # (housing x -0.055..0.083, y +-0.053, z 0..0.093; pad top 0.0896).
    housing_lo: tuple[float, float, float] = (-0.055, -0.053, 0.0)
    housing_hi: tuple[float, float, float] = (0.083, 0.053, 0.075)
    pad_lo: tuple[float, float, float] = (-0.045, -0.045, 0.075)
    pad_hi: tuple[float, float, float] = (0.07, 0.045, 0.0896)
    swivel_size: tuple[float, float, float] = (0.024, 0.018, 0.024)
    proximal_size: tuple[float, float, float] = (0.071, 0.014, 0.022)  # length, width, height
    distal_size: tuple[float, float, float] = (0.0385, 0.014, 0.017)
    # Masses (Gazebo model).
    base_mass: float = 0.271
    pad_mass: float = 0.114
    swivel_mass: float = 0.0126
    proximal_mass: float = 0.0170
    distal_mass: float = 0.0060
    # Joint limits.
    preshape_limit: float = 1.6
    proximal_limit: float = float(np.pi)
    distal_limit: float = 2.74

    def __post_init__(self) -> None:
        if len(self.proximal_sensor_x) != N_PROXIMAL_SENSORS:
            raise ValueError(f"need {N_PROXIMAL_SENSORS} proximal sensor x values")
        if len(self.distal_sensor_x) != N_DISTAL_SENSORS:
            raise ValueError(f"need {N_DISTAL_SENSORS} distal sensor x values")
        if len(self.distal_sensor_z) != N_DISTAL_SENSORS:
            raise ValueError(f"need {N_DISTAL_SENSORS} distal sensor z values")
        if len(self.palm_sites_xy) != N_SENSORS - N_FINGERS * SENSORS_PER_FINGER:
            raise ValueError("need 11 palm sites")

    @property
    def proximal_box(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the proximal collision box in its link frame: top face at the sensors."""
        length, width, height = self.proximal_size
        top = self.proximal_sensor_z
        return (
            np.array([0.0, -width / 2, top - height]),
            np.array([length, width / 2, top]),
        )

    @property
    def chamfer_start_x(self) -> float:
        """Where the fingertip chamfer (the tip sensor's tilted face) meets the distal top."""
        top = max(self.distal_sensor_z[:-1])
        tip_x, tip_z = self.distal_sensor_x[-1], self.distal_sensor_z[-1]
        t = self.tip_sensor_tilt
        if t <= 1e-6:
            return float(self.distal_size[0])
        return float(min(tip_x, tip_x - (top - tip_z) / np.tan(t)))

    @property
    def distal_box(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the distal collision box, top face at the (untilted) distal sensors,
        ending where the fingertip chamfer begins."""
        _, width, height = self.distal_size
        top = max(self.distal_sensor_z[:-1])
        return (
            np.array([0.0, -width / 2, top - height]),
            np.array([self.chamfer_start_x, width / 2, top]),
        )

    @property
    def fingertip_box(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre, size) of the fingertip box in the distal frame, pitched by tip_sensor_tilt:
        its top face is the tip sensor's plane, from the chamfer start to just past the tip, so
        the fingertip sensor faces forward-up as on the real, rounded fingertip."""
        top = max(self.distal_sensor_z[:-1])
        tip = np.array([self.distal_sensor_x[-1], 0.0, self.distal_sensor_z[-1]])
        r = rot_y(self.tip_sensor_tilt)
        start = r.T @ (np.array([self.chamfer_start_x, 0.0, top]) - tip)  # in the tilted frame
        end_x = max(float(start[0]) + 1e-3, self.distal_size[0] - tip[0])  # past the tip
        depth = 0.7 * self.distal_size[2]
        centre_tilted = np.array([(start[0] + end_x) / 2, 0.0, -depth / 2])
        size = np.array([end_x - start[0], self.distal_size[1], depth])
        return tip + r @ centre_tilted, size


def geometry_with_distal_sites(
    distal_x: list[float] | tuple[float, ...],
    distal_z: list[float] | tuple[float, ...],
    proximal_zero_pitch: float = 0.0,
) -> ReflexGeometry:
    """Default geometry with the source-dependent choices replaced: distal sensor sites and
    the proximal joints' zero pitch."""
    return ReflexGeometry(
        distal_sensor_x=tuple(float(v) for v in distal_x),
        distal_sensor_z=tuple(float(v) for v in distal_z),
        proximal_zero_pitch=float(proximal_zero_pitch),
    )


# One shared instance: the kinematics caches key on the geometry, so callers without their own
# (the hardware drivers) hash and hit this one.
DEFAULT_GEOMETRY: Final = ReflexGeometry()


# ---------------------------------------------------------------------------------------------
# Kinematics (pure numpy)


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def transform(rotation: np.ndarray, translation: np.ndarray | tuple[float, ...]) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def swivel_transform(geom: ReflexGeometry, finger: int, preshape: float) -> np.ndarray:
    """4x4 hand-frame pose of finger `finger`'s (0 or 1) swivel link frame."""
    # preshape_1 = +theta about -z, preshape_2 = -theta about -z.
    swivel_angle = -preshape if finger == 0 else preshape
    return transform(rot_z(swivel_angle), geom.swivel_origins[finger])


def finger_link_transforms(
    geom: ReflexGeometry, finger: int, preshape: float, proximal: float, distal: float
) -> tuple[np.ndarray, np.ndarray]:
    """4x4 hand-frame poses of finger `finger`'s proximal and distal link frames."""
    if finger < 2:
        t_prox_origin = swivel_transform(geom, finger, preshape) @ transform(
            rot_y(geom.proximal_zero_pitch), geom.proximal_on_swivel
        )
    else:
        t_prox_origin = transform(
            rot_z(geom.thumb_yaw) @ rot_y(geom.proximal_zero_pitch), geom.thumb_origin
        )
    # Joints turn about -y: rotation by -angle about +y.
    t_prox = t_prox_origin @ transform(rot_y(-proximal), (0.0, 0.0, 0.0))
    t_dist = t_prox @ transform(rot_y(-distal), geom.distal_on_proximal)
    return t_prox, t_dist


def finger_site_offsets(geom: ReflexGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Sensor-site positions in the proximal (5, 3) and distal (4, 3) link frames."""
    prox = np.zeros((N_PROXIMAL_SENSORS, 3))
    prox[:, 0] = geom.proximal_sensor_x
    prox[:, 2] = geom.proximal_sensor_z
    dist = np.zeros((N_DISTAL_SENSORS, 3))
    dist[:, 0] = geom.distal_sensor_x
    dist[:, 2] = geom.distal_sensor_z
    return prox, dist


def palm_site_positions(geom: ReflexGeometry) -> np.ndarray:
    """(11, 3) palm sensor sites in the hand frame."""
    xy = np.asarray(geom.palm_sites_xy, dtype=np.float64)
    return np.column_stack([xy, np.full(len(xy), geom.palm_sensor_z)])


@functools.lru_cache(maxsize=256)
def _proximal_base(
    geom: ReflexGeometry, finger: int, preshape: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and origin of a finger's proximal joint frame at angle 0 (cached: the
    preshape is fixed during a close)."""
    t = finger_link_transforms(geom, finger, preshape, 0.0, 0.0)[0]
    r, o = t[:3, :3].copy(), t[:3, 3].copy()
    r.flags.writeable = o.flags.writeable = False
    return r, o


@functools.lru_cache(maxsize=16)
def _site_offsets(geom: ReflexGeometry) -> tuple[np.ndarray, np.ndarray]:
    prox, dist = finger_site_offsets(geom)
    prox.flags.writeable = dist.flags.writeable = False
    return prox, dist


def finger_sensor_positions(
    geom: ReflexGeometry, finger: int, preshape: float, proximal: float, distal: float
) -> np.ndarray:
    """(9, 3) hand-frame XYZ of finger `finger`'s sensor sites (0 nearest the palm ... 8 tip).
    Same frames as `finger_link_transforms`, composed with fewer operations (hot path)."""
    prox_sites, dist_sites = _site_offsets(geom)
    r0, o = _proximal_base(geom, finger, float(preshape))
    r_prox = r0 @ rot_y(-proximal)
    r_dist = r_prox @ rot_y(-distal)
    o_dist = o + r_prox @ np.asarray(geom.distal_on_proximal)
    out = np.empty((SENSORS_PER_FINGER, 3))
    out[:N_PROXIMAL_SENSORS] = prox_sites @ r_prox.T + o
    out[N_PROXIMAL_SENSORS:] = dist_sites @ r_dist.T + o_dist
    return out


def sensor_positions(
    geom: ReflexGeometry,
    preshape: float,
    proximal: np.ndarray | list[float],
    distal: np.ndarray | list[float],
) -> np.ndarray:
    """(38, 3) hand-frame XYZ of every sensor site (ids as in activetouch.interfaces)."""
    prox_angles = np.asarray(proximal, dtype=np.float64).reshape(N_FINGERS)
    dist_angles = np.asarray(distal, dtype=np.float64).reshape(N_FINGERS)
    out = np.empty((N_SENSORS, 3))
    for f in range(N_FINGERS):
        out[f * SENSORS_PER_FINGER : (f + 1) * SENSORS_PER_FINGER] = finger_sensor_positions(
            geom, f, preshape, prox_angles[f], dist_angles[f]
        )
    out[N_FINGERS * SENSORS_PER_FINGER :] = palm_site_positions(geom)
    return out


def grasp_free_sites(
    geom: ReflexGeometry, preshape: float, proximal: np.ndarray, contact_ids: np.ndarray
) -> np.ndarray:
    """(F, 3) hand-frame points a grasp shows to be outside the object: the sensor sites it
    left without contact at its final proximal angles (distal taken as 0: the grasp does not
    report it), and every finger site at 35 % and 70 % of its finger's closing angle, which
    the finger swept through freely on its way (the palm does not move)."""
    angles = np.asarray(proximal, dtype=np.float64).reshape(N_FINGERS)
    zeros = np.zeros(N_FINGERS)
    final = sensor_positions(geom, preshape, angles, zeros)
    quiet = np.ones(N_SENSORS, dtype=bool)
    quiet[np.asarray(contact_ids, dtype=np.int64)] = False
    free = [final[quiet]]
    for frac in (0.35, 0.7):
        swept = sensor_positions(geom, preshape, angles * frac, zeros)
        free.append(swept[: N_FINGERS * SENSORS_PER_FINGER])
    return np.concatenate(free)


def coupled_joints(
    spool: np.ndarray,
    proximal_hold: np.ndarray,
    proximal_blocked: np.ndarray,
    coupling: float,
    proximal_limit: float,
    distal_limit: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Proximal and distal angles for spool (tendon) angles: a free finger splits the travel
    proximal = spool / (1 + k), distal = k * proximal; a blocked proximal holds its angle and
    the distal takes the rest (distal = spool - proximal, the driver's distal estimate)."""
    free = spool / (1.0 + coupling)
    prox = np.minimum(np.where(proximal_blocked, proximal_hold, free), proximal_limit)
    dist = np.clip(spool - prox, 0.0, distal_limit)
    return prox, dist


# ---------------------------------------------------------------------------------------------
# Links and collision boxes

# Joint and link names; finger f is URDF finger f + 1.
PRESHAPE_JOINTS = ("preshape_1", "preshape_2")
PROXIMAL_JOINTS = ("proximal_1", "proximal_2", "proximal_3")
DISTAL_JOINTS = ("distal_1", "distal_2", "distal_3")
BASE_LINK = "base"
PAD_LINK = "pad"
SWIVEL_LINKS = ("swivel_1", "swivel_2")
PROXIMAL_LINKS = ("proximal_1", "proximal_2", "proximal_3")
DISTAL_LINKS = ("distal_1", "distal_2", "distal_3")


def link_boxes(geom: ReflexGeometry) -> list[Box]:
    """Every collision box in its link's frame, in URDF link order: housing, pad, then per
    finger [swivel (fingers 0, 1)], proximal, distal, fingertip. The URDF is written from
    these, so they are what PyBullet collides."""
    g = geom
    out = [
        Box.from_bounds("housing", BASE_LINK, g.housing_lo, g.housing_hi),
        Box.from_bounds("pad", PAD_LINK, g.pad_lo, g.pad_hi),
    ]
    # The swivel box sits halfway between the swivel joint and the proximal joint.
    half_sw = np.array(g.swivel_size) / 2
    c_sw = np.array([g.proximal_on_swivel[0] * 0.5, 0.0, g.proximal_on_swivel[2] * 0.5])
    prox_lo, prox_hi = g.proximal_box
    dist_lo, dist_hi = g.distal_box
    tip_centre, tip_size = g.fingertip_box
    for f in range(N_FINGERS):
        if f < 2:
            out.append(
                Box.from_bounds(f"swivel_{f}", SWIVEL_LINKS[f], c_sw - half_sw, c_sw + half_sw)
            )
        out.append(Box.from_bounds(f"proximal_{f}", PROXIMAL_LINKS[f], prox_lo, prox_hi))
        out.append(Box.from_bounds(f"distal_{f}", DISTAL_LINKS[f], dist_lo, dist_hi))
        out.append(
            Box(
                f"fingertip_{f}",
                DISTAL_LINKS[f],
                tip_size / 2,
                tip_centre,
                rot_y(g.tip_sensor_tilt),
            )
        )
    return out


def link_frames(
    geom: ReflexGeometry,
    preshape: float = 0.0,
    proximal: np.ndarray | Sequence[float] | None = None,
    distal: np.ndarray | Sequence[float] | None = None,
) -> dict[str, np.ndarray]:
    """4x4 hand-frame pose of every URDF link (sensor sites aside) at these joint angles
    (fingers open, 0, by default)."""
    prox = np.zeros(N_FINGERS) if proximal is None else np.asarray(proximal, dtype=np.float64)
    dist = np.zeros(N_FINGERS) if distal is None else np.asarray(distal, dtype=np.float64)
    out = {BASE_LINK: np.eye(4), PAD_LINK: np.eye(4)}  # the pad is fixed to the base
    for f in range(N_FINGERS):
        if f < 2:
            out[SWIVEL_LINKS[f]] = swivel_transform(geom, f, preshape)
        out[PROXIMAL_LINKS[f]], out[DISTAL_LINKS[f]] = finger_link_transforms(
            geom, f, preshape, float(prox[f]), float(dist[f])
        )
    return out


def collision_boxes(
    geom: ReflexGeometry | None = None,
    preshape: float = 0.0,
    proximal: np.ndarray | Sequence[float] | None = None,
    distal: np.ndarray | Sequence[float] | None = None,
) -> list[Box]:
    """The URDF's collision boxes (`link_boxes`) in the hand frame at these joint angles
    (open by default)."""
    g = geom or DEFAULT_GEOMETRY
    frames = link_frames(g, preshape, proximal, distal)
    return [b.moved(frames[b.link]) for b in link_boxes(g)]


# ---------------------------------------------------------------------------------------------
# URDF text


def sensor_link_name(sensor: int) -> str:
    """Name of the massless site link of sensor id `sensor` (0..37)."""
    if 0 <= sensor < N_FINGERS * SENSORS_PER_FINGER:
        f, s = divmod(sensor, SENSORS_PER_FINGER)
        return f"finger{f}_sensor{s}"
    if sensor < N_SENSORS:
        return f"palm_sensor{sensor - N_FINGERS * SENSORS_PER_FINGER}"
    raise ValueError(f"no sensor {sensor}")


def build_urdf(geom: ReflexGeometry | None = None, sensor_links: bool = True) -> str:
    """The hand's URDF text: boxes with the real sizes and masses, and (if `sensor_links`)
    a massless fixed link per sensor site. The twin loads it without the site links: 38 extra
    links make every PyBullet joint reset ~8x slower, and `sensor_positions` gives the same
    positions (tested against the links)."""
    g = geom or ReflexGeometry()
    boxes: dict[str, list[Box]] = {}
    for b in link_boxes(g):
        boxes.setdefault(b.link, []).append(b)
    parts = ['<?xml version="1.0"?>\n<robot name="reflex">\n']
    parts.append(box_link(BASE_LINK, g.base_mass, boxes[BASE_LINK]))
    parts.append(box_link(PAD_LINK, g.pad_mass, boxes[PAD_LINK]))
    parts.append(urdf_joint("pad_joint", "fixed", BASE_LINK, PAD_LINK, (0.0, 0.0, 0.0)))

    prox_sites, dist_sites = finger_site_offsets(g)
    tilt = g.tip_sensor_tilt
    for f in range(N_FINGERS):
        if f < 2:
            swivel = SWIVEL_LINKS[f]
            parts.append(box_link(swivel, g.swivel_mass, boxes[swivel]))
            parts.append(
                urdf_joint(
                    PRESHAPE_JOINTS[f],
                    "revolute",
                    BASE_LINK,
                    swivel,
                    g.swivel_origins[f],
                    axis=(0.0, 0.0, -1.0),
                    limits=(-g.preshape_limit, g.preshape_limit),
                )
            )
            prox_parent, prox_xyz = swivel, g.proximal_on_swivel
            prox_rpy: tuple[float, ...] = (0.0, g.proximal_zero_pitch, 0.0)
        else:
            prox_parent, prox_xyz = BASE_LINK, g.thumb_origin
            prox_rpy = (0.0, g.proximal_zero_pitch, g.thumb_yaw)
        parts.append(box_link(PROXIMAL_LINKS[f], g.proximal_mass, boxes[PROXIMAL_LINKS[f]]))
        parts.append(
            urdf_joint(
                PROXIMAL_JOINTS[f],
                "revolute",
                prox_parent,
                PROXIMAL_LINKS[f],
                prox_xyz,
                prox_rpy,
                axis=(0.0, -1.0, 0.0),
                limits=(0.0, g.proximal_limit),
            )
        )
        parts.append(box_link(DISTAL_LINKS[f], g.distal_mass, boxes[DISTAL_LINKS[f]]))
        parts.append(
            urdf_joint(
                DISTAL_JOINTS[f],
                "revolute",
                PROXIMAL_LINKS[f],
                DISTAL_LINKS[f],
                g.distal_on_proximal,
                axis=(0.0, -1.0, 0.0),
                limits=(0.0, g.distal_limit),
            )
        )
        for s in range(SENSORS_PER_FINGER if sensor_links else 0):
            sid = f * SENSORS_PER_FINGER + s
            if s < N_PROXIMAL_SENSORS:
                parent, xyz, rpy = PROXIMAL_LINKS[f], prox_sites[s], (0.0, 0.0, 0.0)
            else:
                parent, xyz = DISTAL_LINKS[f], dist_sites[s - N_PROXIMAL_SENSORS]
                rpy = (0.0, tilt, 0.0) if s == SENSORS_PER_FINGER - 1 else (0.0, 0.0, 0.0)
            parts.append(site_link(sensor_link_name(sid)))
            parts.append(
                urdf_joint(
                    f"{sensor_link_name(sid)}_joint",
                    "fixed",
                    parent,
                    sensor_link_name(sid),
                    xyz,
                    rpy,
                )
            )
    for i, xyz in enumerate(palm_site_positions(g) if sensor_links else []):
        sid = N_FINGERS * SENSORS_PER_FINGER + i
        parts.append(site_link(sensor_link_name(sid)))
        parts.append(
            urdf_joint(
                f"{sensor_link_name(sid)}_joint", "fixed", PAD_LINK, sensor_link_name(sid), xyz
            )
        )
    parts.append("</robot>\n")
    return "".join(parts)


def urdf_file(
    geom: ReflexGeometry | None = None, cache_dir: Path | None = None, sensor_links: bool = False
) -> Path:
    """Write the URDF to a cache file named by its content hash (pybullet loads from files).

    Written atomically (temp file + rename), so concurrent worlds and processes are safe."""
    return cached_urdf(build_urdf(geom, sensor_links), "reflex", cache_dir)
