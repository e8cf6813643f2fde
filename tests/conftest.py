"""Shared fixtures: loopback Zenoh sessions (a listening node side and a client of it), and a
small trained model on three builtin objects, shared by the service tests (built once)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from activetouch import paths
from activetouch.config import Config, load_config
from activetouch.model import load_model
from activetouch.objects.library import ObjectLibrary
from activetouch.pipelines.training import collect, fit_and_save
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint

SMALL_OBJECTS = ["cup", "sphere", "bottle"]


def small_config() -> Config:
    # A coarse grid keeps collection to a few seconds.
    return load_config(None, ["grid.step_deg=40"])


@pytest.fixture(scope="session")
def trained_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("home")
    cfg = small_config()
    lib = ObjectLibrary(paths.objects_dir(root))
    lib.ensure_builtins(SMALL_OBJECTS)
    ds = paths.default_dataset(root)
    collect(lib, ds, SMALL_OBJECTS, cfg, workers=1)
    fit_and_save(ds, SMALL_OBJECTS, cfg, paths.default_model(root))
    return root


@pytest.fixture(scope="session")
def small_model(trained_home: Path):
    return load_model(paths.default_model(trained_home))


FAKE_ROBOT = "fakebot"


@pytest.fixture
def start_fake_daemon(trained_home: Path):
    """`start(overrides)` -> (Daemon, endpoint): the whole daemon in this process on the fake
    devices (no physics), on a free loopback port; closed at the end of the test."""
    from activetouch.cli.commands.serve import resolve_mode
    from activetouch.daemon.process import Daemon, DaemonOptions

    started: list = []

    def start(overrides: list[str] = ()):  # type: ignore[assignment]
        ep = loopback_endpoint()
        cfg = load_config(
            None,
            [
                "hand.type=fake",
                "arm.type=fake",
                f"service.robot={FAKE_ROBOT}",
                f'service.listen=["{ep}"]',
                *overrides,
            ],
        )
        opts = DaemonOptions(
            mode=resolve_mode(None, cfg),
            role="all",
            data=trained_home,
            model_dir=paths.default_model(trained_home),
            cfg=cfg,
        )
        daemon = Daemon(opts)
        started.append(daemon)
        daemon.start()
        return daemon, ep

    yield start
    for d in started:
        d.close()


@pytest.fixture
def endpoint() -> str:
    return loopback_endpoint()


@pytest.fixture
def node_session(endpoint: str) -> Iterator[ZenohSession]:
    with ZenohSession(ZenohSettings(listen=(endpoint,))) as zs:
        yield zs


@pytest.fixture
def client_session(endpoint: str, node_session: ZenohSession) -> Iterator[ZenohSession]:
    with ZenohSession(ZenohSettings.client(endpoint)) as zs:
        yield zs
