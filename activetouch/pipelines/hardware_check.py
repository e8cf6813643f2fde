"""Bring-up check (`activetouch hardware check`): walk the configured hand and arm step by step
and say what is wrong and the command that fixes it.

Nothing moves: connecting a driver commands no motion (a hand holds where it is, Baxter's
arm only listens), and the check only reads. Each step is a `Step`: ok, warn (works, but
look at it) or fail (the robot cannot be used so), with what it measured and the fix.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from activetouch.calibration import store
from activetouch.config import Config
from activetouch.devices import DeviceContext
from activetouch.errors import DeviceFaultError
from activetouch.models.bh8 import CELLS_PER_PAD, PAD_NAMES

OK, WARN, FAIL, SKIP = "ok", "warn", "fail", "skip"


@dataclass
class Step:
    device: str  # hand | arm
    name: str
    status: str  # ok | warn | fail | skip
    detail: str
    fix: str = ""

    def as_dict(self) -> dict[str, str]:
        return asdict(self)


# What to look at when a device does not connect, by type.
CONNECT_FIX = {
    "reflex-takktile": "power the hand, check its Ethernet link and that hand.state_listen / "
    "hand.multicast_group / hand.interface are this PC's (docs/drivers.md)",
    "reflex-sf": "plug the hand's USB, check hand.port (ls /dev/ttyUSB*) and that you may open "
    "it (the dialout group)",
    "baxter": "start Baxter and zenoh-bridge-ros1 on its ROS master, and check arm.connect is "
    "the bridge's Zenoh endpoint (docs/protocols/baxter.md)",
}
STREAM_HZ = {"reflex-takktile": 40.0, "reflex-sf": 40.0, "baxter": 100.0}


def stream_rate(read: Callable[[], Any], seconds: float, stamp: Callable[[Any], float]) -> float:
    """Distinct readings per second seen by polling `read` for `seconds`."""
    seen: set[float] = set()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        with contextlib.suppress(Exception):  # a lost stream shows as a low rate
            seen.add(float(stamp(read())))
        time.sleep(0.002)
    return len(seen) / seconds


def stream_step(
    kind: str, name: str, hz: float, dev_type: str, dead: bool, dead_text: str, slow_fix: str
) -> Step:
    """The verdict on a device's stream: dead (FAIL), under half its rate (WARN), or OK."""
    expected = STREAM_HZ.get(dev_type)
    if dead:
        return Step(kind, name, FAIL, dead_text, CONNECT_FIX.get(dev_type, ""))
    if expected and hz < expected / 2:
        return Step(kind, name, WARN, f"{hz:.0f} Hz (expected ~{expected:g})", slow_fix)
    return Step(kind, name, OK, f"{hz:.0f} Hz")


def _connect(kind: str, dev_type: str, make: Callable[[], Any]) -> tuple[Any, Step]:
    fix = CONNECT_FIX.get(dev_type, "")
    try:
        dev = make()
    except Exception as e:
        return None, Step(
            kind, "settings", FAIL, f"{type(e).__name__}: {e}", "fix the setting named"
        )
    t = time.monotonic()
    try:
        dev.connect()
    except Exception as e:
        text = f"{type(e).__name__}: {e}"
        # A fault names what to check itself (servo, zero points, calibration).
        return None, Step(kind, "connect", FAIL, text, "" if "Fault" in text else fix)
    return dev, Step(kind, "connect", OK, f"{dev_type} connected in {time.monotonic() - t:.1f} s")


