"""Run a ReFlex emulator from the command line until interrupted.

    python -m activetouch.rigs.emulate reflex-takktile --state-to 127.0.0.1:11333 \
        --command-listen 127.0.0.1:11334 --contact-spool 1.0 1.5 inf --loss 0.05
    python -m activetouch.rigs.emulate reflex-sf      # prints the pty to open
    python -m activetouch emulate reflex-takktile --object mug   # fingers and pads from the twin

Fingers: by default each finger meets an object at its `--contact-spool` angle (a kinematic
model, no PyBullet). With `--object NAME` they are the twin's instead: the library object
(trained or added in `--data`) stands in a twin world, the hand at `--wrist` (object frame;
default: from above, palm down, 1 cm over the object's box), and the spools the
driver commands pose the twin's fingers against it; pressures are the twin's tactile model.

(`python -m activetouch emulate ...` should forward here: the CLI lives outside this package.)
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import threading
from collections.abc import Iterator

from activetouch import paths
from activetouch.config import load_config
from activetouch.emulators.reflex_sf import SFEmulator, SFEmulatorConfig, SFFaults
from activetouch.emulators.reflex_takktile import (
    EmulatorConfig,
    Faults,
    KinematicFingers,
    TakktileEmulator,
)
from activetouch.errors import ActiveTouchError
from activetouch.interfaces import Pose
from activetouch.objects.library import ObjectLibrary
from activetouch.rigs.twin_fingers import TwinFingers


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="activetouch emulate", description=__doc__.split("\n")[0])
    p.add_argument("hand", choices=["reflex-takktile", "reflex-sf"])
    p.add_argument("--state-to", default="127.0.0.1:11333", help="driver's hand.state_listen")
    p.add_argument(
        "--command-listen",
        default="127.0.0.2:11334",
        help="the board's multicast group, played by a loopback address: the driver's "
        "hand.command_to (commands elsewhere are dropped, as the firmware drops unicast)",
    )
    p.add_argument(
        "--unicast-listen",
        default="127.0.0.1:0",
        help="the board's own address: commands sent here are counted and dropped",
    )
    p.add_argument(
        "--answer-delay-s",
        type=float,
        default=0.5,
        help="servo fields read 0 until the servos answer, this long after start",
    )
    p.add_argument("--rate-hz", type=float, default=40.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--contact-spool",
        type=float,
        nargs=3,
        default=[math.inf] * 3,
        metavar=("F0", "F1", "F2"),
        help="spool angle where each finger meets the object",
    )
    p.add_argument("--noise-std", type=float, default=1.0, help="per-sensor noise, counts")
    p.add_argument(
        "--zero-offset",
        type=float,
        default=None,
        help="raw unloaded reading of every sensor (default: a real hand's, 56-306 counts)",
    )
    for name in ("loss", "duplicate", "reorder", "corrupt", "truncate"):
        p.add_argument(f"--{name}", type=float, default=0.0, help=f"fraction of packets ({name})")
    p.add_argument("--delay-s", type=float, default=0.0)
    p.add_argument("--stuck-zero", type=int, nargs="*", default=[], help="sensor ids reading 0")
    p.add_argument("--stuck-saturated", type=int, nargs="*", default=[], help="ids reading max")
    p.add_argument("--mute", type=int, nargs="*", default=[], help="SF servo ids not answering")
    p.add_argument("--object", default=None, help="back the fingers by the twin with this object")
    p.add_argument("--data", default=None, help="data directory of the object library")
    p.add_argument(
        "--wrist",
        type=float,
        nargs=7,
        default=None,
        metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
        help="hand pose in the object frame (with --object)",
    )
    return p


@contextlib.contextmanager
def twin_backed(a: argparse.Namespace) -> Iterator[object]:
    """`TwinFingers` on a twin world holding `a.object`, the hand at `a.wrist` (or beside it)."""
    # deferred: loads pybullet
    from activetouch.sim.twin import open_twin

    cfg = load_config()
    library = ObjectLibrary(paths.objects_dir(paths.data_dir(a.data)))
    library.ensure_builtins()
    spec = library.get(a.object)
    if a.wrist is not None:
        pose = Pose(a.wrist[:3], a.wrist[3:])
    else:  # from above, palm down, 1 cm over the object's box
        pose = Pose([0.0, 0.0, spec.extents[2] / 2 + PALM_PAD_M + 0.01], TOP_QUAT)
    with open_twin(spec, cfg.sim, seed=a.seed, workcell=cfg.workcell) as twin:
        try:
            twin.wrist.move_to(pose)
        except ActiveTouchError as e:
            raise SystemExit(f"error: the hand cannot be at {pose}: {e}") from None
        yield TwinFingers(twin.world, twin.hand)


PALM_PAD_M = 0.0896  # the palm pad's height above the ReFlex base frame (hardware-facts)
TOP_QUAT = (1.0, 0.0, 0.0, 0.0)  # hand +z pointing down (x, y, z, w)


def main(argv: list[str] | None = None) -> int:

    a = build_parser().parse_args(argv)
    if a.object is None and a.wrist is not None:
        raise SystemExit("error: --wrist places the hand against --object: give --object too")
    with contextlib.ExitStack() as stack:
        if a.object is not None:
            fingers = stack.enter_context(twin_backed(a))
        else:
            fingers = KinematicFingers(contact_spool=list(a.contact_spool))
        return _serve(a, fingers)


def _serve(a: argparse.Namespace, fingers: object) -> int:
    done = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: done.set())
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    if a.hand == "reflex-takktile":
        faults = Faults(
            a.loss,
            a.duplicate,
            a.reorder,
            a.corrupt,
            a.truncate,
            a.delay_s,
            stuck_zero=a.stuck_zero,
            stuck_saturated=a.stuck_saturated,
        )
        cfg = EmulatorConfig(
            state_to=a.state_to,
            command_listen=a.command_listen,
            unicast_listen=a.unicast_listen,
            servo_answer_delay_s=a.answer_delay_s,
            rate_hz=a.rate_hz,
            seed=a.seed,
            noise_std=a.noise_std,
            faults=faults,
        )
        if a.zero_offset is not None:
            cfg.baselines = [a.zero_offset] * 38
        zero_points = [
            round(z * g, 4) for z, g in zip(cfg.motor_zero_rad, cfg.gear_ratio, strict=True)
        ]
        with TakktileEmulator(cfg, fingers) as emu:
            print(
                f"reflex-takktile emulator: state to {a.state_to}, commands on "
                f"{emu.command_address} (the group; unicast dropped on "
                f"{emu.unicast_address}); hand.motor_zero_points = "
                f"{zero_points}",
                flush=True,
            )
            done.wait()
            print(
                f"sent {emu.sent} packets, obeyed {len(emu.commands)} commands, dropped "
                f"{emu.dropped_unicast} unicast, {emu.mode_switches[2]} POSITION switches",
                flush=True,
            )
    else:
        cfg_sf = SFEmulatorConfig(seed=a.seed, faults=SFFaults(mute=a.mute))
        with SFEmulator(cfg_sf, fingers) as emu_sf:
            print(
                f"reflex-sf emulator on {emu_sf.port}; motor_zero_points = "
                f"{list(cfg_sf.zero_points)}",
                flush=True,
            )
            done.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
