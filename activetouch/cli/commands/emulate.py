"""`activetouch emulate reflex-takktile|reflex-sf|baxter|barrett-bh8 ...`: a byte-level device
emulator on this machine (loopback by default), for trying the drivers and the daemon without
hardware."""

from __future__ import annotations

import argparse
import importlib

EMULATORS = {
    "reflex-takktile": ("activetouch.rigs.emulate", True),
    "reflex-sf": ("activetouch.rigs.emulate", True),
    "baxter": ("activetouch.emulators.baxter_bridge", False),
    "barrett-bh8": ("activetouch.emulators.barrett_bh8", False),
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "emulate",
        help="run a device emulator that speaks the device's bytes (ReFlex, Baxter bridge, BH8)",
        description="Run a byte-level emulator of a device. Options after the device name go "
        "to the emulator: `activetouch emulate baxter --help` lists them.",
    )
    p.add_argument("device", choices=sorted(EMULATORS))
    p.add_argument("options", nargs=argparse.REMAINDER, help="the emulator's own options")
    p.set_defaults(func=run_emulate)


def run_emulate(args: argparse.Namespace) -> int:

    module, takes_device = EMULATORS[args.device]
    argv = ([args.device] if takes_device else []) + list(args.options)
    return int(importlib.import_module(module).main(argv) or 0)
