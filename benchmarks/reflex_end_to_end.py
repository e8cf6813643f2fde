"""End to end through the real ReFlex TakkTile driver: the twin hand directly versus the driver
on its byte-level emulator backed by the same twin world, on the same seeds.

    python benchmarks/reflex_end_to_end.py [--data DIR] [--seeds 0-9] [--loss 0 0.05]
        [--objects cup,teapot,...] [--policy tree] [--workers 2] [--stream-timeout-s 0.2]
        [--json FILE]

Trains the paper's 7 simulated objects into DIR (default: $ACTIVETOUCH_HOME or the user data
directory) unless a model with exactly those objects is there already. Then, per object and
seed: one recognition with the twin's own hand (`recognize_in_twin`), and one through
`make_devices` with ``hand.type = "reflex-takktile"``, ``hand.emulate = "twin"`` (the driver
decodes UDP state packets from an in-process emulator whose fingers and pads are the twin's,
in the world the floating arm moves), once per packet-loss rate. Prints the table
(docs/drivers.md holds the last one) and every run whose label differs, with where the two
runs first parted.

Driver runs are paced by the 40 Hz state stream, not by the CPU, so objects run in parallel
processes (`--workers`); times per grasp are wall-clock seconds of the whole session (arm
moves, planning, open, preshape, close) divided by its grasps.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from activetouch import paths
from activetouch.config import Config, load_config
from activetouch.objects.library import PAPER_SIM_OBJECTS


def parse_seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b or a) + 1))
    return out


def ensure_model(root: Path, objects: list[str], cfg: Config) -> Path:
    """The model for `objects` in `root`, trained now if it is missing or has other classes."""
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
    ds = paths.default_dataset(root)
    t0 = time.perf_counter()
    collect(lib, ds, objects, cfg, workers=2)
    fit_and_save(ds, objects, cfg, out)
    print(f"trained {len(objects)} objects in {time.perf_counter() - t0:.0f} s", flush=True)
    return out


FAILED: dict[str, Any] = {
    "label": "",
    "grasps": 0,
    "elapsed_s": 0.0,
    "pose_ids": [],
    "contacts": [],
    "stop_reason": "stream lost",
}


def summarise(res: Any, n_contacts: list[int]) -> dict[str, Any]:
    return {
        "label": res.label,
        "grasps": res.moves,
        "elapsed_s": res.elapsed_s,
        "pose_ids": [int(p) for p in res.pose_ids],
        "contacts": n_contacts,
        "stop_reason": res.stop_reason,
    }


def run_direct(
    root: str, obj: str, seeds: list[int], policy: str, overrides: tuple[str, ...] = ()
) -> list[dict[str, Any]]:
    """The twin hand closing itself (as `activetouch recognize` / `eval` run it)."""
    from activetouch.model import load_model
    from activetouch.objects.library import ObjectLibrary
    from activetouch.session.local import recognize_in_twin

    cfg = load_config(None, list(overrides))
    model = load_model(paths.default_model(Path(root)))
    lib = ObjectLibrary(paths.objects_dir(Path(root)))
    out = []
    for seed in seeds:
        res = recognize_in_twin(model, lib, obj, policy, seed, cfg)
        out.append(summarise(res, [len(c) for c in res.contacts]))
    return out


def run_driver(
    root: str, obj: str, seeds: list[int], policy: str, loss: float, timeout: float
) -> list[dict[str, Any]]:
    """The TakkTile driver on its twin-backed emulator, through the device layer, as `serve
    --set hand.type=reflex-takktile --set hand.emulate=twin` runs it (minus Zenoh)."""
    from activetouch.devices import make_devices
    from activetouch.drivers.reflex.common import StreamLostError
    from activetouch.model import load_model
    from activetouch.session.loop import RecognitionSession, policy_for
    from activetouch.sim.devices import twin_rig

    cfg = load_config(
        None,
        [
            "hand.type=reflex-takktile",
            "hand.emulate=twin",
            f"hand.emulate_loss={loss}",
            f"hand.stream_timeout_s={timeout}",
        ],
    )
    model = load_model(paths.default_model(Path(root)))
    devices = make_devices(cfg, root)
    out = []
    try:
        rig = twin_rig(devices.ctx)  # the world the arm moves in and the emulator reads
        for seed in seeds:
            devices.ctx.place(obj, seed)
            devices.wrist.set_placement(devices.placement())
            policy_obj = policy_for(model, policy, cfg.planner, cfg.recognition)
            before = devices.hand.stats()
            session = RecognitionSession(
                devices.hand,
                devices.wrist,
                model,
                policy_obj,
                cfg.session,
                np.random.default_rng(seed),
                support_z=rig.world.support_z,
            )
            try:
                res = session.run()
            except StreamLostError as e:
                # The state stream stopped for longer than hand.stream_timeout_s mid-command
                # (on a loaded machine the emulator thread can starve): the run fails, as it
                # would on the robot. Counted; the next run waits for the stream to return.
                out.append({**FAILED, "error": str(e), "packets": {}})
                continue
            row = summarise(res, [len(c) for c in res.contacts])
            after = devices.hand.stats()
            row["packets"] = {k: after.get(k, 0) - before.get(k, 0) for k in after}
            out.append(row)
    finally:
        devices.close()
    return out


def job(
    args: tuple[str, str, str, list[int], str, float, float],
) -> tuple[str, str, list[dict]]:
    kind, root, obj, seeds, policy, loss, timeout = args
    if kind == "direct":
        return kind, obj, run_direct(root, obj, seeds, policy)
    if kind == "direct-redraw":
        # The same twin and seeds, the sensor noise drawn from a stream instead of from the
        # pose: how often labels differ from noise alone (the driver's pads are read from
        # the twin's stream too, so its runs cannot repeat the twin's noise draws).
        return kind, obj, run_direct(root, obj, seeds, policy, ("sim.noise_mode=stream",))
    return f"driver@{loss:g}", obj, run_driver(root, obj, seeds, policy, loss, timeout)


def first_divergence(a: dict, b: dict) -> str:
    for i, (pa, pb) in enumerate(zip(a["pose_ids"], b["pose_ids"], strict=False)):
        ca, cb = a["contacts"][i], b["contacts"][i]
        if pa != pb:
            return f"grasp {i + 1}: different poses ({pa} vs {pb})"
        if ca != cb:
            return f"grasp {i + 1} (pose {pa}): {ca} vs {cb} contacts"
    return "same poses and contact counts; lengths differ"


def table(results: dict[str, dict[str, list[dict]]], objects: list[str], seeds: list[int]) -> str:
    direct = results["direct"]
    lines = [
        "| hand | runs | correct | same label as the twin | grasps (mean) | "
        "same first grasp's contact count | s per grasp (mean) | runs failed: stream lost |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for variant, runs in results.items():
        n = correct = same = same_first = failed = 0
        grasps: list[int] = []
        per_grasp: list[float] = []
        for obj in objects:
            for i, r in enumerate(runs[obj]):
                d = direct[obj][i]
                n += 1
                if r.get("error"):
                    failed += 1  # counted as a different label, and not in the means
                    continue
                correct += r["label"] == obj
                same += r["label"] == d["label"]
                same_first += bool(r["contacts"][:1] == d["contacts"][:1])
                grasps.append(r["grasps"])
                per_grasp.append(r["elapsed_s"] / max(1, r["grasps"]))
        if variant == "direct":
            name = "twin hand directly"
        elif variant == "direct-redraw":
            name = "twin hand, noise redrawn (baseline)"
        else:
            name = f"TakkTile driver, emulator, {float(variant.split('@')[1]):.0%} packet loss"
        lines.append(
            f"| {name} | {n} | {correct / n:.0%} | {same / n:.0%} | {np.mean(grasps):.2f} | "
            f"{same_first / n:.0%} | {np.mean(per_grasp):.3f} | {failed} |"
        )
    lines += ["", "Runs whose label differs from the twin's (object, seed: twin -> driver):", ""]
    any_diff = False
    for variant, runs in results.items():
        if variant == "direct":
            continue
        for obj in objects:
            for i, r in enumerate(runs[obj]):
                d = direct[obj][i]
                if r.get("error"):
                    any_diff = True
                    lines.append(f"- {variant}: {obj}, seed {seeds[i]}: failed ({r['error']})")
                elif r["label"] != d["label"]:
                    any_diff = True
                    lines.append(
                        f"- {variant}: {obj}, seed {seeds[i]}: {d['label'] or '-'} "
                        f"({d['grasps']} grasps) -> {r['label'] or '-'} ({r['grasps']} grasps); "
                        f"first parted at {first_divergence(d, r)}"
                    )
    if not any_diff:
        lines.append("- none")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", default=None, help="data directory (model, objects)")
    p.add_argument("--objects", default=",".join(PAPER_SIM_OBJECTS), help="recognise these")
    p.add_argument("--seeds", default="0-9")
    p.add_argument("--policy", default="tree")
    p.add_argument("--loss", type=float, nargs="+", default=[0.0, 0.05])
    p.add_argument("--workers", type=int, default=2)
    p.add_argument(
        "--stream-timeout-s",
        type=float,
        default=0.2,
        help="hand.stream_timeout_s of the driver runs (raise it on a loaded machine: the "
        "emulator thread shares the CPU)",
    )
    p.add_argument("--json", default=None, help="write every run here")
    a = p.parse_args(argv)
    root = paths.data_dir(a.data)
    objects = [o for o in a.objects.split(",") if o]
    seeds = parse_seeds(a.seeds)
    ensure_model(root, list(PAPER_SIM_OBJECTS), load_config(None, []))  # --objects: a subset
    t = a.stream_timeout_s
    jobs = [("direct", str(root), o, seeds, a.policy, 0.0, t) for o in objects]
    jobs += [("direct-redraw", str(root), o, seeds, a.policy, 0.0, t) for o in objects]
    jobs += [("driver", str(root), o, seeds, a.policy, loss, t) for loss in a.loss for o in objects]
    results: dict[str, dict[str, list[dict]]] = {}
    t0 = time.perf_counter()
    # spawn: the workers start PyBullet and threads of their own; nothing forked mid-flight.
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=a.workers, mp_context=ctx) as pool:
        for variant, obj, rows in pool.map(job, jobs):
            results.setdefault(variant, {})[obj] = rows
            print(
                f"{variant:>14} {obj:>13}: " + " ".join(r["label"] or "-" for r in rows), flush=True
            )
    print(
        f"\n{len(objects)} objects x {len(seeds)} seeds, {a.workers} workers, "
        f"{time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} CPUs\n"
    )
    order = ["direct", "direct-redraw"] + [f"driver@{loss:g}" for loss in a.loss]
    results = {k: results[k] for k in order}
    text = table(results, objects, seeds)
    print(f"$ python benchmarks/reflex_end_to_end.py {' '.join(sys.argv[1:])}\n")
    print(text)
    if a.json:
        Path(a.json).write_text(json.dumps({"seeds": seeds, "results": results}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
