"""Run a ReFlex emulator from the command line until interrupted.

    python -m activetouch.drivers.reflex.emulate reflex-takktile --state-to 127.0.0.1:11333 \
        --command-listen 127.0.0.1:11334 --contact-spool 1.0 1.5 inf --loss 0.05
    python -m activetouch.drivers.reflex.emulate reflex-sf      # prints the pty to open

(`python -m activetouch emulate ...` should forward here: the CLI lives outside this package.)
"""

from __future__ import annotations

import argparse
import math
import signal
import threading


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="activetouch emulate", description=__doc__.split("\n")[0])
    p.add_argument("hand", choices=["reflex-takktile", "reflex-sf"])
    p.add_argument("--state-to", default="127.0.0.1:11333", help="driver's hand.state_listen")
    p.add_argument("--command-listen", default="127.0.0.1:11334", help="driver's hand.command_to")
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
    p.add_argument("--noise-std", type=float, default=0.0)
    p.add_argument("--zero-offset", type=float, default=0.0, help="raw zero of every sensor")
    for name in ("loss", "duplicate", "reorder", "corrupt", "truncate"):
        p.add_argument(f"--{name}", type=float, default=0.0, help=f"fraction of packets ({name})")
    p.add_argument("--delay-s", type=float, default=0.0)
    p.add_argument("--stuck-zero", type=int, nargs="*", default=[], help="sensor ids reading 0")
    p.add_argument("--stuck-saturated", type=int, nargs="*", default=[], help="ids reading max")
    p.add_argument("--mute", type=int, nargs="*", default=[], help="SF servo ids not answering")
    return p


def main(argv: list[str] | None = None) -> int:
    from activetouch.drivers.reflex.emulator_takktile import KinematicFingers

    a = build_parser().parse_args(argv)
    fingers = KinematicFingers(contact_spool=list(a.contact_spool))
    done = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: done.set())
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    if a.hand == "reflex-takktile":
        from activetouch.drivers.reflex.emulator_takktile import (
            EmulatorConfig,
            Faults,
            TakktileEmulator,
        )

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
            rate_hz=a.rate_hz,
            seed=a.seed,
            noise_std=a.noise_std,
            zero_offsets=[a.zero_offset] * 38,
            faults=faults,
        )
        with TakktileEmulator(cfg, fingers) as emu:
            print(
                f"reflex-takktile emulator: state to {a.state_to}, commands on "
                f"{a.command_listen}; motor_zero_rad = {list(cfg.motor_zero_rad)}",
                flush=True,
            )
            done.wait()
            print(f"sent {emu.sent} packets, obeyed {len(emu.commands)} commands", flush=True)
    else:
        from activetouch.drivers.reflex.emulator_sf import SFEmulator, SFEmulatorConfig, SFFaults

        cfg_sf = SFEmulatorConfig(seed=a.seed, faults=SFFaults(mute=a.mute))
        with SFEmulator(cfg_sf, fingers) as emu_sf:
            print(
                f"reflex-sf emulator on {emu_sf.port}; motor_zero_rad = "
                f"{list(cfg_sf.motor_zero_rad)}",
                flush=True,
            )
            done.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
