"""End to end through the real Baxter driver: the Baxter twin directly (``arm.type =
"twin-baxter"``) versus the driver on its byte-level emulator backed by the same twin
(``arm.type = "baxter"``, ``arm.emulate = "twin"``), on the same seeds.

    python benchmarks/baxter_end_to_end.py [--data DIR] [--model-objects cup,sphere,bottle]
        [--objects SUBSET] [--seeds 0-4] [--policy tree] [--workers 2]
        [--set session.max_moves=10 ...] [--json FILE]

Both run `deploy/baxter-twin.toml` with the twin's hand through `make_devices`, as
``activetouch serve --config deploy/baxter-twin.toml [--set arm.type=baxter --set
arm.emulate=twin]`` runs them (minus the daemon's Zenoh): per object one set of devices, per
seed ``sim/place`` then a recognition session. The driver's JointCommands and the emulator's
JointStates cross a loopback Zenoh link as ROS 1 bytes; the emulator follows in real time, so
an emulated recognition takes about its robot seconds of wall time. The twin runs twice
("twin again") to show how much it differs from itself: RRT-Connect (OMPL) is not repeatable
within a process, so a transit planned anew may take another path.

The model (`--model-objects`) is trained on the floating twin into DIR/baxter-end-to-end (a
coarse grid, `--grid-step-deg`, 40 as in tests/conftest.py) unless one with exactly these
objects is there.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from activetouch import paths
from activetouch.config import load_config

ROOT = Path(__file__).resolve().parents[1]
BAXTER_TOML = ROOT / "deploy" / "baxter-twin.toml"
SMALL_OBJECTS = ("cup", "sphere", "bottle")
VARIANTS: dict[str, tuple[str, ...]] = {
    "twin": (),
    "twin-again": (),
    "driver": ("arm.type=baxter", "arm.emulate=twin"),
}
DEFAULT_SET = ("session.max_moves=10", "session.max_skips=500")


def parse_seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b or a) + 1))
    return out


def ensure_model(root: Path, objects: list[str], step_deg: float) -> Path:
    """The model for `objects` in `root`, trained now (floating twin) if missing."""
    from activetouch.model import load_model
    from activetouch.objects.library import ObjectLibrary
    from activetouch.pipelines.training import collect, fit_and_save

    out = paths.default_model(root)
    lib = ObjectLibrary(paths.objects_dir(root))
    lib.ensure_builtins(objects)
    if (out / "model.json").is_file():
        if sorted(load_model(out).class_names) == sorted(objects):
            print(f"reusing the model at {out}", flush=True)
            return out
        raise SystemExit(f"{out} holds a model of other objects: pass another --data")
    cfg = load_config(None, [f"grid.step_deg={step_deg:g}"])
    ds = paths.default_dataset(root)
    t0 = time.perf_counter()
    collect(lib, ds, objects, cfg, workers=2)
    fit_and_save(ds, objects, cfg, out)
    print(f"trained {len(objects)} objects in {time.perf_counter() - t0:.0f} s", flush=True)
    return out


def run(
    variant: str, root: str, obj: str, seeds: list[int], policy: str, overrides: list[str]
) -> list[dict[str, Any]]:
    """One set of devices for `variant`; a recognition of `obj` per seed."""
    from activetouch.devices import make_devices
    from activetouch.errors import UnreachableError
    from activetouch.model import load_model
    from activetouch.session.loop import RecognitionSession, policy_for

    cfg = load_config(BAXTER_TOML, [*VARIANTS[variant], *overrides])
    model = load_model(paths.default_model(Path(root)))
    t0 = time.perf_counter()
    devices = make_devices(cfg, root)
    setup_s = time.perf_counter() - t0
    out = []
    try:
        wrist = devices.wrist
        emu = getattr(devices.arm, "emulator", None)
        # Why poses were skipped: each move the session tried and the motion layer refused
        # (no plan) or the arm could not finish (a contact in the twin).
        skips: list[str] = []
        move_to = wrist.move_to

        def recording_move_to(pose: Any) -> None:
            try:
                move_to(pose)
            except UnreachableError as e:
                skips.append(str(e))
                raise

        wrist.move_to = recording_move_to  # type: ignore[method-assign]
        for seed in seeds:
            t0 = time.perf_counter()
            devices.ctx.place(obj, seed)
            placement = devices.placement()
            wrist.set_placement(placement)
            policy_obj = policy_for(model, policy, cfg.planner, cfg.recognition)
            robot0, cmds0 = wrist.robot_seconds, len(emu.commands(cfg.arm.side)) if emu else 0
            session = RecognitionSession(
                devices.hand,
                wrist,
                model,
                policy_obj,
                cfg.session,
                np.random.default_rng(seed),
                support_z=placement.support_z(cfg.workcell.table_top_z),
            )
            skips.clear()
            res = session.run()
            row = {
                "seed": seed,
                "label": res.label,
                "probability": res.probability,
                "grasps": res.moves,
                "skipped": res.skipped,
                "stop_reason": res.stop_reason,
                "pose_ids": [int(p) for p in res.pose_ids],
                "contacts": [len(c) for c in res.contacts],
                "robot_s": wrist.robot_seconds - robot0,
                "total_robot_s": res.total_s,
                "wall_s": time.perf_counter() - t0,
                "setup_s": setup_s,
                "skip_reasons": list(skips),
                "blocked": sum("blocked" in r for r in skips),
            }
            if emu is not None:
                row["joint_commands"] = len(emu.commands(cfg.arm.side)) - cmds0
                row["malformed"] = emu.malformed
                follower = devices.arm.follower
                row["slowest_tick_s"] = follower.max_step_s  # so far in this process
            out.append(row)
            print(
                f"{variant:>10} {obj:>8} seed {seed}: {res.label} {res.moves} grasps "
                f"robot {row['robot_s']:.1f} s wall {row['wall_s']:.1f} s",
                flush=True,
            )
    finally:
        devices.close()
    return out


def job(args: tuple[str, str, str, list[int], str, list[str]]) -> tuple[str, str, list[dict]]:
    variant, root, obj, seeds, policy, overrides = args
    return variant, obj, run(variant, root, obj, seeds, policy, overrides)


def table(results: dict[str, dict[str, list[dict]]], objects: list[str]) -> str:
    twin = results["twin"]
    names = {
        "twin": "twin-baxter directly",
        "twin-again": "twin-baxter again (its own repeatability)",
        "driver": "baxter driver, twin-backed emulator",
    }
    lines = [
        "| arm | runs | correct | same label as the twin | same poses as the twin | "
        "grasps (mean) | skipped (mean) | moves ended by a contact | robot s (mean) | "
        "wall s (mean) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for variant, runs in results.items():
        rows = [(obj, i, r) for obj in objects for i, r in enumerate(runs[obj])]
        n = len(rows)
        correct = sum(r["label"] == obj for obj, _, r in rows)
        same = sum(r["label"] == twin[obj][i]["label"] for obj, i, r in rows)
        poses = sum(r["pose_ids"] == twin[obj][i]["pose_ids"] for obj, i, r in rows)
        lines.append(
            f"| {names[variant]} | {n} | {correct}/{n} | {same}/{n} | {poses}/{n} | "
            f"{np.mean([r['grasps'] for *_, r in rows]):.2f} | "
            f"{np.mean([r['skipped'] for *_, r in rows]):.1f} | "
            f"{sum(r['blocked'] for *_, r in rows)} | "
            f"{np.mean([r['robot_s'] for *_, r in rows]):.1f} | "
            f"{np.mean([r['wall_s'] for *_, r in rows]):.1f} |"
        )
    lines += [
        "",
        "| object | seed | twin: label, grasps, skipped, robot s, wall s | driver: label, grasps, "
        "skipped, robot s, wall s | same poses |",
        "|---|---|---|---|---|",
    ]
    drv = results["driver"]
    for obj in objects:
        for a, b in zip(twin[obj], drv[obj], strict=True):
            lines.append(
                f"| {obj} | {a['seed']} | {a['label']}, {a['grasps']}, {a['skipped']}, "
                f"{a['robot_s']:.1f}, {a['wall_s']:.1f} | {b['label']}, {b['grasps']}, "
                f"{b['skipped']}, {b['robot_s']:.1f}, "
                f"{b['wall_s']:.1f} | {'yes' if a['pose_ids'] == b['pose_ids'] else 'no'} |"
            )
    lines += ["", "Why moves were refused or ended (runs with more than 4, by first 60 chars):", ""]
    many = False
    for variant, runs in results.items():
        for obj in objects:
            for r in runs[obj]:
                if len(r["skip_reasons"]) > 4:
                    many = True
                    kinds = Counter(x[:60] for x in r["skip_reasons"]).most_common(3)
                    text = "; ".join(f"{n}x {k!r}" for k, n in kinds)
                    lines.append(f"- {variant}, {obj}, seed {r['seed']}: {text}")
    if not many:
        lines.append("- none")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", default=None, help="data directory (a subfolder holds the model)")
    p.add_argument("--model-objects", default=",".join(SMALL_OBJECTS), help="train on these")
    p.add_argument("--objects", default=None, help="recognise these (default: the model's)")
    p.add_argument("--seeds", default="0-4")
    p.add_argument("--policy", default="tree")
    p.add_argument("--grid-step-deg", type=float, default=40.0, help="training grid (if trained)")
    p.add_argument("--workers", type=int, default=2)
    what = f"config override for every run (default: {' '.join(DEFAULT_SET)})"
    p.add_argument("--set", dest="overrides", action="append", default=None, help=what)
    p.add_argument("--json", default=None, help="write every run here")
    a = p.parse_args(argv)
    root = paths.data_dir(a.data) / "baxter-end-to-end"
    trained = [o for o in a.model_objects.split(",") if o]
    objects = [o for o in (a.objects or a.model_objects).split(",") if o]
    seeds = parse_seeds(a.seeds)
    overrides = list(DEFAULT_SET if a.overrides is None else a.overrides)
    ensure_model(root, trained, a.grid_step_deg)
    # The slow driver jobs first, so the twin's fill the gaps.
    order = ("driver", "twin", "twin-again")
    jobs = [(v, str(root), o, seeds, a.policy, overrides) for v in order for o in objects]
    results: dict[str, dict[str, list[dict]]] = {}
    t0 = time.perf_counter()
    # spawn: workers start PyBullet, Zenoh and threads of their own; nothing forked mid-flight.
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=a.workers, mp_context=ctx) as pool:
        for variant, obj, rows in pool.map(job, jobs):
            results.setdefault(variant, {})[obj] = rows
    print(
        f"\n{len(objects)} objects x {len(seeds)} seeds x {len(VARIANTS)} variants, "
        f"{a.workers} workers, {time.perf_counter() - t0:.0f} s\n"
    )
    results = {k: results[k] for k in VARIANTS}
    print(f"$ python benchmarks/baxter_end_to_end.py {' '.join(sys.argv[1:])}\n")
    print(table(results, objects))
    if a.json:
        Path(a.json).write_text(json.dumps({"seeds": seeds, "results": results}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
