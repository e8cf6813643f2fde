"""Evaluation against the paper: every (object, policy, seed) recognised in the twin, in
parallel processes, summarised as the paper's tables (moves until correct) and figures.

Moves are counted in grasps, the first random grasp included; `None` means never."""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import multiprocessing as mp
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import binomtest, bootstrap

from activetouch.config import SIM_ERROR_SETTINGS, Config, SimConfig
from activetouch.errors import ConfigError
from activetouch.objects.library import ObjectLibrary
from activetouch.pipelines.executors import check_executor, exit_with_parent, ray_map
from activetouch.pipelines.journal import RunJournal
from activetouch.recognition.distances import inner_product_distance
from activetouch.recognition.faults import draw_faulty_sensors

STABLE_RUN = 3  # "3-in-a-row correct", as in the paper's real-robot table
SENSOR_FAULT_KEYS = {
    "noise": "fault_noise_std",
    "dead": "fault_dead",
    "stuck": "fault_stuck",
    "spurious": "fault_spurious",
}
CALIBRATION_DRIFT_KEYS = {
    "fingers": "fault_finger_offset_rad",
    "sensors": "fault_sensor_drift",
}


def robot_errors(sim: SimConfig) -> dict[str, float]:
    """The error settings that are on (empty: the nominal twin)."""
    return {k: getattr(sim, k) for k in SIM_ERROR_SETTINGS if getattr(sim, k)}


def _key_values(flag: str, text: str, keys: dict[str, str], example: str) -> list[str]:
    """`key=value,...` as `sim.<setting>=value` overrides; ConfigError naming `flag`."""
    out = []
    for item in text.split(","):
        key, _, value = item.partition("=")
        key = key.strip()
        if key not in keys or not value.strip():
            raise ConfigError(
                f"{flag}: expected e.g. {example} (keys {', '.join(keys)}), got {item!r}"
            )
        out.append(f"sim.{keys[key]}={value.strip()}")
    return out


def error_overrides(
    placement: str | None,
    faults: str | None,
    nudge: str | None = None,
    drift: str | None = None,
) -> list[str]:
    """`--set` overrides from eval's flags: `--placement-error M[,DEG]` (metres, degrees),
    `--sensor-faults noise=S,dead=N,stuck=N,spurious=P`, `--nudge M` (metres) and
    `--calibration-drift fingers=RAD,sensors=U`."""
    out: list[str] = []
    if placement:
        parts = [p.strip() for p in placement.split(",")]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            vals = []
        if len(vals) not in (1, 2) or any(not np.isfinite(v) or v < 0 for v in vals):
            raise ConfigError(
                f"--placement-error: expected METRES[,DEGREES] >= 0 (e.g. 0.02,15), got "
                f"{placement!r}"
            )
        out.append(f"sim.placement_error_m={vals[0]!r}")
        if len(vals) == 2:
            out.append(f"sim.placement_error_deg={vals[1]!r}")
    if faults:
        out += _key_values(
            "--sensor-faults", faults, SENSOR_FAULT_KEYS, "noise=5,dead=2,stuck=1,spurious=0.02"
        )
    if nudge:
        try:
            m = float(nudge)
        except ValueError:
            m = -1.0
        if not (np.isfinite(m) and 0 <= m <= 0.05):
            raise ConfigError(f"--nudge: expected METRES in 0..0.05 (e.g. 0.01), got {nudge!r}")
        out.append(f"sim.nudge_max_m={m!r}")
    if drift:
        out += _key_values(
            "--calibration-drift", drift, CALIBRATION_DRIFT_KEYS, "fingers=0.05,sensors=1"
        )
    return out


