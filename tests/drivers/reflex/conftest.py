from __future__ import annotations

import socket

import pytest

from activetouch.drivers.reflex.takktile import ReflexTakktileConfig, ReflexTakktileHand
from activetouch.emulators.reflex_takktile import (
    EmulatorConfig,
    KinematicFingers,
    TakktileEmulator,
)

MOTOR_ZERO = [56.0, 57.0, 55.5, 53.0]  # joint side (raw * scale / gear)
GEAR = [1.42, 1.42, 1.42, 1.5]
ENCODER_ZERO = [1.0, 2.0, 0.5]
GROUP = "127.0.0.2"  # the loopback address that plays the board's multicast group


def zero_points(joint_zero: list[float]) -> list[float]:
    """hand.motor_zero_points (servo-side motor rad) of joint-side zeros."""
    return [z * g for z, g in zip(joint_zero, GEAR, strict=True)]


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def driver_config(
    state_port: int, command_port: int, command_host: str = GROUP, **kw
) -> ReflexTakktileConfig:
    kw.setdefault("motor_zero_points", zero_points(kw.pop("motor_zero_rad", MOTOR_ZERO)))
    kw.setdefault("encoder_zero_rad", list(ENCODER_ZERO))
    kw.setdefault("mode_switch_sleep_s", 0.005)
    # The driver's 0.2 s suits a board sending at 40 Hz; on a loaded 2-core machine the
    # emulator's thread can be held longer than that (a full run beside other work did).
    kw.setdefault("stream_timeout_s", 0.6)
    return ReflexTakktileConfig(
        type="reflex-takktile",
        state_listen=f"127.0.0.1:{state_port}",
        command_to=f"{command_host}:{command_port}",
        multicast_group="",
        **kw,
    )


@pytest.fixture
def ports() -> tuple[int, int]:
    return free_udp_port(), free_udp_port()


@pytest.fixture
def emulator(ports):
    state_port, command_port = ports
    emu = TakktileEmulator(
        EmulatorConfig(
            state_to=f"127.0.0.1:{state_port}",
            command_listen=f"{GROUP}:{command_port}",
            motor_zero_rad=tuple(MOTOR_ZERO),
            encoder_zero_rad=tuple(ENCODER_ZERO),
            baselines=[300.0 + 10 * i for i in range(38)],
            noise_std=1.0,
        ),
        KinematicFingers(contact_spool=[1.0, 1.5, float("inf")]),
    ).start()
    yield emu
    emu.stop()


@pytest.fixture
def hand(ports, emulator):
    cfg = driver_config(*ports, zero_offsets=[300.0 + 10 * i for i in range(38)])
    h = ReflexTakktileHand(cfg)
    h.connect()
    yield h
    h.disconnect()
