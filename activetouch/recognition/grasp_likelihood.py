"""A Bayesian belief over classes from per-grasp likelihoods p(grasp | y, wrist pose).

The paper classifies the histogram of every triangle felt so far. That bag forgets where each
grasp was made and drops grasps with fewer than 3 contacts, so look-alikes that differ in one
place (a bottle's neck, a box a centimetre taller) stay confused, and an empty grasp, which
says "the object is not here", counts for nothing. This belief keeps both:

    log b_t(y) = sum over grasps g of log p(g | y, pose of g),  p(y | history) = softmax(b_t)

p(g | y, x) is a kernel estimate from class y's training grasps near wrist pose x (the same
grasps the observation model draws from): each training grasp j weighs

    w_j = exp(-|x - x_j|^2 / 2 s_x^2 - angle(x, x_j)^2 / 2 s_r^2)            (near in pose)
    k_j = exp(-hamming(sensors, sensors_j) / s_h - |theta - theta_j|^2 / 2 s_t^2)   (alike)

with the sensors in contact as bits (38 for the ReFlex, 96 for the BarrettHand: 64-bit words)
and theta the three fingers' closing angles (how far a
finger closed says how wide the object is where it touched). p(g | y, x) = sum w k / sum w,
plus a floor so one odd grasp cannot rule a class out. A class with no training grasp near x
gets the mean likelihood of those that have one (it has no say there).

Sensors masked in a recognition (dead, stuck, in contact at rest) are left out of the Hamming
distance on both sides. They also move where a finger stops: the guarded close stops a finger
on the first reading in which one of its own sensors feels the object, so a finger whose
training grasp felt the object only on sensors masked now (they are not heard) closes on past
that angle. For such a finger and training grasp only closing less than the training grasp
counts against the class (`censored_fingers`): with the placement known, 4 dead sensors cost
the lip-necked bottle a quarter of its runs against the long-necked one (docs/benchmark.md).
"""

from __future__ import annotations

import hashlib
import io
import logging
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from activetouch.config import RecognitionConfig
from activetouch.errors import ConfigError, DataError
from activetouch.interfaces import Grasp, Pose
from activetouch.storage import atomic_write_bytes

log = logging.getLogger(__name__)

MAX_SENSOR_ID = 1023  # sensor ids the masks take (words of 64 bits, as many as needed)
_WEIGHT_CUTOFF = 1e-6  # training poses weighing less than this are left out of the sums


_DEFAULTS = RecognitionConfig()  # the widths' defaults live with the settings


@dataclass(frozen=True)
class LikelihoodParams:
    """The kernel widths: the `recognition.likelihood_*` settings without their prefix."""

    pose_sigma_m: float = _DEFAULTS.likelihood_pose_sigma_m
    pose_sigma_deg: float = _DEFAULTS.likelihood_pose_sigma_deg
    sensor_scale: float = _DEFAULTS.likelihood_sensor_scale  # Hamming distance per e-fold
    angle_sigma_rad: float = _DEFAULTS.likelihood_angle_sigma_rad
    floor: float = _DEFAULTS.likelihood_floor

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, int | float) and np.isfinite(v) and v > 0):
                raise ConfigError(f"recognition.likelihood_{f.name} must be > 0, got {v!r}")

    @classmethod
    def from_config(cls, rc: RecognitionConfig) -> LikelihoodParams:
        return cls(**{f.name: getattr(rc, f"likelihood_{f.name}") for f in fields(cls)})


