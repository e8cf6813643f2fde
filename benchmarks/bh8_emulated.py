"""The BH8 through its driver's bytes against the BH8 twin directly: the same recognitions
(object, seed, policy, budget) in the twin (`hand.type = twin-bh8`) and through the driver
on its twin-backed emulator (`hand.type = barrett-bh8`, `hand.emulate = twin`: CAN frames on
a python-can virtual bus), side by side.

    ACTIVETOUCH_HOME=DIR python benchmarks/bh8_emulated.py --seeds 0-1 --max-moves 5

DIR holds a BH8 model (`activetouch train --set hand.type=twin-bh8`). The emulated runs are
paced by the driver's 20 ms control step, so they take robot time in wall time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from activetouch import paths
from activetouch.config import load_config
from activetouch.model import load_model
from activetouch.objects.library import ObjectLibrary
from activetouch.session.local import placed_devices, recognize_in_twin
from activetouch.session.loop import RecognitionSession, policy_for


def through_driver(model, library, obj: str, policy: str, seed: int, max_moves: int):
    cfg = load_config(
        None, ["hand.type=barrett-bh8", "hand.emulate=twin", f"session.max_moves={max_moves}"]
    )
    pol = policy_for(model, policy, cfg.planner, cfg.recognition)
    with placed_devices(cfg, library.root.parent, obj, seed, "recognize") as (devices, placement):
        res = RecognitionSession(
            devices.hand,
            devices.wrist,
            model,
            pol,
            cfg.session,
            np.random.default_rng(seed),
            support_z=placement.support_z(cfg.workcell.table_top_z),
            recognition=cfg.recognition,
            library=library,
        ).run()
        stats = devices.hand.stats()
    return res, stats


def contacts(res) -> float:
    return float(np.mean([len(c) for c in res.contacts])) if res.contacts else 0.0


def first_correct(labels: list[str], obj: str) -> int | None:
    return next((i + 1 for i, lab in enumerate(labels) if lab == obj), None)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--objects", default=None)
    ap.add_argument("--seeds", default="0-1")
    ap.add_argument("--policy", default="greedy")
    ap.add_argument("--max-moves", type=int, default=5)
    args = ap.parse_args(argv)
    root = paths.data_dir(None)
    model = load_model(paths.default_model(root, "bh8"))
    library = ObjectLibrary(paths.objects_dir(root))
    objects = args.objects.split(",") if args.objects else list(model.class_names)
    lo, _, hi = args.seeds.partition("-")
    seeds = range(int(lo), int(hi or lo) + 1)
    twin_cfg = load_config(None, ["hand.type=twin-bh8"])
    print(
        "| object | seed | twin: label, first correct, contacts/grasp | driver on emulator: "
        "label, first correct, contacts/grasp | frames accepted / refused / crashes | wall s |"
    )
    print("|---|---|---|---|---|---|")
    same = n = 0
    for obj in objects:
        for seed in seeds:
            d = recognize_in_twin(model, library, obj, args.policy, seed, twin_cfg, args.max_moves)
            t0 = time.perf_counter()
            e, st = through_driver(model, library, obj, args.policy, seed, args.max_moves)
            wall = time.perf_counter() - t0
            refused = sum(v for k, v in st.items() if k.startswith("refused"))
            same += d.label == e.label
            n += 1
            print(
                f"| {obj} | {seed} | {d.label}, {first_correct(d.labels, obj)}, "
                f"{contacts(d):.1f} | {e.label}, {first_correct(e.labels, obj)}, "
                f"{contacts(e):.1f} | {st['accepted']} / {refused} / {st['crashes']} | "
                f"{wall:.0f} |",
                flush=True,
            )
    print(f"\nsame final label: {same} of {n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
