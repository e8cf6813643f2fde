"""`activetouch recordings list|show ID` and `activetouch replay FILE` (docs/recordings.md).

Every recognition (`recognize`, the daemon) leaves an MCAP file under <data>/recordings/;
`replay` re-runs the classifier and belief on its grasps offline and prints the labels."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from rich.console import Console

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.errors import DataError
from activetouch.objects.library import ObjectLibrary
from activetouch.recordings import format as fmt
from activetouch.recordings.store import find_recording, list_recordings


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "recordings",
        help="list or show the recorded recognitions (MCAP files under <data>/recordings/)",
    )
    rs = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    ls = rs.add_parser("list", help="every recording: time, object, label, grasps, size")
    ls.add_argument("--json", action="store_true", help="one JSON object per line")
    add_common_options(ls)
    ls.set_defaults(func=run_list)
    sh = rs.add_parser("show", help="one recording: request, grasps, beliefs, plans, result")
    sh.add_argument("id", metavar="ID", help="recording id (or a unique part of it), or a file")
    sh.add_argument("--json", action="store_true", help="the decoded messages as JSON")
    add_common_options(sh)
    sh.set_defaults(func=run_show)

    r = sub.add_parser(
        "replay",
        help="re-run the classifier and belief on a recording's grasps (offline) and compare",
    )
    r.add_argument("file", metavar="FILE", help="a recording (.mcap), or its id")
    r.add_argument(
        "--model", metavar="DIR", default=None, help="model directory (default: the recorded one)"
    )
    r.add_argument("--json", action="store_true")
    add_common_options(r)
    r.set_defaults(func=run_replay)


def _root(args: argparse.Namespace) -> Path:
    return paths.data_dir(args.data)


def _when(t: float | None) -> str:
    if not t:
        return "?"
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))


def _summary(path: Path) -> dict[str, Any]:
    # deferred: loads mcap
    from activetouch.recordings.reader import read_recording

    try:
        rec = read_recording(path)
    except DataError as e:
        return {"id": path.stem, "path": str(path), "error": str(e)}
    req, res = rec.request, rec.result or {}
    if rec.kind == "calibration":
        return {
            "id": path.stem,
            "path": str(path),
            "kind": rec.kind,
            "started": req.get("started"),
            "object": f"calibrate {req.get('procedure')}",
            "label": req.get("device"),
            "grasps": 0,
            "moves": len(rec.log_times.get("/tf", [])),
            "size": path.stat().st_size,
            "source": req.get("source"),
            "complete": rec.complete,
            "error": res.get("error"),
        }
    label = res.get("label")
    if label is None:
        label = rec.labels[-1] if rec.labels else ""
    return {
        "id": path.stem,
        "path": str(path),
        "kind": rec.kind,
        "started": req.get("started"),
        "object": req.get("object"),
        "label": label,
        "grasps": len(rec.grasps),
        "size": path.stat().st_size,
        "policy": req.get("policy"),
        "source": req.get("source"),
        "complete": rec.complete,
        "error": res.get("error"),
    }


def run_list(args: argparse.Namespace) -> int:

    root = _root(args)
    recs = list_recordings(root)
    rows = [_summary(r.path) for r in recs]
    if args.json:
        for row in rows:
            sys.stdout.write(json.dumps(row) + "\n")
        return 0
    console = Console()
    if not rows:
        console.print(f"no recordings in {paths.recordings_dir(root)}", highlight=False)
        return 0
    w = max(len(row["id"]) for row in rows)
    console.print(
        f"{'id':<{w}}  {'time':<19}  {'object':<14} {'label':<14} {'grasps':>6} {'size':>10}",
        highlight=False,
        soft_wrap=True,
    )
    for row in rows:
        note = ""
        if row.get("error"):
            note = f"  error: {str(row['error'])[:60]}"
        elif not row.get("complete", True):
            note = "  incomplete (cut short)"
        console.print(
            f"{row['id']:<{w}}  {_when(row.get('started')):<19}  "
            f"{row.get('object') or '-'!s:<14} {row.get('label') or '-'!s:<14} "
            f"{row.get('grasps', '?')!s:>6} {row.get('size', 0) / 1024:>6.1f} KiB{note}",
            highlight=False,
            soft_wrap=True,
        )
    total = sum(r.size for r in recs)
    console.print(f"{len(recs)} recordings, {total / 1e6:.2f} MB in {paths.recordings_dir(root)}")
    return 0


def run_show(args: argparse.Namespace) -> int:
    # deferred: loads mcap
    from activetouch.recordings.reader import read_recording

    path = find_recording(_root(args), args.id)
    rec = read_recording(path)
    if args.json:
        out = {
            "path": str(path),
            "complete": rec.complete,
            "channels": {
                t: {
                    "schema": c.schema_name,
                    "schema_encoding": c.schema_encoding,
                    "message_encoding": c.message_encoding,
                    "count": c.count,
                }
                for t, c in rec.channels.items()
            },
            "messages": rec.json,
        }
        json.dump(out, sys.stdout)
        sys.stdout.write("\n")
        return 0
    console = Console(soft_wrap=True)
    req = rec.request
    console.print(f"[bold]{path.stem}[/]  {path}", highlight=False)
    if rec.kind == fmt.CALIBRATION:
        _show_calibration(rec, console)
        return 0
    console.print(
        f"{_when(req.get('started'))}  {req.get('source', '')}  object "
        f"{req.get('object') or '-'}  policy {req.get('policy')}  seed {req.get('seed')}  "
        f"budget {req.get('max_moves')}  belief {(req.get('recognition') or {}).get('belief')}",
        highlight=False,
    )
    console.print(f"model {req.get('model')} ({', '.join(req.get('class_names', []))})")
    plans = {p["move"]: p for p in rec.json.get(fmt.PLAN, [])}
    times = {t["move"]: t for t in rec.json.get(fmt.ROBOT_TIME, [])}
    for g, b in zip(rec.grasps, rec.beliefs, strict=False):
        m = g["move"]
        top = "  ".join(f"{n} {p:.2f}" for n, p in b.get("top3", [])) or "nothing felt"
        rt = times.get(m, {}).get("total_s")
        console.print(
            f"grasp {m:>2}  pose {g['pose_id']:>4}  contacts {len(g['sensor_ids']):>2}  |  {top}"
            + (f"  robot {rt:.1f} s" if rt is not None else ""),
            highlight=False,
        )
        pl = plans.get(m)
        if pl is not None:
            value = pl.get("value")
            console.print(
                f"          plan ({pl['policy']}): poses {pl['poses']}"
                + (f"  value {value:.3f}" if isinstance(value, float) else "")
                + (f"  {pl['simulations']} simulations" if "simulations" in pl else ""),
                highlight=False,
            )
    for e in rec.json.get(fmt.ERROR, []):
        console.print(f"[yellow]{e['kind']}[/] after grasp {e['move']}: {e['error']}")
    res = rec.result
    if res is None:
        console.print("[yellow]no result: the recording was cut short[/]")
    elif res.get("error"):
        console.print(f"[red]failed:[/] {res.get('error_type', '')}: {res['error']}")
    else:
        console.print(
            f"result: [bold]{res.get('label') or 'nothing'}[/] "
            f"(p = {res.get('probability', 0):.2f}) after {res.get('moves')} grasps, "
            f"stopped: {res.get('stop_reason')}"
        )
    console.print(
        "channels: "
        + ", ".join(f"{t} ({c.schema_name}, {c.count})" for t, c in rec.channels.items()),
        highlight=False,
    )
    if not rec.complete:
        console.print("[yellow]no footer: the writer did not finish (read up to its last grasp)[/]")
    return 0


def _show_calibration(rec: Any, console: Console) -> None:

    req = rec.request
    settings = " ".join(f"{k}={v}" for k, v in (req.get("settings") or {}).items())
    console.print(
        f"{_when(req.get('started'))}  calibrate {req.get('procedure')}  device "
        f"{req.get('device')}  hand {req.get('hand')}  arm {req.get('arm')}  {settings}",
        highlight=False,
    )
    states = rec.json.get(fmt.HAND_STATE, [])
    if states:
        span = states[-1]["stamp"] - states[0]["stamp"]
        touched = sum(1 for s in states if s["contact"])
        console.print(
            f"hand states: {len(states)} over {span:.2f} s, {touched} with a contact",
            highlight=False,
        )
    console.print(
        f"flange moves: {len(rec.log_times.get(fmt.TF, []))}, grasps: "
        f"{len(rec.ros.get(fmt.CONTACTS, []))}",
        highlight=False,
    )
    res = rec.result
    if res is None:
        console.print("[yellow]no result: the recording was cut short[/]")
    elif res.get("error"):
        console.print(f"[red]failed:[/] {res.get('error_type', '')}: {res['error']}")
    else:
        r = res.get("record") or {}
        stored = "stored" if res.get("stored") else "not stored (--dry-run)"
        console.print(
            f"result: {r.get('kind')} {r.get('device')}, {stored}; quality "
            f"{json.dumps(r.get('quality', {}))[:300]}",
            highlight=False,
        )
    console.print(
        "channels: "
        + ", ".join(f"{t} ({c.schema_name}, {c.count})" for t, c in rec.channels.items()),
        highlight=False,
    )


def run_replay(args: argparse.Namespace) -> int:
    # deferred: loads mcap
    from activetouch.recordings.reader import read_recording

    # deferred: loads numba, scipy
    from activetouch.session.local import load_trained

    # deferred: loads mcap, numba, scipy
    from activetouch.session.replay import recorded_model_dir, replay

    root = _root(args)
    path = Path(args.file)
    if not path.is_file():
        path = find_recording(root, args.file)
    rec = read_recording(path)
    if rec.kind != "recognition":
        raise DataError(
            f"{path.name} records `calibrate {rec.request.get('procedure')}`: replay re-runs "
            "recognitions (`activetouch recordings show` shows this one)"
        )
    if not rec.grasps:
        raise DataError(f"{path}: no grasp recorded, nothing to replay")
    if args.model:
        model_dir = Path(args.model)
    else:
        model_dir = recorded_model_dir(rec) or paths.default_model(root)
        if not (model_dir / "model.json").is_file():
            model_dir = paths.default_model(root)
    model = load_trained(model_dir)
    checksum = rec.request.get("model_checksum")
    console = Console(stderr=args.json, soft_wrap=True)
    if checksum and checksum != model.dataset_checksum:
        console.print(
            f"[yellow]note:[/] the model at {model_dir} was trained on another dataset than the "
            "recorded one: labels may differ",
            highlight=False,
        )
    out = replay(rec, model, ObjectLibrary(paths.objects_dir(root)))
    if args.json:
        json.dump(
            {
                "path": str(path),
                "model": str(model_dir),
                "labels": out.labels,
                "recorded_labels": out.recorded_labels,
                "probabilities": out.probabilities,
                "same_labels": out.same_labels,
                "max_abs_diff": out.max_abs_diff,
            },
            sys.stdout,
        )
        sys.stdout.write("\n")
    else:
        # deferred: loads numba, scipy
        from activetouch.session.loop import display_label

        for i, (a, b) in enumerate(zip(out.labels, out.recorded_labels, strict=False), 1):
            mark = "" if a == b else f"   [red]recorded: {display_label(b)}[/]"
            console.print(f"grasp {i:>2}  {display_label(a)}{mark}", highlight=False)
        verdict = "the same labels as recorded" if out.same_labels else "[red]labels differ[/]"
        console.print(
            f"replayed {len(out.labels)} grasps with {model_dir}: {verdict} "
            f"(largest probability difference {out.max_abs_diff:.2g})",
            highlight=False,
        )
    if not out.same_labels:
        raise DataError(
            f"replay of {path.name} gave other labels than recorded: is {model_dir} the model "
            "that recognised it? (--model DIR)"
        )
    return 0
