"""Hard library figures (issue 15): per object, the share of training-grid grasps with fewer
than 3 contacts, on the default grid and on the small-object grid.

    python benchmarks/hard_library.py contacts [--objects all|hard|paper|a,b,...] [--json FILE]

Each object is grasped once at every pose of its own grid in a fresh twin
(`activetouch.sim.contact_probe.probe_object`), table contacts dropped as in training.
Objects are generated into a temporary library (or `--data DIR`).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import warnings
from pathlib import Path

from activetouch.config import load_config
from activetouch.objects.library import BUILTIN_OBJECTS, ObjectLibrary, generated_set
from activetouch.planning.grid import small_object_overrides
from activetouch.sim.contact_probe import FEW_CONTACTS_WARN, probe_object


def _names(arg: str) -> list[str]:
    if arg == "all":
        return list(BUILTIN_OBJECTS + generated_set("hard"))
    if arg == "hard":
        return list(generated_set("hard"))
    if arg == "paper":
        return list(BUILTIN_OBJECTS)
    return [n.strip() for n in arg.split(",") if n.strip()]


def contacts(args: argparse.Namespace) -> None:
    root = Path(args.data) if args.data else Path(tempfile.mkdtemp(prefix="hardlib-"))
    lib = ObjectLibrary(root / "objects")
    names = _names(args.objects)
    lib.ensure_builtins([n for n in names if n in BUILTIN_OBJECTS])
    lib.ensure_builtins([n for n in names if n not in BUILTIN_OBJECTS])
    grids = {"default": load_config(None, []), "small": load_config(None, small_object_overrides())}
    rows = []
    print(f"{'object':24s} {'size (cm)':>18s}  " + "  ".join(f"{g + ' <3':>14s}" for g in grids))
    for n in names:
        spec = lib.get(n)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            shares = {g: probe_object(spec, cfg) for g, cfg in grids.items()}
        size = " x ".join(f"{e * 100:.1f}" for e in spec.extents)
        cells = "  ".join(
            f"{s.share:6.0%} of {s.grasps:3d}{'*' if s.high else ' '}" for s in shares.values()
        )
        print(f"{n:24s} {size:>18s}  {cells}", flush=True)
        rows.append(
            {
                "object": n,
                "set": spec.set,
                "extents": [float(e) for e in spec.extents],
                **{
                    g: {"grasps": s.grasps, "few": s.few, "share": s.share, "mean": s.mean_contacts}
                    for g, s in shares.items()
                },
            }
        )
    for g in grids:
        bad = [r["object"] for r in rows if r[g]["share"] > FEW_CONTACTS_WARN]
        print(f"{g}: {len(rows) - len(bad)}/{len(rows)} objects at target (<= 15 %); over: {bad}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("contacts", help="share of grasps with fewer than 3 contacts per object")
    c.add_argument("--objects", default="all")
    c.add_argument("--data", default=None, help="data directory (default: a temporary one)")
    c.add_argument("--json", default=None)
    c.set_defaults(func=contacts)
    args = ap.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
