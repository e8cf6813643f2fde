"""The emulator as a separate process: a driver connects to it and closes on its object."""

from __future__ import annotations

import subprocess
import sys

from activetouch.drivers.reflex.takktile import ReflexTakktileHand

from .conftest import driver_config, free_udp_port

ZERO = [56.0, 57.0, 55.5, 53.0]  # the emulator's default motor zeros


def test_emulator_process_serves_the_driver():
    sp, cp = free_udp_port(), free_udp_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "activetouch.drivers.reflex.emulate",
            "reflex-takktile",
            "--state-to",
            f"127.0.0.1:{sp}",
            "--command-listen",
            f"127.0.0.1:{cp}",
            "--contact-spool",
            "0.5",
            "0.5",
            "0.5",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert "reflex-takktile emulator" in proc.stdout.readline()
        hand = ReflexTakktileHand(
            driver_config(sp, cp, motor_zero_rad=ZERO, encoder_zero_rad=[0.0] * 3)
        )
        hand.connect()
        try:
            g = hand.guarded_close()
            assert hand.last_close_reasons == ("contact",) * 3
            assert g.n_contacts >= 6
            hand.open()
        finally:
            hand.disconnect()
    finally:
        proc.terminate()
        proc.wait(timeout=5)
    assert proc.returncode == 0
