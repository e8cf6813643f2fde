"""`activetouch objects list|add|render`: the object library from the command line.

    activetouch objects list [--json]
    activetouch objects add NAME PATH [--scale S] [--force]
    activetouch objects render [NAME ...] [--out DIR] [--parts]

The builtin objects are generated into the library on first use.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from rich.console import Console
from rich.table import Table

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import load_config
from activetouch.errors import DataError
from activetouch.objects.library import ObjectLibrary, ObjectSpec
from activetouch.sim.render import contacts_in_object_frame, render_object_png


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("objects", help="the object library: list, import, render")
    p.set_defaults(func=lambda _args: _usage(p))
    osub = p.add_subparsers(dest="objects_command", metavar="ACTION")

    pl = osub.add_parser("list", help="list the objects (builtins are generated on first use)")
    add_common_options(pl)
    pl.add_argument("--json", action="store_true", help="print JSON instead of a table")
    pl.set_defaults(func=_list)

    pa = osub.add_parser("add", help="import a mesh (OBJ, STL or URDF) as a new object")
    add_common_options(pa)
    pa.add_argument("name", metavar="NAME", help="object name (letters, digits, '_', '-')")
    pa.add_argument("path", metavar="PATH", help="mesh file: .obj, .stl or .urdf")
    pa.add_argument(
        "--scale", type=float, default=1.0, help="multiply coordinates by S (0.001 for mm)"
    )
    pa.add_argument("--force", action="store_true", help="replace an imported object of that name")
    pa.add_argument(
        "--decomposition",
        choices=("coacd", "vhacd"),
        default="coacd",
        help="convex decomposition for concave meshes (default: coacd)",
    )
    pa.add_argument(
        "--no-probe",
        action="store_true",
        help="skip the test grasps that count how often the hand feels fewer than 3 contacts",
    )
    pa.set_defaults(func=_add)

    pr = osub.add_parser(
        "render",
        help="draw each object to a PNG, with its training poses and contacts if collected",
    )
    add_common_options(pr)
    pr.add_argument("names", nargs="*", metavar="NAME", help="objects to draw (default: all)")
    pr.add_argument(
        "--out", metavar="DIR", default=None, help="output folder (default: DATA/renders)"
    )
    pr.add_argument(
        "--dataset",
        metavar="NAME",
        default=paths.DEFAULT_DATASET,
        help="training dataset under DATA/datasets whose poses and contacts to draw",
    )
    pr.add_argument("--parts", action="store_true", help="draw the convex collision parts instead")
    pr.set_defaults(func=_render)


def _usage(p: argparse.ArgumentParser) -> int:
    p.print_help()
    return 2


def _library(args: argparse.Namespace, console: Console | None = None) -> ObjectLibrary:
    lib = ObjectLibrary(paths.objects_dir(paths.data_dir(args.data)))
    console = console or Console(stderr=True)
    with console.status("generating the builtin objects ..."):
        made = lib.ensure_builtins()
    if made:
        console.print(f"generated {len(made)} builtin objects in {lib.root}", highlight=False)
    return lib


def _row(spec: ObjectSpec) -> dict:
    return {
        "name": spec.name,
        "set": spec.set,
        "source": spec.source,
        "extents": [round(float(e), 6) for e in spec.extents],
        "parts": len(spec.collision_meshes),
        "scale": spec.scale,
        "visual_mesh": str(spec.visual_mesh),
        "sha256": spec.meta.get("sha256"),
        "family": spec.meta.get("family"),
    }


def _list(args: argparse.Namespace) -> int:
    lib = _library(args)
    with Console(stderr=True).status("generating the hard library (33 objects, once) ..."):
        lib.ensure_set("hard")
    specs = lib.specs()
    if args.json:
        sys.stdout.write(json.dumps([_row(s) for s in specs], indent=2) + "\n")
        return 0
    table = Table(title=f"objects in {lib.root}")
    for col, just in (("name", "left"), ("set", "left"), ("source", "left")):
        table.add_column(col, justify=just)
    table.add_column("extents (cm)", justify="right")
    table.add_column("parts", justify="right")
    for s in specs:
        ext = " x ".join(f"{e * 100:.1f}" for e in s.extents)
        table.add_row(s.name, s.set, s.source, ext, str(len(s.collision_meshes)))
    Console().print(table)
    return 0


def _add(args: argparse.Namespace) -> int:
    lib = _library(args)
    err = Console(stderr=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with err.status(f"importing {args.path} ..."):
            spec = lib.add(
                args.name,
                args.path,
                args.scale,
                overwrite=args.force,
                decomposition=args.decomposition,
            )
    for w in caught:
        err.print(f"[yellow]warning:[/] {w.message}", highlight=False)
    ext = " x ".join(f"{e * 100:.1f}" for e in spec.extents)
    Console().print(
        f"added {spec.name}: {ext} cm, {len(spec.collision_meshes)} convex parts "
        f"({spec.meta.get('decomposition')}), in {spec.directory}",
        highlight=False,
        soft_wrap=True,
    )
    if not args.no_probe:
        _probe(spec, args, err)
    return 0


def _probe(spec: ObjectSpec, args: argparse.Namespace, err: Console) -> None:
    """Grasp the new object at its own training grid in the twin and report how often the
    hand feels fewer than 3 contacts (with what to do when that is often)."""
    # deferred: loads scipy
    from activetouch.sim.contact_probe import advice, probe_object

    cfg = load_config(args.config, args.overrides)
    with err.status(f"test grasps of {spec.name} at its training grid ..."):
        share = probe_object(spec, cfg)
    Console().print(
        f"{spec.name}: {share.share:.0%} of {share.grasps} test grasps felt fewer than 3 contacts "
        f"(mean {share.mean_contacts:.1f} contacts, {share.unreachable} poses unreachable)",
        highlight=False,
        soft_wrap=True,
    )
    for line in advice([share], cfg):
        err.print(f"[yellow]warning:[/] {line}", highlight=False, soft_wrap=True)


def _dataset(root: Path, name: str, console: Console):
    """The collected dataset to draw poses and contacts from, or None if there is none."""
    path = paths.datasets_dir(root) / name
    if not path.exists():
        if name == paths.DEFAULT_DATASET:
            return None  # nothing trained yet: draw the meshes alone
        d = paths.datasets_dir(root)
        have = sorted(p.name for p in d.iterdir() if p.is_dir()) if d.is_dir() else []
        raise DataError(f"no dataset {name!r} in {d} (has: {', '.join(have) or 'none'})")
    # deferred: loads scipy
    from activetouch.recognition.dataset import Dataset

    try:
        return Dataset.open(path)
    except DataError as e:
        console.print(f"[yellow]warning:[/] not drawing poses: {e}", highlight=False)
        return None


def _render(args: argparse.Namespace) -> int:

    err = Console(stderr=True)
    root = paths.data_dir(args.data)
    lib = _library(args, err)
    names = args.names or lib.names()
    specs = [lib.get(n) for n in names]  # unknown names fail before anything is drawn
    out = Path(args.out) if args.out else root / "renders"
    ds = _dataset(root, args.dataset, err)
    have = set(ds.object_names()) if ds is not None else set()
    for spec in specs:
        poses = contacts = None
        if spec.name in have:
            og = ds.read(spec.name)
            poses = og.poses
            contacts = contacts_in_object_frame(og.poses, [g.xyz for g in og.grasps])
        suffix = "_parts" if args.parts else ""
        png = render_object_png(
            spec, out / f"{spec.name}{suffix}.png", poses, contacts, parts=args.parts
        )
        what = f"{len(poses)} poses, {len(contacts)} contacts" if poses is not None else "mesh only"
        Console().print(f"{png}  ({what})", highlight=False, soft_wrap=True)
    return 0


__all__ = ["register"]
