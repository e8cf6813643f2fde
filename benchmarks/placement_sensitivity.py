"""Which training poses still tell two look-alikes apart when the object stands a little off.

The pose belief weighs each real grasp against the training grasps at the wrist pose each of its
placement hypotheses implies. The hypotheses are `recognition.pose_step_m` (1 cm) and
`pose_step_deg` (7.5 deg) apart, so the object stands up to half a step off the nearest one, and
a training grasp is one sample of what the hand feels there. Where a finger catches a lip at
the trained placement and misses it 3 mm away, that one sample is a coin toss that the belief
reads as a verdict.

For each pair of classes `A:B` of a trained model, every training pose both share is grasped
again `--draws` times in the twin with the object off by a uniform draw within +-`--jitter-m`
and +-`--jitter-deg` (the wrist moved instead: the same relative pose), and the script counts
the shared poses where the two classes' grasps are unlike (the grasp likelihood's kernel, its
sensor and closure widths, below `--threshold`): at the trained placement, and under the draws
(every grasp of one unlike every grasp of the other), and how many poses give each class the
same outcome under every draw.

    ACTIVETOUCH_HOME=DIR python benchmarks/placement_sensitivity.py \\
        h_bottle_lip_neck:h_bottle_long_neck h_bowl_foot:h_bowl_shallow [--draws 2] [--json F]

With `--meshes` no grasp is made: at every pose the planner can choose (the model's pooled
poses) the two meshes predict how far each finger closes (`planning/mesh_lookahead.py`, what
`planner.policy = "mesh"` plans on), at the trained placement and at a grid of placements
within the jitter (5 x 5 in x, y, three yaws), and the script counts the poses where the two
classes' predicted closures differ by more than `--threshold-rad` in some finger: at the
trained placement, and for every pair of placements of the grid.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from activetouch import paths
from activetouch.config import Config, load_config
from activetouch.errors import ActiveTouchError, UnreachableError
from activetouch.interfaces import Grasp, Pose
from activetouch.objects.library import ObjectLibrary
from activetouch.recognition.contacts import drop_support_contacts
from activetouch.recognition.dataset import Dataset
from activetouch.recognition.grasp_likelihood import (
    LikelihoodParams,
    finger_closure,
    grasp_kernel,
    pose_at_offset,
)
from activetouch.session.local import load_trained, model_path


def similarity(a: Grasp, b: Grasp, params: LikelihoodParams) -> float:
    """The grasp likelihood's kernel between two grasps: sensors in contact and finger closure."""
    ham = len(set(np.asarray(a.sensor_ids).tolist()) ^ set(np.asarray(b.sensor_ids).tolist()))
    d2 = float(np.sum((finger_closure(a) - finger_closure(b)) ** 2))
    return float(grasp_kernel(np.float64(ham), np.float64(d2), params))


