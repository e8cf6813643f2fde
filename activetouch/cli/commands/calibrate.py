"""`activetouch calibrate tactile|fingers|mount|object|show|import`: measure a calibration with
the configured devices, store it per device (``<data>/calibration/<device>/<kind>.json``),
make the running driver use it, print what is stored, or import a lab's reflex-ros-pkg
calibration files."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from rich.console import Console

from activetouch import paths
from activetouch.calibration import store
from activetouch.calibration.sf_fingers import JOG_STEPS, calibrate_sf_fingers
from activetouch.calibration.store import device_name
from activetouch.calibration.upstream_files import import_file
from activetouch.cli.main import add_common_options
from activetouch.config import load_config
from activetouch.errors import ActiveTouchError
from activetouch.objects.library import BUILTIN_OBJECTS, ObjectLibrary
from activetouch.recordings.store import prune

PROCEDURES = ("tactile", "fingers", "mount", "object")


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "calibrate",
        help="calibrate tactile zero, finger zero, hand mount, object placement; show them",
        description="Measure a calibration with the configured hand/arm and store it, or show "
        "the stored ones. docs/calibration.md says what each procedure does.",
    )
    p.add_argument("what", choices=(*PROCEDURES, "show", "import"))
    p.add_argument(
        "kind",
        nargs="?",
        help="show: only this kind; import: a reflex-ros-pkg yaml file "
        "(reflex_sf_motor_zero_points.yaml, finger_calibrate.yaml, tactile_calibrate.yaml)",
    )
    p.add_argument("files", nargs="*", help="import: more yaml files")
    p.add_argument(
        "--accept-current",
        action="store_true",
        help="fingers, ReFlex SF: take the servos' present positions as the zero points (the "
        "fingers are already open, tendons just taut) instead of jogging each one",
    )
    p.add_argument("--device", default=None, help="device name (default: the hand type)")
    p.add_argument("--json", action="store_true", help="print the record as JSON")
    p.add_argument("--dry-run", action="store_true", help="measure and print, store nothing")
    p.add_argument("--duration", type=float, default=None, help="tactile: seconds of samples")
    p.add_argument("--k-sigma", type=float, default=None, help="tactile: threshold = k sigma")
    p.add_argument("--min-threshold", type=float, default=None, help="tactile: lowest threshold")
    p.add_argument("--no-open", action="store_true", help="tactile: do not open the hand first")
    p.add_argument(
        "--inject-mount",
        default=None,
        metavar="X,Y,Z,RX,RY,RZ",
        help="mount, twin only: hang the hand off the flange through this true mount "
        "(mm, deg) to check the procedure",
    )
    p.add_argument("--object", default=None, help="object: its name in the object library")
    p.add_argument(
        "--inject-object",
        default=None,
        metavar="DX,DY[,DEG]",
        help="object, twin only: stand the object this far off the workcell's placement (mm, "
        "deg about z) while the procedure believes the nominal one",
    )
    p.add_argument("--directions", type=int, default=None, help="object: approaches (8)")
    p.add_argument(
        "--no-record",
        dest="record",
        action="store_false",
        help="write no recording of this procedure (default: recording.enabled, an MCAP file "
        "under <data>/recordings/)",
    )
    add_common_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    console = Console(soft_wrap=True)
    root = paths.data_dir(args.data)
    if args.what == "show":
        if args.kind is not None and args.kind not in PROCEDURES:
            raise ActiveTouchError(
                f"calibrate show {args.kind}: not a kind; use one of {', '.join(PROCEDURES)}"
            )
        return show(root, args.kind, args.json, console)
    cfg = load_config(args.config, args.overrides)
    device = device_name(cfg, args.device)
    if args.what == "import":
        return run_import(root, device, [args.kind, *args.files], args, console)
    procedure = {"tactile": run_tactile, "fingers": run_fingers, "mount": run_mount}.get(
        args.what, run_object
    )
    recorder = _recorder(cfg, root, device, args) if args.record else None
    try:
        rec = procedure(cfg, root, args.device if args.what == "object" else device, args,
                        console, recorder)  # fmt: skip
        if args.json:
            print(rec.to_json(), end="")
        if not args.dry_run:
            path = store.save(root, rec)
            console.print(f"stored {path}")
    except BaseException as e:
        _close_recorder(recorder, root, cfg, console, error=e)
        raise
    _close_recorder(recorder, root, cfg, console, record=rec, stored=not args.dry_run)
    return 0


def _recorder(cfg, root, device, args):
    # deferred: loads mcap, scipy
    from activetouch.recordings.calibration import open_calibration_recorder

    settings = {
        k: getattr(args, k)
        for k in ("duration", "k_sigma", "min_threshold", "no_open", "inject_mount", "object",
                  "inject_object", "directions", "accept_current", "dry_run")
        if getattr(args, k, None) not in (None, False)
    }  # fmt: skip
    return open_calibration_recorder(
        root, cfg, procedure=args.what, device=device, settings=settings
    )


def _close_recorder(recorder, root, cfg, console, record=None, stored=False, error=None):
    """Finish the recording with the record (or the error), then apply the size/age limits."""
    if recorder is None:
        return

    if error is not None:
        recorder.finish(error=error)
    else:
        recorder.finish(record=json.loads(record.to_json()), stored=stored)
        console.print(f"recorded {recorder.path}", highlight=False)
    try:
        prune(root, cfg.recording, keep=recorder.path)
    except Exception as e:  # the calibration is done and stored: only the limits failed
        console.print(f"[yellow]recordings: cannot apply the limits: {e}[/]")


def _recorded(recorder, hand=None, flange=None):
    """The hand and flange a procedure is handed: recorded ones when recording."""
    if recorder is None:
        return hand, flange
    # deferred: loads mcap, scipy
    from activetouch.recordings.calibration import RecordingFlange, RecordingHand

    return (
        None if hand is None else RecordingHand(hand, recorder),
        None if flange is None else RecordingFlange(flange, recorder),
    )


def _hand(cfg, root):
    # deferred: loads scipy
    from activetouch.devices import DeviceContext

    ctx = DeviceContext(cfg, root)
    hand = cfg.hand.make(ctx)
    hand.connect()
    return hand, ctx


def run_tactile(cfg, root, device, args, console, recorder=None):
    # deferred: loads scipy
    from activetouch.calibration.tactile import TactileSettings, apply_tactile, calibrate_tactile

    st = TactileSettings(open_first=not args.no_open)
    if args.duration is not None:
        st.duration_s = args.duration
    if args.k_sigma is not None:
        st.k_sigma = args.k_sigma
    if args.min_threshold is not None:
        st.min_threshold = args.min_threshold
    previous = store.load(root, "tactile", device)
    hand, ctx = _hand(cfg, root)
    try:
        rec, fit = calibrate_tactile(_recorded(recorder, hand)[0], device, st, previous)
        apply_tactile(hand, fit.zero, fit.threshold)
    finally:
        hand.disconnect()
        ctx.close()
    q = rec.quality
    console.print(
        f"tactile {device}: {q['n_samples']} samples in {q['window_s']:.2f} s; sigma median "
        f"{q['sigma_median']:.2f}, max {q['sigma_max']:.2f} counts; zero standard error <= "
        f"{q['zero_standard_error_max']:.2f}; flags {rec.values['flags']}"
    )
    return rec


def run_import(root, device, files, args, console) -> int:

    if not files or files[0] is None:
        raise ActiveTouchError("calibrate import: name the reflex-ros-pkg yaml file(s)")
    records = [import_file(Path(f), device) for f in files]  # all read before any is stored
    for f, rec in zip(files, records, strict=True):
        if args.json:
            print(rec.to_json(), end="")
        line = f"{f}: {rec.kind} of {device} ({rec.method['format']})"
        if args.dry_run:
            console.print(line + ", not stored (--dry-run)")
        else:
            console.print(f"{line} -> {store.save(root, rec)}")
    return 0


def run_sf_fingers(cfg, root, device, args, console, recorder=None):
    # deferred: loads scipy
    from activetouch.devices import DeviceContext

    ctx = DeviceContext(cfg, root)
    hand = cfg.hand.make(ctx)
    hand.check_travel = False  # the zero points are what is being found
    hand.connect()

    def ask(k: int, name: str, pos: float) -> str:
        if args.accept_current:
            return ""
        keys = "/".join(JOG_STEPS)
        return input(
            f"{name} (servo {k + 1}) at {pos:.3f} motor rad: {keys} tighten/loosen (capital: "
            "5 steps), Enter when open with the tendon just taut > "
        )

    try:
        rec = calibrate_sf_fingers(_recorded(recorder, hand)[0], device, ask)
    except EOFError:
        raise ActiveTouchError(
            "calibrate fingers: no terminal to jog from; use --accept-current"
        ) from None
    finally:
        hand.disconnect()
        ctx.close()
    console.print(
        f"fingers {device}: zero points {rec.values['motor_zero_points']} motor rad "
        f"(hand.motor_zero_points; moved {rec.quality['moved_motor_rad']})"
    )
    return rec


def run_fingers(cfg, root, device, args, console, recorder=None):
    # deferred: loads scipy
    from activetouch.calibration.fingers import calibrate_fingers

    if cfg.hand.type == "reflex-sf":
        return run_sf_fingers(cfg, root, device, args, console, recorder)
    hand, ctx = _hand(cfg, root)
    try:
        rec, fit = calibrate_fingers(_recorded(recorder, hand)[0], device)
    finally:
        hand.disconnect()
        ctx.close()
    console.print(
        f"fingers {device}: motor zero {np.round(fit.motor_zero, 4).tolist()} rad (correction "
        f"{rec.quality['correction_motor_rad']}), encoder zero "
        f"{np.round(fit.encoder_zero, 4).tolist()} rad, in {fit.duration_s:.1f} s"
    )
    return rec


def _parse_mount(text: str):
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial.transform import Rotation

    # deferred: loads scipy
    from activetouch.interfaces import Pose

    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 6:
        raise ActiveTouchError(f"--inject-mount {text!r}: expected X,Y,Z,RX,RY,RZ (mm, deg)")
    return Pose(np.array(v[:3]) / 1000.0, Rotation.from_euler("xyz", v[3:], degrees=True).as_quat())


def run_mount(cfg, root, device, args, console, recorder=None):
    # deferred: loads scipy
    from activetouch.calibration.mount import calibrate_mount

    # deferred: loads scipy
    from activetouch.calibration.probing import FloatingFlange

    # deferred: loads scipy
    from activetouch.devices import make_devices

    # deferred: loads scipy
    from activetouch.interfaces import Pose

    mount_device = f"{device}-on-{cfg.arm.type}"
    previous = store.load(root, "mount", mount_device)
    mount0 = (
        Pose(previous.values["xyz"], previous.values["quat_xyzw"])
        if previous is not None
        else Pose(np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    )
    devices = make_devices(cfg, root)
    try:
        arm = devices.arm
        if args.inject_mount:
            if not devices.simulated:
                raise ActiveTouchError("--inject-mount is for the twin only")
            # deferred: loads scipy
            from activetouch.calibration.sim import MountedArm

            arm = MountedArm(arm, _parse_mount(args.inject_mount))
        threshold = float(getattr(cfg.sim, "contact_threshold", 20.0))
        hand, flange = _recorded(recorder, devices.hand, FloatingFlange(arm))
        rec, fit, _ = calibrate_mount(
            hand,
            flange,
            mount0,
            cfg.workcell.table_top_z,
            mount_device,
            threshold=threshold,
        )
    finally:
        devices.close()
    q = rec.quality
    console.print(
        f"mount {mount_device}: xyz {np.round(fit.mount.xyz * 1e3, 2).tolist()} mm, rotation "
        f"{np.round(np.degrees(_rotvec(fit.mount.quat)), 3).tolist()} deg (rotation vector); "
        f"{q['n_touches']} touches, RMS residual {q['rms_residual_mm']:.3f} mm"
    )
    return rec


def _parse_object_error(text: str):
    # deferred: loads pybullet, scipy
    from activetouch.sim.twin import PlacementError

    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) not in (2, 3) or not np.all(np.isfinite(v)):
        raise ActiveTouchError(f"--inject-object {text!r}: expected DX,DY[,DEG] (mm, deg)")
    return PlacementError(
        v[0] / 1000.0, v[1] / 1000.0, float(np.radians(v[2] if len(v) > 2 else 0))
    )


def run_object(cfg, root, device, args, console, recorder=None):
    # deferred: loads numba, scipy
    from activetouch.calibration.object_frame import (
        DEFAULT_DEVICE,
        IDENTITY,
        ObjectSettings,
        calibrate_object,
        nominal_placement,
    )

    # deferred: loads scipy
    from activetouch.calibration.probing import FloatingFlange

    # deferred: loads scipy
    from activetouch.devices import make_devices

    # deferred: loads scipy
    from activetouch.interfaces import Pose

    if not args.object:
        raise ActiveTouchError("calibrate object: name the object with --object NAME")
    device = device or DEFAULT_DEVICE
    library = ObjectLibrary.in_data_dir(root)
    if args.object not in library and args.object in _builtins():
        library.ensure_builtins([args.object])
    spec = library.get(args.object)  # DataError names the known ones
    st = ObjectSettings()
    if args.directions is not None:
        st.directions = int(args.directions)
    nominal = nominal_placement(cfg.workcell, spec.extents)
    injected = _parse_object_error(args.inject_object) if args.inject_object else None
    devices = make_devices(cfg, root)
    try:
        mount = IDENTITY
        if devices.simulated:
            if devices.ctx.place is None:
                raise ActiveTouchError("calibrate object: this simulated robot places no object")
            devices.ctx.place(spec.name, cfg.sim.seed)
            if injected is not None:
                _misplace(devices, spec, injected)
        else:
            if injected is not None:
                raise ActiveTouchError("--inject-object is for the twin only")
            hand_name = device_name(cfg, None)
            rec_m = store.load(root, "mount", f"{hand_name}-on-{cfg.arm.type}")
            if rec_m is not None:
                mount = Pose(rec_m.values["xyz"], rec_m.values["quat_xyzw"])
        # deferred: loads pybullet, scipy
        from activetouch.sim.world import geometry_from_config

        hand, flange = _recorded(recorder, devices.hand, FloatingFlange(devices.arm))
        rec, fit, _ = calibrate_object(
            hand,
            flange,
            spec,
            nominal,
            cfg.workcell.table_top_z,
            device,
            st,
            mount=mount,
            geometry=geometry_from_config(cfg.sim),
            threshold=float(cfg.sim.contact_threshold),
        )
    finally:
        devices.close()
    q = rec.quality
    p = fit.placement
    yaw = f"{np.degrees(p.yaw_rad):.2f} deg" if fit.yaw_observed else "not seen (kept nominal)"
    console.print(
        f"object {spec.name}: x {p.xyz[0] * 1e3:.2f} y {p.xyz[1] * 1e3:.2f} z {p.xyz[2] * 1e3:.2f}"
        f" mm, yaw {yaw}; correction {np.round(fit.correction_xy * 1e3, 2).tolist()} mm; "
        f"{q['n_touches']} touches ({len(q['missed_approaches'])} missed), RMS residual "
        f"{q['rms_residual_mm']:.3f} mm, contact offset {fit.offset_m * 1e3:.2f} mm",
        highlight=False,
    )
    if injected is not None:
        ex = fit.correction_xy[0] - injected.dx
        ey = fit.correction_xy[1] - injected.dy
        console.print(
            f"  injected ({injected.dx * 1e3:.2f}, {injected.dy * 1e3:.2f}) mm, "
            f"{np.degrees(injected.yaw_rad):.2f} deg: error ({ex * 1e3:.2f}, {ey * 1e3:.2f}) mm, "
            f"|{np.hypot(ex, ey) * 1e3:.2f}| mm",
            highlight=False,
        )
    return rec


def _builtins() -> tuple[str, ...]:

    return BUILTIN_OBJECTS


def _misplace(devices, spec, err) -> None:
    """Stand the twin's object off its placement (the object frame stays nominal)."""
    # deferred: loads scipy
    from activetouch.sim.devices import TWIN

    # deferred: loads pybullet, scipy
    from activetouch.sim.twin import place_displaced

    rig = devices.ctx.shared(TWIN, lambda: None)
    if rig is None or not hasattr(rig, "world"):
        raise ActiveTouchError(
            "--inject-object needs the twin (hand.type=twin, arm.type=twin-floating)"
        )
    place_displaced(rig.world, spec, err)


def _rotvec(quat):
    # deferred: scipy submodules load on first use (scipy.stats: 1.1 s)
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(quat).as_rotvec()


def show(root, kind: str | None, as_json: bool, console: Console) -> int:

    rows = [(p, r) for p, r in store.list_records(root) if kind is None or p.stem == kind]
    if as_json:
        out = [
            {"path": str(p), "error": str(r)}
            if isinstance(r, Exception)
            else {"path": str(p), **json.loads(r.to_json())}
            for p, r in rows
        ]
        print(json.dumps(out, indent=2))
        return 0
    if not rows:
        console.print(f"no calibration stored under {store.calibration_dir(root)}")
        return 0
    for p, r in rows:
        if isinstance(r, Exception):
            console.print(f"{p}: [red]unreadable[/]: {r}", highlight=False)
            continue
        stale = store.staleness(r, r.kind)
        note = f" [yellow]({stale})[/]" if stale else ""
        console.print(f"{r.kind} {r.device}: measured {r.measured_at}{note}", highlight=False)
        console.print(f"  {p}", highlight=False)
        console.print(f"  quality: {json.dumps(r.quality)}", highlight=False)
    return 0
