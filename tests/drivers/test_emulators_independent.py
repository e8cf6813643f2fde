"""The emulators share no code with the drivers (issue 23): a bug in a driver's codec or
conventions cannot hide behind the same bug in its emulator. Each emulator module is imported
alone in a fresh interpreter and no driver module may come with it (import-linter's floor
contract says the same statically: drivers | emulators are independent siblings)."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import pytest

import activetouch.emulators

MODULES = sorted(
    f"activetouch.emulators.{m.name}" for m in pkgutil.iter_modules(activetouch.emulators.__path__)
)


def test_every_emulator_is_listed() -> None:
    assert {"activetouch.emulators.reflex_sf", "activetouch.emulators.reflex_takktile"} <= set(
        MODULES
    )
    assert "activetouch.emulators.baxter_bridge" in MODULES


@pytest.mark.parametrize("module", MODULES)
def test_an_emulator_imports_no_driver_module(module: str) -> None:
    code = (
        f"import sys, {module}\n"
        "bad = sorted(m for m in sys.modules if m.startswith(('activetouch.drivers', "
        "'activetouch.rigs', 'activetouch.models')))\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert out.stdout.strip() == "", f"{module} imports {out.stdout.strip()}"
