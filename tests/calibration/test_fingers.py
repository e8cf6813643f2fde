"""Finger zero calibration against the TakkTile emulator with slack tendons and wrong
configured zeros whose true values the test knows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from activetouch.calibration.fingers import FingerSettings, calibrate_fingers, taut_point
from activetouch.calibration.tactile import CalibrationRefusedError
from activetouch.drivers.reflex.takktile import ReflexTakktileConfig, ReflexTakktileHand
from activetouch.emulators.reflex_takktile import (
    EmulatorConfig,
    KinematicFingers,
    TakktileEmulator,
)

from .board import free_udp_port

TRUE_MOTOR_ZERO = (56.0, 57.0, 55.5, 53.0)
TRUE_ENCODER_ZERO = (1.0, 2.0, 0.5)
INVERTED = (1, -1, 1, -1)
GEAR = (1.42, 1.42, 1.42, 1.5)


class SlackFingers:
    """KinematicFingers behind slack tendons: nothing moves until spool > slack[f]."""

    def __init__(self, slack: list[float], base: KinematicFingers) -> None:
        self.slack = np.asarray(slack, dtype=np.float64)
        self.base = base

    def _taut(self, spool: np.ndarray) -> np.ndarray:
        return np.maximum(0.0, np.asarray(spool) - self.slack)

    def joints(self, spool, preshape):
        return self.base.joints(self._taut(spool), preshape)

    def forces(self, spool, preshape):
        return self.base.forces(self._taut(spool), preshape)

    def stall_spool(self):
        return self.base.stall_spool() + self.slack


def run(slack, zero_error, contact=(math.inf,) * 3, settings=None):
    state_port, cmd_port = free_udp_port(), free_udp_port()
    emu = TakktileEmulator(
        EmulatorConfig(
            state_to=f"127.0.0.1:{state_port}",
            command_listen=f"127.0.0.1:{cmd_port}",
            motor_zero_rad=TRUE_MOTOR_ZERO,
            encoder_zero_rad=TRUE_ENCODER_ZERO,
            baselines=[400.0] * 38,
            noise_std=1.0,
        ),
        SlackFingers(slack, KinematicFingers(contact_spool=list(contact))),
    ).start()
    cfg = ReflexTakktileConfig(
        type="reflex-takktile",
        state_listen=f"127.0.0.1:{state_port}",
        command_to=f"127.0.0.1:{cmd_port}",
        multicast_group="",
        motor_zero_points=[
            (z + e) * g for z, e, g in zip(TRUE_MOTOR_ZERO, zero_error, GEAR, strict=True)
        ],
        encoder_zero_rad=[0.0, 0.0, 0.0],
        zero_offsets=[400.0] * 38,
    )
    hand = ReflexTakktileHand(cfg)
    try:
        hand.connect()
        return calibrate_fingers(hand, "emu", settings), hand, emu
    finally:
        hand.disconnect()
        emu.stop()


def test_taut_point_from_a_line():
    spool = np.arange(0.0, 0.5, 0.02)
    prox = 0.3 + 0.8 * np.maximum(0.0, spool - 0.233)
    taut, slope, n, rms = taut_point(spool, prox, 0.3, 0.004)
    assert abs(taut - 0.233) < 1e-6 and abs(slope - 0.8) < 1e-6 and n > 5 and rms < 1e-9


def test_finger_zeros_recovered_within_0p02_rad():
    slack = [0.35, 0.2, 0.5]
    (rec, _fit), _hand, emu = run(slack, zero_error=(0.3, -0.25, 0.15, 0.0))
    true = np.array(TRUE_MOTOR_ZERO[:3]) + np.array(INVERTED[:3]) * np.array(slack)
    got = np.asarray(rec.values["motor_zero_rad"][:3])
    err = np.abs(got - true)
    assert err.max() < 0.02, (got, true)
    assert rec.values["motor_zero_rad"][3] == pytest.approx(TRUE_MOTOR_ZERO[3])
    enc = np.asarray(rec.values["encoder_zero_rad"])
    assert np.abs(enc - np.array(TRUE_ENCODER_ZERO)).max() < 0.002
    # After applying, the hand is open with the tendons just taut: emulator spool = slack.
    spool, _ = emu.joint_state()
    assert np.abs(spool - np.array(slack)).max() < 0.03
    assert all(n >= 2 for n in rec.quality["fit_points"])


def test_blocked_finger_refused_and_servos_restored():
    # Finger 1 meets an object as soon as its tendon is taut: its servo stalls, encoder still.
    with pytest.raises(CalibrationRefusedError, match="finger 1 is blocked"):
        run([0.2, 0.2, 0.2], zero_error=(0.0,) * 4, contact=(math.inf, 0.0, math.inf))


def test_timeout_refused():
    with pytest.raises(CalibrationRefusedError, match="not done within"):
        run([0.6, 0.6, 0.6], (0.0,) * 4, settings=FingerSettings(timeout_s=0.3))