def draws(n: int, jitter_m: float, jitter_deg: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) placements off the trained one: dx, dy (m), yaw (rad), uniform within the bounds."""
    return np.column_stack(
        [
            rng.uniform(-jitter_m, jitter_m, n),
            rng.uniform(-jitter_m, jitter_m, n),
            np.deg2rad(rng.uniform(-jitter_deg, jitter_deg, n)),
        ]
    )


def regrasp(
    library: ObjectLibrary, name: str, poses: np.ndarray, offsets: np.ndarray, cfg: Config
) -> list[list[Grasp | None]]:
    """Per pose, one twin grasp per offset (None where the wrist cannot get there)."""
    # deferred: loads pybullet
    from activetouch.sim.twin import open_twin

    out: list[list[Grasp | None]] = []
    spec = library.get(name)
    with open_twin(spec, cfg.sim, seed=cfg.sim.seed, workcell=cfg.workcell, hand=cfg.hand) as tw:
        for i, p in enumerate(poses):
            row: list[Grasp | None] = []
            for off in offsets[i]:
                pose = Pose.from_array(pose_at_offset(p, off))
                tw.hand.open()
                try:
                    tw.wrist.move_to(pose)
                except UnreachableError:
                    row.append(None)
                    continue
                g = tw.hand.guarded_close()
                row.append(
                    drop_support_contacts(g, pose, tw.support_z, cfg.recognition.support_margin_m)
                )
                tw.hand.open()
            out.append(row)
    return out


def pair_counts(
    a: list[list[Grasp]], b: list[list[Grasp]], params: LikelihoodParams, threshold: float
) -> dict[str, int]:
    """Counts over shared poses, each given as [trained grasp, redrawn grasps...] per class."""
    unlike = lambda x, y: similarity(x, y, params) < threshold  # noqa: E731
    return {
        "poses": len(a),
        "differ_trained": sum(unlike(ga[0], gb[0]) for ga, gb in zip(a, b, strict=True)),
        "differ_under_draws": sum(
            all(unlike(x, y) for x in ga for y in gb) for ga, gb in zip(a, b, strict=True)
        ),
        "stable_a": sum(all(not unlike(ga[0], x) for x in ga[1:]) for ga in a),
        "stable_b": sum(all(not unlike(gb[0], x) for x in gb[1:]) for gb in b),
    }


def jitter_grid(jitter_m: float, jitter_deg: float) -> np.ndarray:
    """(75, 3) placements dx, dy (m), yaw (rad): 5 x 5 in x and y, three yaws; the trained
    placement (zero) first."""
    xy = np.linspace(-jitter_m, jitter_m, 5)
    yaw = np.deg2rad([-jitter_deg, 0.0, jitter_deg])
    g = np.stack(np.meshgrid(xy, xy, yaw, indexing="ij"), axis=-1).reshape(-1, 3)
    zero = np.all(g == 0.0, axis=1)
    return np.concatenate([g[zero], g[~zero]])


def mesh_closures(
    belief: Any, classes: list[int], poses: np.ndarray, placements: np.ndarray, preshape: float
) -> np.ndarray:
    """(C, P, O, 3) proximal angles (rad) at which each finger's first sensor site meets class
    `classes[c]` moved by `placements[o]` (about its pivot, as the belief moves it), the hand
    at training pose `poses[p]` (P, 7)."""
    # deferred: numba compiles the sweeps
    from activetouch.planning.mesh_lookahead import predicted_closures
    from activetouch.recognition.pose_belief import class_frames

    ids = np.asarray(classes, dtype=np.int64)
    frames = class_frames(placements, belief.pivots[ids]).reshape(-1, 3)  # class-major
    cls = np.repeat(ids, len(placements))
    angles = predicted_closures(belief, poses, preshape, np.zeros(3), cls, frames)
    return angles.reshape(len(poses), len(ids), len(placements), 3).transpose(1, 0, 2, 3)


def closure_counts(a: np.ndarray, b: np.ndarray, threshold_rad: float) -> dict[str, int]:
    """Poses where two classes' predicted closures (P, O, 3; placement 0 the trained one)
    differ by more than `threshold_rad` in some finger: at the trained placement, and for
    every pair of placements."""
    apart = np.abs(a[:, :, None, :] - b[:, None, :, :]).max(axis=-1)  # (P, O, O)
    return {
        "poses": len(a),
        "differ_trained": int((apart[:, 0, 0] > threshold_rad).sum()),
        "differ_under_draws": int((apart.min(axis=(1, 2)) > threshold_rad).sum()),
    }


def mesh_rows(
    pairs: list[list[str]], model: Any, library: ObjectLibrary, cfg: Config, args: Any
) -> list[dict[str, Any]]:
    # deferred: loads pybullet
    from activetouch.session.loop import pose_belief_of
    from activetouch.sim.twin import open_twin

    rc = dataclasses.replace(cfg.recognition, belief="pose")
    make = pose_belief_of(model, rc, library)
    om = model.observation
    poses = np.concatenate([om.pose_xyz, om.pose_quat], axis=1)
    placements = jitter_grid(args.jitter_m, args.jitter_deg)
    rows = []
    for names in pairs:
        with open_twin(library.get(names[0]), cfg.sim, seed=cfg.sim.seed) as tw:
            belief = make(tw.support_z)
        if belief is None:
            raise ActiveTouchError("--meshes needs the pose belief: every class's mesh")
        ids = [list(model.class_names).index(n) for n in names]
        a, b = mesh_closures(belief, ids, poses, placements, cfg.grid.preshape)
        row = {"a": names[0], "b": names[1], **closure_counts(a, b, args.threshold_rad)}
        rows.append(row)
        print(
            f"{names[0]} vs {names[1]} (meshes): {row['poses']} poses; predicted closures "
            f"differ by more than {args.threshold_rad:g} rad at the trained placement "
            f"{row['differ_trained']}, for every pair of placements within +-"
            f"{args.jitter_m * 1e3:g} mm / +-{args.jitter_deg:g} deg {row['differ_under_draws']}",
            flush=True,
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs", nargs="+", help="class pairs A:B")
    ap.add_argument("--draws", type=int, default=2)
    ap.add_argument("--jitter-m", type=float, default=0.005)
    ap.add_argument("--jitter-deg", type=float, default=3.75)
    ap.add_argument("--threshold", type=float, default=0.3)
    ap.add_argument("--meshes", action="store_true", help="predicted closures, no grasps")
    ap.add_argument("--threshold-rad", type=float, default=0.08, help="with --meshes")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-poses", type=int, default=0, help="the first N shared poses (0: all)")
    ap.add_argument("--model")
    ap.add_argument("--data")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    root = paths.data_dir(args.data)
    cfg = load_config(None, [])
    model_dir = model_path(root, args.model, cfg.hand.family)
    model = load_trained(model_dir)
    params = LikelihoodParams.from_config(cfg.recognition)
    dataset = Dataset.open(str(model.meta["dataset"]))
    library = ObjectLibrary(paths.objects_dir(root))
    rows: list[dict[str, Any]] = []
    pairs = [pair.split(":") for pair in args.pairs]
    for pair, names in zip(args.pairs, pairs, strict=True):
        bad = [n for n in names if n not in model.class_names]
        if len(names) != 2 or bad:
            ap.error(f"{pair!r}: give two of the model's classes as A:B (unknown: {bad})")
    if args.meshes:
        rows = mesh_rows(pairs, model, library, cfg, args)
    for names in [] if args.meshes else pairs:
        trained = [dataset.read(n) for n in names]
        shared = sorted(set(trained[0].pose_ids.tolist()) & set(trained[1].pose_ids.tolist()))
        if args.max_poses > 0:
            shared = shared[: args.max_poses]
        rng = np.random.default_rng(args.seed)
        offsets = draws(len(shared) * args.draws, args.jitter_m, args.jitter_deg, rng)
        offsets = offsets.reshape(len(shared), args.draws, 3)
        per_class = []
        for og in trained:
            at = {pid: i for i, pid in enumerate(og.pose_ids.tolist())}
            idx = [at[pid] for pid in shared]
            again = regrasp(library, og.name, og.poses[idx], offsets, cfg)
            per_class.append([[og.grasps[i], *g] for i, g in zip(idx, again, strict=True)])
        # Only poses every redraw reached, for both classes.
        keep = [
            k
            for k in range(len(shared))
            if all(g is not None for g in per_class[0][k] + per_class[1][k])
        ]
        a = [per_class[0][k] for k in keep]
        b = [per_class[1][k] for k in keep]
        row = {"a": names[0], "b": names[1], **pair_counts(a, b, params, args.threshold)}
        rows.append(row)
        print(
            f"{names[0]} vs {names[1]}: {row['poses']} shared poses; unlike at the trained "
            f"placement {row['differ_trained']}, under every draw {row['differ_under_draws']}; "
            f"the same outcome under every draw: {row['stable_a']} / {row['stable_b']}",
            flush=True,
        )
    if args.json:
        doc = {"argv": sys.argv[1:], "rows": rows}
        Path(args.json).write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except ActiveTouchError as e:  # a missing model, dataset or object: said, not traced
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