def parse_seeds(text: str) -> list[int]:
    """'0-9' or '0,3,5' or '2'."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part[1:]:
                lo, hi = part.split("-", 1) if not part.startswith("-") else ("", part)
                a, b = int(lo), int(hi)
                if b < a:
                    raise ValueError
                seeds.extend(range(a, b + 1))
            elif part:
                seeds.append(int(part))
    except ValueError:
        raise ConfigError(f"--seeds: expected e.g. 0-9 or 0,3,5, got {text!r}") from None
    if not seeds:
        raise ConfigError("--seeds: give at least one seed")
    return sorted(set(seeds))


def first_correct(labels: list[str], truth: str) -> int | None:
    for i, lab in enumerate(labels):
        if lab == truth:
            return i + 1
    return None


def robot_s_at(robot_s: list[float], move: int | None) -> float | None:
    """Robot seconds after grasp `move` (1-based); None for None or a run without times."""
    if move is None or move > len(robot_s):
        return None
    return float(robot_s[move - 1])


def first_stable_correct(labels: list[str], truth: str, run: int = STABLE_RUN) -> int | None:
    """Moves until the label has been correct `run` grasps in a row (counted at the last)."""
    streak = 0
    for i, lab in enumerate(labels):
        streak = streak + 1 if lab == truth else 0
        if streak >= run:
            return i + 1
    return None


@dataclass(frozen=True)
class Job:
    model_dir: str
    library_root: str
    object_name: str
    policy: str
    seed: int
    max_moves: int
    cfg: Config


_MODEL_CACHE: dict[str, Any] = {}


def run_job(job: Job) -> dict[str, Any]:
    """One recognition; returns the run record (JSON-able) plus arrays for the figures."""
    # deferred: loads numba
    from activetouch.model import load_model

    # deferred: loads numba
    from activetouch.session.local import recognize_in_twin

    model = _MODEL_CACHE.get(job.model_dir)
    if model is None:  # one load per worker process
        model = _MODEL_CACHE[job.model_dir] = load_model(job.model_dir)
    res = recognize_in_twin(
        model,
        ObjectLibrary(job.library_root),
        job.object_name,
        job.policy,
        job.seed,
        job.cfg,
        max_moves=job.max_moves,
    )
    errors: dict[str, Any] = {}
    if robot_errors(job.cfg.sim):
        # deferred: loads pybullet
        from activetouch.sim.twin import placement_error, sensor_faults

        # The same draws the twin made from this seed: what this run really had.
        err = placement_error(job.cfg.sim, job.seed)
        faulty = draw_faulty_sensors(sensor_faults(job.cfg.sim), job.seed)
        errors = {
            "placement_dx_m": err.dx,
            "placement_dy_m": err.dy,
            "placement_yaw_deg": float(np.degrees(err.yaw_rad)),
            "dead_sensors": faulty.dead.tolist(),
            "stuck_sensors": faulty.stuck.tolist(),
        }
    # Distance of the histogram after each grasp to the true class's training histogram.
    distances: list[float | None] = []
    counts = np.zeros(model.spec.n_bins)
    truth_idx = (
        model.class_names.index(job.object_name) if job.object_name in model.class_names else None
    )
    for xyz in res.contacts:
        counts = counts + model.spec.counts(model.triangles(xyz))
        ref = model.class_histograms
        if truth_idx is None or ref is None:
            distances.append(None)
        else:
            distances.append(float(inner_product_distance(counts, ref[truth_idx])))
    return {
        "object": job.object_name,
        "policy": job.policy,
        "seed": job.seed,
        "labels": res.labels,
        "moves_to_first_correct": first_correct(res.labels, job.object_name),
        "moves_to_stable_correct": first_stable_correct(res.labels, job.object_name),
        "final_correct": bool(res.labels) and res.labels[-1] == job.object_name,
        "final_label": res.label,
        "final_probability": res.probability,
        "moves": res.moves,
        "skipped": res.skipped,
        "stop_reason": res.stop_reason,
        "planning_s": res.planning_s,
        "search_s": res.search_s,
        "belief_s": res.belief_s,
        "elapsed_s": res.elapsed_s,
        # Robot time (session.py): moving, grasping, planning, their total, and the total
        # when the label was first right (None: never).
        "motion_s": res.motion_s,
        "grasp_s": res.grasp_s,
        "total_s": res.total_s,
        "robot_s_to_first_correct": robot_s_at(
            res.robot_s, first_correct(res.labels, job.object_name)
        ),
        "unreachable": res.unreachable,
        "distance_to_true": distances,
        "pose_ids": res.pose_ids,
        "mean_contacts": float(np.mean([len(c) for c in res.contacts])) if res.contacts else 0.0,
        "errors": errors,
        # Not in results.json (bulky); used for figures.
        "_contacts": [c.tolist() for c in res.contacts],
        "_counts": counts.tolist(),
    }


def job_key(job: Job) -> str:
    """A digest of everything a run's outcome depends on but the code: the model's and the
    object's files as they are now, the object, policy, seed, budget and every setting."""
    model = Path(job.model_dir) / "model.json"
    mesh = ObjectLibrary(job.library_root).get(job.object_name).visual_mesh

    def stamp(f: Path) -> tuple[str, int, int]:
        st = f.stat()
        return str(f.resolve()), st.st_mtime_ns, st.st_size

    ident = (stamp(model), stamp(mesh), job.object_name, job.policy, job.seed, job.max_moves)
    return hashlib.sha256(repr((*ident, job.cfg)).encode()).hexdigest()[:32]


