"""`activetouch hardware check`: the configured hand and arm walked step by step, what is
wrong and the command that fixes it (activetouch.pipelines.hardware_check; the BarrettHand's
steps, `check_bh8_hand`, here)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.table import Table

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import Config, load_config
from activetouch.errors import ConfigError, DeviceFaultError

if TYPE_CHECKING:
    from activetouch.devices import DeviceContext
    from activetouch.pipelines.hardware_check import Step

BH8 = "barrett-bh8"
BH8_CONNECT_FIX = (
    "power the hand, bring its CAN link up at 1 Mbit/s (sudo ip link set can0 type can bitrate "
    "1000000; sudo ip link set can0 up; `ip -details link show can0` says ERROR-ACTIVE) and "
    "check hand.can_interface / hand.can_channel and the bus terminations (docs/drivers.md)"
)
BH8_INIT_FIX = (
    "set hand.initialize_on_connect = true once the hand is clear of people and objects: the "
    "HI moves every finger and the spread to their open stops"
)


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "hardware",
        help="bring-up: check the connected hand and arm, say what is wrong and how to fix it",
        description="Connect the configured devices (nothing moves), measure their streams, "
        "check their readings, calibrations, bridge and robot state. Exit 1 if a step fails.",
    )
    p.add_argument("what", choices=("check",))
    p.add_argument("--seconds", type=float, default=1.0, help="how long to measure each stream")
    p.add_argument("--json", action="store_true", help="print the steps as JSON")
    add_common_options(p)
    p.set_defaults(func=run)


STYLE = {"ok": "green", "warn": "yellow", "fail": "bold red", "skip": "dim"}


def _cells(ids: Any) -> str:
    """Cell ids with their pad: ``29 (F2 cell 5)``."""
    from activetouch.models.bh8 import CELLS_PER_PAD, PAD_NAMES

    return ", ".join(
        f"{int(i)} ({PAD_NAMES[int(i) // CELLS_PER_PAD]} cell {int(i) % CELLS_PER_PAD})"
        for i in ids
    )


def check_bh8_hand(cfg: Config, ctx: DeviceContext, seconds: float) -> list[Step]:
    """The BarrettHand's steps: connect (nothing moves unless ``hand.initialize_on_connect``
    asks for the HI), its pucks, the stream (fresh readings at the poll rate), the tactile
    pads at rest (no cell in contact; masked stuck cells named) and whether it is initialised
    (motion needs it). The check itself moves the hand only if it is initialised and its
    fingers are not open (it opens them to read the pads at rest)."""
    import numpy as np

    from activetouch.pipelines.hardware_check import FAIL, OK, WARN, Step, stream_rate

    hc = cfg.hand
    try:
        hand = hc.make(ctx)
    except Exception as e:
        return [Step("hand", "settings", FAIL, f"{type(e).__name__}: {e}", "fix the setting named")]
    t = time.monotonic()
    try:
        hand.connect()
    except Exception as e:
        # A puck fault names what to check itself.
        fix = "" if isinstance(e, DeviceFaultError) else BH8_CONNECT_FIX
        return [Step("hand", "connect", FAIL, f"{type(e).__name__}: {e}", fix)]
    steps: list[Step] = []
    try:
        took = time.monotonic() - t
        moved = (
            "initialised at connect (hand.initialize_on_connect: the fingers and the spread "
            "moved to their open stops)"
            if hand.initialized
            else "nothing moved"
        )
        steps.append(
            Step(
                "hand",
                "connect",
                OK,
                f"{BH8} connected in {took:.1f} s on {hc.can_interface} {hc.can_channel}; {moved}",
            )
        )
        pucks = "; ".join(
            f"{p.name} firmware {p.vers}"
            + (", tactile pad" if p.tact else ", no tactile pad")
            + (", strain gauge" if p.strain else "")
            for p in hand.pucks.values()
        )
        fault = hand.fault
        steps.append(
            Step("hand", "pucks", FAIL, str(fault), "power-cycle the hand; see the message")
            if fault is not None
            else Step("hand", "pucks", OK, f"{pucks} (positions and strain plausible)")
        )
        expected = 1.0 / hc.control_period_s
        hz = stream_rate(hand.state, seconds, lambda s: s.stamp)
        stats = hand.stats()
        frames = f"frames: {stats['received']} received, {stats['refused']} refused"
        if hz == 0 or hand.state().stale:
            steps.append(
                Step(
                    "hand",
                    "stream",
                    FAIL,
                    f"no fresh readings ({hz:.0f} Hz): a puck is silent or the bus is down; "
                    + frames,
                    BH8_CONNECT_FIX,
                )
            )
        elif hz < expected / 2:
            steps.append(
                Step(
                    "hand",
                    "stream",
                    WARN,
                    f"{hz:.0f} Hz (expected ~{expected:.0f}: one reading per "
                    f"hand.control_period_s = {hc.control_period_s:g} s); {frames}",
                    "check the bus load (candump) and that this PC is not overloaded",
                )
            )
        else:
            steps.append(
                Step("hand", "stream", OK, f"{hz:.0f} Hz (poll rate {expected:.0f} Hz); {frames}")
            )
        opened = ""
        if hand.initialized and hand.fault is None:
            st = hand.state()
            if not np.all(np.abs(st.finger_angles) <= hc.open_tolerance_rad):
                try:  # initialised: allowed; the pads are read with the hand open
                    hand.open()
                    opened = "; the fingers were opened first"
                except Exception as e:
                    opened = f"; opening the fingers first failed ({type(e).__name__}: {e})"
        st = hand.state()
        contact = np.flatnonzero(st.contact)
        masked = np.flatnonzero(getattr(st, "masked", np.zeros(0, dtype=bool)))
        where = "with the hand open" if hand.initialized else "where the fingers are"
        if contact.size:
            steps.append(
                Step(
                    "hand",
                    "tactile at rest",
                    FAIL,
                    f"cells {_cells(contact)} read contact {where}, nothing touching{opened}",
                    "clear the pads and reconnect (the pads are tared at connect); a cell that "
                    "stays on: check its pad and the puck's cable",
                )
            )
        elif masked.size:
            steps.append(
                Step(
                    "hand",
                    "tactile at rest",
                    WARN,
                    f"cells {_cells(masked)} stuck at full scale: masked (never reported); "
                    f"no other cell in contact {where}{opened}",
                    "check those pads and their pucks' cables; power-cycle the hand",
                )
            )
        else:
            steps.append(
                Step(
                    "hand",
                    "tactile at rest",
                    OK,
                    f"no cell of {len(st.contact)} in contact {where} (tared at connect){opened}",
                )
            )
        if hand.initialized:
            steps.append(
                Step(
                    "hand",
                    "initialisation",
                    OK,
                    "initialised (HI): open, preshape and guarded_close allowed",
                )
            )
        else:
            steps.append(
                Step(
                    "hand",
                    "initialisation",
                    WARN,
                    "not initialised: open, preshape and guarded_close are refused until the "
                    "HI (hand.initialize_on_connect = false)",
                    BH8_INIT_FIX,
                )
            )
    finally:
        hand.disconnect()
    return steps


def bh8_hardware_check(cfg: Config, root: Path, seconds: float = 1.0) -> list[Step]:
    """`hardware_check` for a ``barrett-bh8`` hand: its own steps, then the arm's."""
    from activetouch.devices import DeviceContext
    from activetouch.pipelines.hardware_check import check_arm

    ctx = DeviceContext(cfg, root)
    try:
        return check_bh8_hand(cfg, ctx, seconds) + check_arm(cfg, ctx, seconds)
    finally:
        ctx.close()


def run(args: argparse.Namespace) -> int:
    # deferred: loads scipy
    from activetouch.pipelines.hardware_check import FAIL, hardware_check

    if not args.seconds > 0:
        raise ConfigError(f"--seconds must be > 0, got {args.seconds}")
    cfg = load_config(args.config, args.overrides)
    check = bh8_hardware_check if cfg.hand.type == BH8 else hardware_check
    steps = check(cfg, paths.data_dir(args.data), args.seconds)
    if args.json:
        print(json.dumps({"steps": [s.as_dict() for s in steps]}, indent=2))
    else:
        table = Table(title=f"hardware check: hand {cfg.hand.type}, arm {cfg.arm.type}")
        for col in ("device", "step", "", "what was found", "fix"):
            table.add_column(col, overflow="fold")
        for s in steps:
            table.add_row(s.device, s.name, f"[{STYLE[s.status]}]{s.status}[/]", s.detail, s.fix)
        Console(soft_wrap=True).print(table)
    return 1 if any(s.status == FAIL for s in steps) else 0