def check_hand(cfg: Config, root: Path, ctx: DeviceContext, seconds: float) -> list[Step]:
    hand_type = cfg.hand.type
    steps: list[Step] = []
    hand, step = _connect("hand", hand_type, lambda: cfg.hand.make(ctx))
    steps.append(step)
    if hand is None:
        return steps
    try:
        hz = stream_rate(hand.state, seconds, lambda s: s.stamp)
        dead = bool(getattr(hand.state(), "stale", False)) or hz == 0
        steps.append(
            stream_step(
                "hand", "stream", hz, hand_type, dead, f"no fresh state ({hz:.0f} Hz)",
                "check the link's load and cabling",
            )
        )  # fmt: skip
        fault = getattr(hand, "fault", None)
        steps.append(
            Step(
                "hand", "servo readings", FAIL, str(fault), "power-cycle the hand; see the message"
            )
            if fault
            else Step(
                "hand", "servo readings", OK, "plausible (checked at connect and on every reading)"
            )
        )
        if cfg.hand.simulated:
            return steps
        device = store.device_name(cfg, None)
        kinds = ("tactile", "fingers") if hand_type == "reflex-takktile" else ("fingers",)
        for kind in kinds:
            rec = store.load(root, kind, device)
            why = store.staleness(rec, kind)
            if rec is None:
                if kind == "tactile" and getattr(cfg.hand, "zero_on_connect", False):
                    steps.append(
                        Step(
                            "hand",
                            "tactile calibration",
                            OK,
                            "zeroed at connect (hand.zero_on_connect)",
                        )
                    )
                    continue
                status = FAIL if kind == "tactile" else WARN
                detail = f"none stored for {device}"
                if kind == "fingers":
                    detail += " (the configured zero points are used)"
                steps.append(
                    Step(
                        "hand",
                        f"{kind} calibration",
                        status,
                        detail,
                        f"activetouch calibrate {kind} (or calibrate import FILE)",
                    )
                )
            else:
                age = rec.age_days()
                steps.append(
                    Step(
                        "hand",
                        f"{kind} calibration",
                        WARN if why else OK,
                        f"{rec.method.get('procedure', kind)} of {rec.measured_at[:19]} "
                        f"({age:.1f} days old)",
                        f"activetouch calibrate {kind}" if why else "",
                    )
                )
        masked = getattr(hand, "masked", None)
        if masked is not None and int(masked.sum()):
            ids = [int(i) for i in masked.nonzero()[0]]
            steps.append(
                Step(
                    "hand",
                    "contacts at rest",
                    WARN,
                    f"sensors {ids} read contact with the hand open: masked",
                    "activetouch calibrate tactile",
                )
            )
        elif hand_type == "reflex-takktile":
            n = int(hand.state().contact.sum())
            steps.append(
                Step(
                    "hand",
                    "contacts at rest",
                    FAIL if n else OK,
                    f"{n} sensors in contact with nothing touching",
                    "activetouch calibrate tactile" if n else "",
                )
            )
    finally:
        hand.disconnect()
    return steps


def check_arm(cfg: Config, ctx: DeviceContext, seconds: float) -> list[Step]:
    arm_type = cfg.arm.type
    steps: list[Step] = []
    arm, step = _connect("arm", arm_type, lambda: cfg.arm.make(ctx))
    steps.append(step)
    if arm is None:
        return steps
    try:
        hz = stream_rate(arm.joint_state, seconds, lambda s: s.stamp)
        steps.append(
            stream_step(
                "arm", "joint states", hz, arm_type, hz == 0, "none fresh",
                "check the bridge's network",
            )
        )  # fmt: skip
        fmt = getattr(arm, "bridge_format", None)
        if fmt is not None:
            ns = getattr(arm, "bridge_namespace", "")
            steps.append(
                Step(
                    "arm",
                    "bridge keys",
                    OK,
                    f"{fmt}{f' (namespace {ns!r})' if ns else ''}; arm.bridge_format = "
                    f"{getattr(cfg.arm, 'bridge_format', '?')}",
                )
            )
            steps.append(
                Step(
                    "arm",
                    "commands bridged",
                    SKIP,
                    "not checked (it takes a motion); a bridge that forwards no joint_command is "
                    "named at the first move (zenoh-plugin-ros1 #92)",
                    "run the bridge with mode auto and a ROS publisher-side bridge of "
                    "/robot/limb/<side>/joint_command",
                )
            )
        robot_state = getattr(arm, "robot_state", None)
        if callable(robot_state):
            rs = robot_state()
            deadline = time.monotonic() + 2.0  # one late message is not "no /robot/state"
            while rs is None and time.monotonic() < deadline:
                time.sleep(0.02)
                rs = robot_state()
            if rs is None:
                steps.append(
                    Step(
                        "arm",
                        "robot state",
                        FAIL,
                        "no /robot/state",
                        "check the bridge bridges /robot/state",
                    )
                )
            elif rs.stopped or rs.error or not rs.enabled:
                steps.append(
                    Step(
                        "arm",
                        "robot state",
                        FAIL,
                        rs.describe(),
                        "release the e-stop, then enable the robot (rosrun baxter_tools "
                        "enable_robot.py -e, or arm.enable_on_connect = true)",
                    )
                )
            else:
                steps.append(Step("arm", "robot state", OK, rs.describe()))
    finally:
        arm.disconnect()
    return steps


def hardware_check(cfg: Config, root: Path, seconds: float = 1.0) -> list[Step]:
    """Every step for the configured hand and arm (a simulated one is checked as well, briefly);
    the BarrettHand has steps of its own (`check_bh8_hand`)."""
    ctx = DeviceContext(cfg, root)
    try:
        if cfg.hand.type == BH8:
            hand_steps = check_bh8_hand(cfg, ctx, seconds)
        else:
            hand_steps = check_hand(cfg, root, ctx, seconds)
        return hand_steps + check_arm(cfg, ctx, seconds)
    finally:
        ctx.close()


# -- the BarrettHand BH8 ---------------------------------------------------------------------

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


def _cells(ids: Any) -> str:
    """Cell ids with their pad: ``29 (F2 cell 5)``."""
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
