"""The TakkTile driver loads its stored tactile calibration at connect (issue 14's hook): a
board with known offsets, `calibrate tactile` stores them, and a hand made from config reads
pressures near zero with them."""

from __future__ import annotations

import numpy as np

from activetouch.cli.main import main
from activetouch.config import load_config
from activetouch.devices import make_devices
from tests.calibration.board import NoisyBoard


def _settings(board: NoisyBoard) -> list[str]:
    return [
        "hand.type=reflex-takktile",
        f"hand.state_listen=127.0.0.1:{board.state_port}",
        f"hand.command_to=127.0.0.1:{board.command_port}",
        "hand.multicast_group=",
    ]


def test_the_driver_loads_its_calibration_at_connect(tmp_path) -> None:
    offsets = np.random.default_rng(5).uniform(200.0, 3000.0, 38)
    with NoisyBoard(offsets, noise=2.0, seed=1) as board:
        args = ["calibrate", "tactile", "--no-open", "--device", "reflex-B7", "--duration", "1"]
        args += ["--data", str(tmp_path)]
        for s in _settings(board):
            args += ["--set", s]
        assert main(args) == 0
        cfg = load_config(None, [*_settings(board), "hand.serial=reflex-B7", "arm.type=fake"])
        devices = make_devices(cfg, tmp_path)
        try:
            hand = devices.hand
            # Each offset is a mean of ~40 samples of noise 2 (σ ≈ 0.3): 2.5 is ~8σ, so none of
            # the 38 misses by chance, even on a loaded machine that takes half the samples.
            np.testing.assert_allclose(hand.offsets, offsets, atol=2.5)
            assert np.abs(hand.state().pressures).max() < 20.0  # zeroed: nothing touches
        finally:
            devices.close()
        # Without a stored record for its name, the driver keeps the configured offsets (0).
        cfg = load_config(None, [*_settings(board), "hand.serial=reflex-none", "arm.type=fake"])
        devices = make_devices(cfg, tmp_path)
        try:
            assert np.abs(devices.hand.offsets).max() == 0.0
        finally:
            devices.close()