def mask_words(sensor_ids: np.ndarray) -> int:
    """64-bit words a mask needs for these ids (at least one)."""
    ids = np.asarray(sensor_ids, dtype=np.int64).reshape(-1)
    return max(1, int(ids.max()) // 64 + 1) if len(ids) else 1


def sensor_mask(sensor_ids: np.ndarray, words: int = 1) -> np.ndarray:
    """The sensors in contact as a bit mask of `words` 64-bit words (bit i % 64 of word
    i // 64 = sensor i)."""
    ids = np.asarray(sensor_ids, dtype=np.int64).reshape(-1)
    if len(ids) and (ids.min() < 0 or ids.max() >= 64 * words):
        raise DataError(
            f"sensor ids must be in [0, {64 * words}) for the likelihood, got {ids.tolist()}"
        )
    out = np.zeros(words, dtype=np.uint64)
    np.bitwise_or.at(out, ids // 64, np.left_shift(np.uint64(1), (ids % 64).astype(np.uint64)))
    return out


def finger_closure(grasp: Grasp) -> np.ndarray:
    """The three fingers' closing angles (3,), zeros where the hand reports fewer."""
    out = np.zeros(3)
    a = np.asarray(grasp.finger_angles, dtype=np.float64).reshape(-1)[:3]
    out[: len(a)] = a
    return out


def finger_censor(ignore: np.ndarray | None, finger_sensors: int, words: int) -> np.ndarray | None:
    """(2, 3, `words`) mask words of each finger's masked sensors (`ignore`; [0]) and of its
    other sensors ([1]), finger f's own sensors being ids f * `finger_sensors` ... +
    `finger_sensors` - 1 (the palm's after them stop no finger); None when no finger has one
    masked or the hand's layout is not given (`finger_sensors` 0)."""
    if ignore is None or finger_sensors <= 0:
        return None
    ids = np.asarray(ignore, dtype=np.int64).reshape(-1)
    ids = ids[ids < min(3 * finger_sensors, 64 * words)]
    if not ids.size:
        return None
    out = np.zeros((2, 3, words), dtype=np.uint64)
    for f in range(3):
        own = np.arange(f * finger_sensors, (f + 1) * finger_sensors)
        own = own[own < 64 * words]
        masked = np.intersect1d(own, ids)
        out[0, f] = sensor_mask(masked, words)
        out[1, f] = sensor_mask(np.setdiff1d(own, masked), words)
    return out


def censored_fingers(trained: np.ndarray, censor: np.ndarray) -> np.ndarray:
    """(R, 3) for R training grasps' sensor words `trained` (R, W): whether each finger felt
    the object only on sensors masked now (`finger_censor`'s words). Such a finger stopped
    on a sensor the guarded close no longer hears, and closes on past that angle; one that
    also felt an unmasked sensor stops about where it did (that sensor is pressed within the
    step after the first), so it is compared as usual."""
    t = trained[:, None, :]
    return np.any(t & censor[0][None], axis=-1) & ~np.any(t & censor[1][None], axis=-1)


def closure_gaps(trained: np.ndarray, felt: np.ndarray, censored: np.ndarray | None) -> np.ndarray:
    """(n, R) the squared closure differences summed over the fingers between n grasps
    `felt` (n, 3) and R training grasps `trained` (R, 3); where `censored` (R, 3) a finger
    closing further than its training grasp costs nothing (its stop was not heard)."""
    d = trained[None, :, :] - felt[:, None, :]
    if censored is not None:
        d = np.where(censored[None], np.maximum(d, 0.0), d)
    return np.sum(d**2, axis=2)


def grasp_kernel(ham: np.ndarray, d2: np.ndarray, params: LikelihoodParams) -> np.ndarray:
    """k between grasps from their sensor bits' Hamming distance `ham` and the squared
    difference `d2` of their fingers' closure (summed over the fingers)."""
    return np.exp(-ham / params.sensor_scale - d2 / (2.0 * params.angle_sigma_rad**2))


def pose_weights(poses: np.ndarray, x: np.ndarray, sigma_m: float, sigma_rad: float) -> np.ndarray:
    """Gaussian weights (n,) of training poses (n, 7) around wrist pose `x` (7,): translation
    distance and rotation angle (q and -q alike)."""
    return pose_weights_at(
        poses, np.asarray(x, dtype=np.float64).reshape(1, 7), sigma_m, sigma_rad
    )[0]


def pose_weights_at(
    poses: np.ndarray, x: np.ndarray, sigma_m: float, sigma_rad: float
) -> np.ndarray:
    """(P, n) Gaussian weights of training poses (n, 7) around each wrist pose of `x` (P, 7)."""
    q = x[:, 3:] / np.linalg.norm(x[:, 3:], axis=1, keepdims=True)
    d2 = np.sum((x[:, None, :3] - poses[None, :, :3]) ** 2, axis=2)
    ang = 2.0 * np.arccos(np.clip(np.abs(q @ poses[:, 3:].T), 0.0, 1.0))
    return np.exp(-d2 / (2.0 * sigma_m**2) - ang**2 / (2.0 * sigma_rad**2))


@njit(cache=True)
def cut_pose_weights_at(
    poses: np.ndarray, x: np.ndarray, sigma_m: float, sigma_rad: float, cutoff: float
) -> np.ndarray:
    """`pose_weights_at` with the weights at or under `cutoff` set to 0, compiled: a
    translation alone that puts a pair under the cutoff skips its rotation angle (the pose
    belief weighs hundreds of placements against thousands of training poses per grasp)."""
    P, n = len(x), len(poses)
    out = np.zeros((P, n))
    limit = -np.log(cutoff)
    for p in range(P):
        qn = np.sqrt(x[p, 3] ** 2 + x[p, 4] ** 2 + x[p, 5] ** 2 + x[p, 6] ** 2)
        for j in range(n):
            dx = x[p, 0] - poses[j, 0]
            dy = x[p, 1] - poses[j, 1]
            dz = x[p, 2] - poses[j, 2]
            e = (dx * dx + dy * dy + dz * dz) / (2.0 * sigma_m**2)
            if e >= limit:
                continue
            dot = (
                x[p, 3] * poses[j, 3]
                + x[p, 4] * poses[j, 4]
                + x[p, 5] * poses[j, 5]
                + x[p, 6] * poses[j, 6]
            ) / qn
            ang = 2.0 * np.arccos(min(max(abs(dot), 0.0), 1.0))
            w = np.exp(-e - ang * ang / (2.0 * sigma_rad**2))
            if w > cutoff:
                out[p, j] = w
    return out


def poses_under_offsets(pose: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(H, 7) the wrist `pose` (7: x y z qx qy qz qw, the believed object frame) relative to
    the object as it stands off by each offset (H, 3: dx, dy, yaw about the vertical through
    its origin): T_h^-1 * pose."""
    off = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    p = np.asarray(pose, dtype=np.float64).reshape(7)
    r_h = Rotation.from_euler("z", off[:, 2:3])
    t = np.zeros((len(off), 3))
    t[:, :2] = off[:, :2]
    xyz = r_h.inv().apply(p[None, :3] - t)
    quat = (r_h.inv() * Rotation.from_quat(p[3:])).as_quat()
    return np.concatenate([xyz, quat], axis=1)


def pose_at_offset(pose: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(7,) the wrist `pose` (7, relative to the object) in the believed object frame when the
    object stands off it by `offset` (3: dx, dy, yaw about the vertical through its origin):
    T_h * pose, the inverse of `poses_under_offsets`."""
    o = np.asarray(offset, dtype=np.float64).reshape(3)
    p = np.asarray(pose, dtype=np.float64).reshape(7)
    r_h = Rotation.from_euler("z", o[2])
    xyz = r_h.apply(p[:3]) + np.array([o[0], o[1], 0.0])
    return np.concatenate([xyz, (r_h * Rotation.from_quat(p[3:])).as_quat()])


def placement_offsets(range_m: float, range_deg: float) -> np.ndarray:
    """(H, 3) the placements the planner averages a grasp's evidence over: the believed one,
    the 8 around it at +-`range_m` in x and y, and turned +-`range_deg` (none if both 0)."""
    if range_m <= 0 and range_deg <= 0:
        return np.zeros((0, 3))
    out = [(0.0, 0.0, 0.0)]
    if range_m > 0:
        out += [
            (dx * range_m, dy * range_m, 0.0)
            for dx in (-1, 0, 1)
            for dy in (-1, 0, 1)
            if (dx, dy) != (0, 0)
        ]
    if range_deg > 0:
        out += [(0.0, 0.0, np.deg2rad(s * range_deg)) for s in (-1, 1)]
    return np.asarray(out, dtype=np.float64)


def _offsets_key(offsets: np.ndarray | None) -> bytes:
    if offsets is None or len(offsets) == 0:
        return b""
    return np.ascontiguousarray(np.asarray(offsets, dtype=np.float64).reshape(-1, 3)).tobytes()


def softmax_belief(log_b: np.ndarray) -> np.ndarray:
    """p(y | history) from the summed log-likelihoods (a uniform prior)."""
    z = np.exp(log_b - np.max(log_b))
    return z / z.sum()


@dataclass
class GraspLikelihood:
    """Every training grasp's pose, class, sensor mask and finger closure."""

    poses: np.ndarray  # (G, 7) x y z qx qy qz qw, unit quaternions
    labels: np.ndarray  # (G,) int64 class index
    masks: np.ndarray  # (G, W) uint64: W words per grasp
    closure: np.ndarray  # (G, 3) float64
    n_classes: int
    # training_log_likelihoods per kernel widths (derived, so not compared or shown)
    _tables: dict[tuple[LikelihoodParams, bytes], np.ndarray] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )
    # Where those tables are kept between processes (the model's directory, set by
    # `load_model`): a daemon then starts in a second, not in the table's 18 s. None: memory.
    table_dir: Path | None = field(default=None, init=False, repr=False, compare=False)

    @classmethod
    def fit(cls, per_object: list[tuple[np.ndarray, list[Grasp]]]) -> GraspLikelihood:
        """From each class's (poses (G, 7), grasps), classes in order."""
        poses, labels, masks, closure = [], [], [], []
        all_ids = [g.sensor_ids for _, gs in per_object for g in gs]
        words = mask_words(np.concatenate(all_ids)) if all_ids else 1
        for y, (p, grasps) in enumerate(per_object):
            p = np.asarray(p, dtype=np.float64).reshape(-1, 7)
            if len(p) != len(grasps):
                raise DataError(f"class {y}: {len(p)} poses for {len(grasps)} grasps")
            poses.append(p)
            labels.append(np.full(len(p), y, dtype=np.int64))
            masks.append(
                np.array(
                    [sensor_mask(g.sensor_ids, words) for g in grasps], dtype=np.uint64
                ).reshape(-1, words)
            )
            closure.append(np.array([finger_closure(g) for g in grasps]).reshape(-1, 3))
        P = np.concatenate(poses)
        P[:, 3:] /= np.linalg.norm(P[:, 3:], axis=1, keepdims=True)
        return cls(
            P,
            np.concatenate(labels),
            np.concatenate(masks),
            np.concatenate(closure),
            len(per_object),
        )

    def log_likelihood(
        self,
        grasp: Grasp,
        pose: Pose,
        params: LikelihoodParams,
        ignore: np.ndarray | None = None,
        finger_sensors: int = 0,
    ) -> np.ndarray:
        """log p(grasp | y, pose) for every class y (K,). `ignore`: sensor ids left out of
        the comparison on both sides (masked this recognition: what they say is not known);
        `finger_sensors`: the hand's sensors per finger (`FAMILY_FINGER_SENSORS`), so a
        finger whose training stop was on a masked sensor may close past it (0: not known)."""
        x = np.concatenate([np.asarray(pose.xyz, float), np.asarray(pose.quat, float)])
        mask = self._mask(grasp.sensor_ids)[None]
        keep = ~self._mask(ignore) if ignore is not None and len(ignore) else None
        censor = finger_censor(ignore, finger_sensors, self.words)
        return self._log_likelihood_many(
            mask, finger_closure(grasp)[None], x, params, keep, censor
        )[0]

    @property
    def words(self) -> int:
        return int(self.masks.shape[1])

    def _mask(self, sensor_ids: np.ndarray) -> np.ndarray:
        """(W,) mask of these ids; ids past the training grasps' words are dropped: no
        training grasp saw them, so they say nothing here."""
        ids = np.asarray(sensor_ids, dtype=np.int64).reshape(-1)
        return sensor_mask(ids[ids < 64 * self.words], self.words)

    def log_likelihood_at_poses(
        self,
        grasp: Grasp,
        poses: np.ndarray,
        params: LikelihoodParams,
        ignore: np.ndarray | None = None,
        finger_sensors: int = 0,
        class_groups: np.ndarray | None = None,
    ) -> np.ndarray:
        """(P, K) log p(grasp | y, x) of one grasp as if made at each of `poses` (P, 7), the
        same as `log_likelihood` at each; the training grasps further from all of them than
        the weight cutoff are left out first (the poses are close together: one placement's
        hypotheses). With `class_groups` (K,), `poses` is (G, P, 7) and class y is weighed at
        poses[class_groups[y]] (classes that turn about another point stand elsewhere under
        the same hypothesis); the sensors are compared once for all."""
        G = 1 if class_groups is None else int(np.max(class_groups)) + 1
        x = np.asarray(poses, dtype=np.float64).reshape(G, -1, 7)
        groups = np.zeros(self.n_classes, dtype=np.int64) if class_groups is None else class_groups
        s_m, s_r = params.pose_sigma_m, np.deg2rad(params.pose_sigma_deg)
        reach = s_m * np.sqrt(2.0 * np.log(1.0 / _WEIGHT_CUTOFF))  # translation alone
        flat = x.reshape(-1, 7)
        centre = flat[:, :3].mean(axis=0)
        spread = float(np.max(np.linalg.norm(flat[:, :3] - centre, axis=1)))
        cand = np.flatnonzero(
            np.sum((self.poses[:, :3] - centre) ** 2, axis=1) <= (spread + reach) ** 2
        )
        P, K = x.shape[1], self.n_classes
        if cand.size == 0:
            return np.full((P, K), np.log(1.0 + params.floor))
        keep = ~self._mask(ignore) if ignore is not None and len(ignore) else None
        k = self._similarity(
            cand,
            self._mask(grasp.sensor_ids)[None],
            finger_closure(grasp)[None],
            params,
            keep,
            finger_censor(ignore, finger_sensors, self.words),
        )
        if G == 1:
            w = cut_pose_weights_at(self.poses[cand], x[0], s_m, s_r, _WEIGHT_CUTOFF)  # (P, cand)
            return self._class_log_average(w, k, cand, params.floor)
        lik, has = np.zeros((P, K)), np.zeros((P, K), dtype=bool)
        for g in range(G):  # each group's poses against its own classes' training grasps only
            cols = groups == g
            at = np.flatnonzero(cols[self.labels[cand]])
            if not at.size:
                continue
            w = cut_pose_weights_at(self.poses[cand[at]], x[g], s_m, s_r, _WEIGHT_CUTOFF)
            lg, hg = self._class_means(w, k[:, at], cand[at])
            lik[:, cols], has[:, cols] = lg[:, cols], hg[:, cols]
        return self._log_with_no_say(lik, has, params.floor)

    def training_log_likelihoods(
        self, params: LikelihoodParams, offsets: np.ndarray | None = None
    ) -> np.ndarray:
        """(G, K) log p(g_j | y, x_j) of every training grasp j at its own pose: what a
        simulated observation of grasp j tells the planner's belief. `offsets` (H, 3: dx, dy
        in metres, yaw in radians, the object's placement off the believed one): instead the
        log of the mean over them of p(g_j | y, T_h^-1 x_j), what grasp j tells when the
        object may stand at any of them. Cached per (`params`, `offsets`), in memory and
        beside the model."""
        off = _offsets_key(offsets)
        key = (params, off)
        cache = self._tables
        if key not in cache:
            out = self._stored_table(params, off)
            if out is None:
                out = self._table(params, off)
                self._store_table(params, out, off)
            out.flags.writeable = False
            cache[key] = out
        return cache[key]

    def table_file(self, params: LikelihoodParams, offsets: bytes = b"") -> Path | None:
        """The stored table's file for `params` (and placement offsets, as bytes): named by a
        digest of them and of every training grasp, so a retrained or edited model never
        reads another's table."""
        if self.table_dir is None:
            return None
        h = hashlib.blake2b(repr(params).encode() + offsets, digest_size=10)
        for a in (self.poses, self.labels, self.masks, self.closure):
            h.update(np.ascontiguousarray(a).tobytes())
        return Path(self.table_dir) / f"likelihood_table-{h.hexdigest()}.npy"

    def _stored_table(self, params: LikelihoodParams, offsets: bytes = b"") -> np.ndarray | None:
        path = self.table_file(params, offsets)
        if path is None or not path.is_file():
            return None
        try:
            out = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            log.warning("%s: unreadable, computing it again (%s)", path, e)
            return None
        if out.shape != (len(self.labels), self.n_classes) or out.dtype != np.float64:
            log.warning("%s: of shape %s, computing it again", path, out.shape)
            return None
        return out

    def _store_table(
        self, params: LikelihoodParams, table: np.ndarray, offsets: bytes = b""
    ) -> None:
        path = self.table_file(params, offsets)
        if path is None:
            return
        buf = io.BytesIO()
        np.save(buf, table, allow_pickle=False)
        try:
            atomic_write_bytes(path, buf.getvalue())
        except OSError as e:  # a read-only model directory: computed again next time
            log.info("could not keep the likelihood table in %s (%s)", path.parent, e)

    def _table(self, params: LikelihoodParams, offsets: bytes = b"") -> np.ndarray:
        """(G, K) computed: each distinct training pose once, all its grasps together (at
        every placement offset, averaged in probability)."""
        off = np.frombuffer(offsets, dtype=np.float64).reshape(-1, 3)
        out = np.empty((len(self.labels), self.n_classes))
        _, first, at = np.unique(
            np.round(self.poses, 9), axis=0, return_index=True, return_inverse=True
        )
        at = at.reshape(-1)
        order = np.argsort(at, kind="stable")
        bounds = np.searchsorted(at[order], np.arange(len(first) + 1))
        for u in range(len(first)):
            rows = order[bounds[u] : bounds[u + 1]]
            x = self.poses[first[u]]
            if not len(off):
                out[rows] = self._log_likelihood_many(
                    self.masks[rows], self.closure[rows], x, params
                )
                continue
            per = np.stack(
                [
                    self._log_likelihood_many(self.masks[rows], self.closure[rows], xh, params)
                    for xh in poses_under_offsets(x, off)
                ]
            )
            m = per.max(axis=0)
            out[rows] = m + np.log(np.mean(np.exp(per - m), axis=0))
        return out

    def _log_likelihood_many(
        self,
        masks: np.ndarray,
        closure: np.ndarray,
        x: np.ndarray,
        params: LikelihoodParams,
        keep: np.ndarray | None = None,
        censor: np.ndarray | None = None,
    ) -> np.ndarray:
        """(n, K) log-likelihoods of n grasps (masks (n, W), closure (n, 3)) all made at `x`;
        `keep`: the sensor bits compared (all if None); `censor`: `finger_censor`'s words."""
        w = pose_weights(self.poses, x, params.pose_sigma_m, np.deg2rad(params.pose_sigma_deg))
        near = np.flatnonzero(w > _WEIGHT_CUTOFF)
        k = self._similarity(near, masks, closure, params, keep, censor)
        return self._class_log_average(w[near][None], k, near, params.floor)

    def _similarity(
        self,
        rows: np.ndarray,
        masks: np.ndarray,
        closure: np.ndarray,
        params: LikelihoodParams,
        keep: np.ndarray | None,
        censor: np.ndarray | None = None,
    ) -> np.ndarray:
        """(n, R) kernel k between n grasps (masks (n, W), closure (n, 3)) and the training
        grasps `rows`: Hamming distance of the sensor bits (`keep`: those compared) and the
        fingers' closure (`censor`: `finger_censor`'s words, or None)."""
        trained = self.masks[rows]
        diff = trained[None, :, :] ^ masks[:, None, :]
        if keep is not None:
            diff = diff & keep
        ham = np.bitwise_count(diff).sum(axis=-1).astype(float)
        censored = None if censor is None else censored_fingers(trained, censor)
        return grasp_kernel(ham, closure_gaps(self.closure[rows], closure, censored), params)

    def _class_log_average(
        self, w: np.ndarray, k: np.ndarray, rows: np.ndarray, floor: float
    ) -> np.ndarray:
        """log of each class's pose-weighted mean kernel, p(g | y, x) = sum w k / sum w over
        y's grasps among `rows`: (P, R) weights of P poses and (n, R) kernels of n grasps, one
        of P and n being 1; (max(P, n), K). A class with no weight at a pose gets the mean of
        those that have (no say); nowhere near any: 1."""
        return self._log_with_no_say(*self._class_means(w, k, rows), floor)

    def _class_means(
        self, w: np.ndarray, k: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each class's pose-weighted mean kernel (`_class_log_average`) and whether it has
        any weight there, both (max(P, n), K)."""
        num = self._per_class_sums(w * k, rows)
        den = self._per_class_sums(w, rows)  # (P, K)
        has = np.broadcast_to(den > 0, num.shape)
        return np.where(has, num / np.where(den > 0, den, 1.0), 0.0), has

    @staticmethod
    def _log_with_no_say(lik: np.ndarray, has: np.ndarray, floor: float) -> np.ndarray:
        """log(`lik` + floor), a class without weight at a pose (`has` False) given the mean
        of those with; nowhere near any: 1."""
        n_has = has.sum(axis=1, keepdims=True)
        mean = np.where(n_has > 0, lik.sum(axis=1, keepdims=True) / np.maximum(n_has, 1), 1.0)
        return np.log(np.where(has, lik, mean) + floor)

    def _per_class_sums(self, a: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(n, K) the columns of `a` (n, R; column r is training grasp rows[r]) summed per
        class: a segment sum over the classes' runs (the training grasps are stored class by
        class), not a product with a one-hot matrix K times the size."""
        labels = self.labels[rows]
        out = np.zeros((a.shape[0], self.n_classes))
        if not len(rows):
            return out
        if np.any(np.diff(labels) < 0):  # not class by class: put them so
            order = np.argsort(labels, kind="stable")
            labels, a = labels[order], a[:, order]
        present, starts = np.unique(labels, return_index=True)
        out[:, present] = np.add.reduceat(a, starts, axis=1)
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {
            "poses": self.poses,
            "labels": self.labels,
            "masks": self.masks,
            "closure": self.closure,
            "n_classes": np.array([self.n_classes], dtype=np.int64),
        }

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> GraspLikelihood:
        try:
            out = cls(
                np.asarray(d["poses"], dtype=np.float64),
                np.asarray(d["labels"], dtype=np.int64),
                _as_words(np.asarray(d["masks"], dtype=np.uint64)),
                np.asarray(d["closure"], dtype=np.float64),
                int(np.asarray(d["n_classes"]).reshape(-1)[0]),
            )
        except KeyError as e:
            raise DataError(f"grasp likelihood arrays: {e} missing") from None
        except (IndexError, TypeError, ValueError) as e:
            raise DataError(f"grasp likelihood arrays: malformed ({e})") from None
        G = len(out.labels)
        if out.poses.shape != (G, 7) or len(out.masks) != G or out.closure.shape != (G, 3):
            raise DataError("grasp likelihood arrays differ in length")
        if G and (out.labels.min() < 0 or out.labels.max() >= out.n_classes):
            raise DataError("grasp likelihood labels out of range")
        return out


def _as_words(masks: np.ndarray) -> np.ndarray:
    """(G, W) masks; a model saved with one word per grasp stored them as (G,)."""
    return masks.reshape(-1, 1) if masks.ndim == 1 else masks