def run_all(
    jobs: list[Job],
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    executor: str = "local",
    address: str | None = None,
    journal: RunJournal | None = None,
) -> list[dict[str, Any]]:
    """Every job's record, in the order of `jobs`. `executor`: "local" (this machine's
    processes, `workers` of them) or "ray" (`run_all_ray`). `journal`: each run is kept there
    as it finishes, and runs it already holds are not made again (a resumed evaluation)."""
    check_executor(executor, address)
    keys = [job_key(j) for j in jobs] if journal is not None else []
    out: list[dict[str, Any] | None] = (
        [journal.get(k) for k in keys] if journal is not None else [None] * len(jobs)
    )
    todo = [i for i, r in enumerate(out) if r is None]
    done = len(jobs) - len(todo)
    if progress and done:
        progress(done, len(jobs))

    def finished(i: int, record: dict[str, Any]) -> None:
        nonlocal done
        out[i] = record
        if journal is not None:
            journal.add(keys[i], record)
        done += 1
        if progress:
            progress(done, len(jobs))

    workers = max(1, min(workers or os.cpu_count() or 1, len(todo)))
    if not todo:
        pass
    elif executor == "ray":
        run_all_ray([jobs[i] for i in todo], address, workers, lambda k, r: finished(todo[k], r))
    elif workers == 1:
        for i in todo:
            finished(i, run_job(jobs[i]))
    else:
        ctx = mp.get_context("spawn")  # PyBullet and numba state do not survive fork()
        with cf.ProcessPoolExecutor(
            workers, mp_context=ctx, initializer=exit_with_parent, initargs=(os.getpid(),)
        ) as pool:
            futures = {pool.submit(run_job, jobs[i]): i for i in todo}
            try:
                for f in cf.as_completed(futures):
                    finished(futures[f], f.result())
            except BaseException:  # a failed run or Ctrl-C: the finished ones are kept
                pool.shutdown(wait=False, cancel_futures=True)
                raise
    return [r for r in out if r is not None]


def run_all_ray(
    jobs: list[Job],
    address: str | None,
    workers: int | None,
    finished: Callable[[int, dict[str, Any]], None],
) -> None:
    """`run_all` on Ray (executors.ray_map): one task per job, each worker keeping the model
    it loaded, as a local pool worker does; `finished(index, record)` as each comes back.
    `address`: a running cluster ("auto" on one of its nodes, "ray://head:10001"); None
    starts a Ray here with `workers` CPUs."""
    calls = [(j,) for j in jobs]
    for i, record in ray_map(run_job, calls, address, workers):
        finished(i, record)


def _median(values: list[int | None], budget: int) -> float | None:
    """Median moves counting `never` as beyond the budget; None if most runs never got there."""
    v = np.array([budget + 1 if x is None else x for x in values], dtype=float)
    m = float(np.median(v)) if len(v) else float("nan")
    return None if m > budget else m


def sign_test_p(wins: int, losses: int) -> float:
    """Two-sided exact sign test (ties dropped)."""
    n = wins + losses
    if n == 0:
        return 1.0
    return float(binomtest(min(wins, losses), n, 0.5).pvalue)


def bootstrap_ci(
    diffs: np.ndarray, rng: np.random.Generator, n_boot: int = 10_000, chunk: int = 500
) -> tuple[float, float]:
    """95 % percentile-bootstrap interval of the mean of `diffs` (scipy's, `chunk` resamples
    at a time so memory stays small for large evaluations); reproducible for a seeded `rng`.

    Percentile, not BCa: differences in moves are small integers, often all equal, where BCa
    is undefined (scipy warns and gives NaN)."""
    d = np.asarray(diffs, dtype=float)
    if d.size == 0:
        return float("nan"), float("nan")
    if np.all(d == d.flat[0]):
        # Every resample has this mean (scipy also refuses a single observation).
        return float(d.flat[0]), float(d.flat[0])
    res = bootstrap(
        (d.ravel(),),
        np.mean,
        n_resamples=n_boot,
        batch=chunk,
        vectorized=True,
        method="percentile",
        confidence_level=0.95,
        rng=rng,
    )
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def paired_stats(diffs: np.ndarray, rng: np.random.Generator) -> dict[str, Any]:
    """Paired differences (positive: the first of the pair needed fewer moves): their mean,
    95 % bootstrap interval, wins / ties / losses and sign-test p."""
    wins, losses = int((diffs > 0).sum()), int((diffs < 0).sum())
    return {
        "mean": float(diffs.mean()) if diffs.size else float("nan"),
        "ci95": bootstrap_ci(diffs, rng),
        "wins": wins,
        "ties": int((diffs == 0).sum()),
        "losses": losses,
        "sign_p": sign_test_p(wins, losses),
    }


