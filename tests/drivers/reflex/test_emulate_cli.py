"""The emulator as a separate process: a driver connects to it and closes on its object."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator

from activetouch.drivers.reflex.takktile import ReflexTakktileHand
from activetouch.interfaces import Grasp

from .conftest import driver_config, free_udp_port

ZERO = [56.0, 57.0, 55.5, 53.0]  # the emulator's default motor zeros


@contextlib.contextmanager
def emulator_process(argv: list[str], wait_s: float) -> Iterator[None]:
    """The emulator started from `argv`, once it has announced itself; stopped by its pid on
    exit, which it must leave cleanly."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
    try:
        assert "reflex-takktile emulator" in proc.stdout.readline()
        yield
    finally:
        proc.terminate()
        proc.wait(timeout=wait_s)
    assert proc.returncode == 0


def driver_close(state_port: int, command_port: int) -> tuple[Grasp, tuple[str, ...]]:
    """One guarded close (then open) by the driver against the emulator: the grasp and each
    finger's stop reason."""
    hand = ReflexTakktileHand(
        driver_config(
            state_port,
            command_port,
            motor_zero_rad=ZERO,
            encoder_zero_rad=[0.0] * 3,
            zero_on_connect=True,  # the emulator sits at a real hand's baselines
        )
    )
    hand.connect()
    try:
        g = hand.guarded_close()
        reasons = hand.last_close_reasons
        hand.open()
    finally:
        hand.disconnect()
    return g, reasons


def test_emulator_process_serves_the_driver():
    sp, cp = free_udp_port(), free_udp_port()
    argv = [sys.executable, "-m", "activetouch.rigs.emulate", "reflex-takktile"]
    argv += ["--state-to", f"127.0.0.1:{sp}", "--command-listen", f"127.0.0.2:{cp}"]
    argv += ["--contact-spool", "0.5", "0.5", "0.5"]
    with emulator_process(argv, wait_s=5):
        g, reasons = driver_close(sp, cp)
    assert reasons == ("contact",) * 3
    assert g.n_contacts >= 6


def test_twin_backed_emulator_process_closes_on_the_object(trained_home):
    """`activetouch emulate reflex-takktile --object sphere`: the fingers and pads are the
    twin's, so the driver's close stops on the sphere and feels it."""
    sp, cp = free_udp_port(), free_udp_port()
    argv = [sys.executable, "-m", "activetouch", "emulate", "reflex-takktile"]
    argv += ["--state-to", f"127.0.0.1:{sp}", "--command-listen", f"127.0.0.2:{cp}"]
    argv += ["--object", "sphere", "--data", str(trained_home)]
    with emulator_process(argv, wait_s=10):
        g, reasons = driver_close(sp, cp)
    assert reasons == ("contact",) * 3
    # Every finger stopped on its pads; the final reading feels the sphere on two or three of
    # them (the twin's own close from above feels it on fingers 0 and 1).
    assert len({int(i) // 9 for i in g.sensor_ids if i < 27}) >= 2
    assert g.n_contacts >= 3
    bad = subprocess.run(
        [*argv[:5], "--wrist", "0", "0", "0", "0", "0", "0", "1"], capture_output=True, text=True
    )
    assert bad.returncode != 0 and "give --object too" in bad.stderr
    assert "Traceback" not in bad.stderr