def summarise(runs: list[dict[str, Any]], max_moves: int) -> dict[str, Any]:
    objects = list(dict.fromkeys(r["object"] for r in runs))
    policies = list(dict.fromkeys(r["policy"] for r in runs))
    table: dict[str, dict[str, Any]] = {}
    for o in objects:
        table[o] = {}
        for p in policies:
            rs = [r for r in runs if r["object"] == o and r["policy"] == p]
            fc = [r["moves_to_first_correct"] for r in rs]
            sc = [r["moves_to_stable_correct"] for r in rs]
            table[o][p] = {
                "runs": len(rs),
                "median_first_correct": _median(fc, max_moves),
                "median_stable_correct": _median(sc, max_moves),
                "ever_correct": sum(x is not None for x in fc),
                "final_correct": sum(r["final_correct"] for r in rs),
                "mean_moves": float(np.mean([r["moves"] for r in rs])) if rs else None,
            }
    per_policy: dict[str, Any] = {}
    for p in policies:
        rs = [r for r in runs if r["policy"] == p]
        fc = [r["moves_to_first_correct"] for r in rs]
        # Objects recognised at the end by the majority of seeds.
        majority = sum(table[o][p]["final_correct"] * 2 > table[o][p]["runs"] for o in objects)
        per_policy[p] = {
            "objects_final_correct_majority": int(majority),
            "final_correct_rate": float(np.mean([r["final_correct"] for r in rs])),
            "median_first_correct": _median(fc, max_moves),
            # 'never' counted as budget + 1 so policies are compared on the same runs.
            "mean_first_correct_capped": float(
                np.mean([max_moves + 1 if x is None else x for x in fc])
            ),
            "mean_planning_s": float(np.mean([r["planning_s"] for r in rs])),
            # Robot seconds to first correct, 'never' counted as the run's whole robot time
            # (a lower bound of what it would have taken), over the runs' never count.
            "mean_robot_s_to_first_correct": _mean_robot_s(rs),
            "mean_robot_s": float(np.mean([r.get("total_s", 0.0) for r in rs])),
            "never_correct": sum(x is None for x in fc),
            "mean_contacts": float(np.mean([r.get("mean_contacts", 0.0) for r in rs])),
        }
    paired: dict[str, Any] = {}
    if "tree" in policies:
        by_key = {(r["policy"], r["object"], r["seed"]): r for r in runs}
        for other in policies:
            if other == "tree":
                continue
            diffs, sdiffs = [], []
            for r in runs:
                if r["policy"] != "tree":
                    continue
                o = by_key[(other, r["object"], r["seed"])]
                diffs.append(moves_capped(o, max_moves) - moves_capped(r, max_moves))
                sdiffs.append(robot_s_capped(o) - robot_s_capped(r))
            d = np.asarray(diffs, dtype=float)
            # Fixed bootstrap seed: the same runs always give the same interval.
            st = paired_stats(d, np.random.default_rng(0))
            paired[f"tree_vs_{other}"] = {
                "mean_moves_saved": st["mean"] if d.size else None,
                "ci95": list(st["ci95"]) if d.size else None,
                "tree_fewer": st["wins"],
                "ties": st["ties"],
                "tree_more": st["losses"],
                "sign_p": st["sign_p"],
            }
            if any(r.get("total_s") for r in runs):  # runs that kept robot time
                sd = np.asarray(sdiffs, dtype=float)
                ss = paired_stats(sd, np.random.default_rng(0))
                paired[f"tree_vs_{other}"]["robot_s_saved"] = {
                    "mean": ss["mean"] if sd.size else None,
                    "ci95": list(ss["ci95"]) if sd.size else None,
                    "tree_faster": ss["wins"],
                    "tree_slower": ss["losses"],
                    "sign_p": ss["sign_p"],
                }
    return {
        "objects": objects,
        "policies": policies,
        "max_moves": max_moves,
        "table": table,
        "per_policy": per_policy,
        "paired_by_seed": paired,
    }


def moves_capped(run: dict[str, Any], budget: int) -> int:
    """Grasps to first correct; a run never correct counts as budget + 1."""
    m = run["moves_to_first_correct"]
    return budget + 1 if m is None else int(m)


def robot_s_capped(run: dict[str, Any]) -> float:
    """Robot seconds to first correct; a run never correct counts its whole robot time."""
    t = run.get("robot_s_to_first_correct")
    return float(run.get("total_s", 0.0) if t is None else t)


def _mean_robot_s(runs: list[dict[str, Any]]) -> float:
    return float(np.mean([robot_s_capped(r) for r in runs])) if runs else float("nan")


def public_runs(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if not k.startswith("_")} for r in runs]


def make_jobs(
    model_dir: Path,
    library_root: Path,
    objects: list[str],
    policies: list[str],
    seeds: list[int],
    max_moves: int,
    cfg: Config,
) -> list[Job]:
    return [
        Job(str(model_dir), str(library_root), o, p, s, max_moves, cfg)
        for o in objects
        for p in policies
        for s in seeds
    ]
