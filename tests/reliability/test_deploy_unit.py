"""deploy/activetouch.service and its hardware drop-in keep their hardening (issue 16,
finding 10): the directives are checked here by parsing the files, and, where systemd-analyze
exists, `systemd-analyze security --offline=true` must score both at 3.0 or lower."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
UNIT = DEPLOY / "activetouch.service"
HARDWARE = DEPLOY / "activetouch-hardware.conf"
MAX_EXPOSURE = 3.0


def parse(text: str) -> dict[str, dict[str, list[str]]]:
    """systemd unit syntax: [Section], Key=Value (repeatable), backslash continuations, #/;
    comments. Every assignment of a key is kept in order, empty ones (a reset) included."""
    out: dict[str, dict[str, list[str]]] = {}
    section: dict[str, list[str]] | None = None
    lines = iter(text.splitlines())
    for raw in lines:
        line = raw.strip()
        while line.endswith("\\"):
            line = line[:-1] + " " + next(lines).strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            section = out.setdefault(line.strip("[]"), {})
            continue
        assert section is not None and "=" in line, raw
        key, value = (s.strip() for s in line.split("=", 1))
        section.setdefault(key, []).append(value)
    return out


def service(*texts: str) -> dict[str, list[str]]:
    """The [Service] settings of a unit and its drop-ins, in order; `Key=` resets a list."""
    merged: dict[str, list[str]] = {}
    for text in texts:
        for key, values in parse(text).get("Service", {}).items():
            for value in values:
                if value:
                    merged.setdefault(key, []).append(value)
                else:
                    merged[key] = []
    return merged


def one(svc: dict[str, list[str]], key: str) -> str:
    assert svc.get(key), f"{key}= missing"
    return svc[key][-1]


def test_unit_hardening_directives() -> None:
    svc = service(UNIT.read_text())
    assert "CapabilityBoundingSet" in svc and svc["CapabilityBoundingSet"] == []
    assert "AmbientCapabilities" in svc and svc["AmbientCapabilities"] == []
    for key, value in {
        "User": "activetouch",
        "NoNewPrivileges": "yes",
        "ProtectSystem": "strict",
        "ProtectHome": "yes",
        "PrivateTmp": "yes",
        "PrivateDevices": "yes",
        "DevicePolicy": "closed",
        "PrivateUsers": "yes",
        "ProtectKernelTunables": "yes",
        "ProtectKernelModules": "yes",
        "ProtectKernelLogs": "yes",
        "ProtectControlGroups": "yes",
        "ProtectClock": "yes",
        "ProtectHostname": "yes",
        "ProtectProc": "invisible",
        "RestrictNamespaces": "yes",
        "RestrictRealtime": "yes",
        "RestrictSUIDSGID": "yes",
        "LockPersonality": "yes",
        "SystemCallArchitectures": "native",
        "UMask": "0077",
        "IPAddressDeny": "any",
        "StateDirectory": "activetouch",
    }.items():
        assert one(svc, key) == value, key
    assert set(one(svc, "RestrictAddressFamilies").split()) == {
        "AF_INET", "AF_INET6", "AF_UNIX", "AF_NETLINK",
    }  # fmt: skip
    assert svc["SystemCallFilter"][0] == "@system-service"
    assert any(v.startswith("~") and "@privileged" in v for v in svc["SystemCallFilter"])
    assert one(svc, "IPAddressAllow") == "localhost"
    assert re.fullmatch(r"\d+[KMG]", one(svc, "MemoryMax"))
    assert 0 < int(one(svc, "TasksMax")) <= 4096
    # numba compiles to executable memory: MemoryDenyWriteExecute would break the planner.
    assert "MemoryDenyWriteExecute" not in svc
    # The watchdog and notify protocol the daemon speaks.
    assert one(svc, "Type") == "notify" and one(svc, "NotifyAccess") == "main"
    assert "--sim" in one(svc, "ExecStart")


def test_hardware_drop_in_opens_only_the_serial_port() -> None:
    svc = service(UNIT.read_text(), HARDWARE.read_text())
    assert "--hardware" in one(svc, "ExecStart") and len(svc["ExecStart"]) == 1
    assert one(svc, "PrivateDevices") == "no"
    assert one(svc, "DevicePolicy") == "closed"
    assert svc["DeviceAllow"] == ["char-ttyUSB rw"]
    # Everything else stays as strict as the twin's unit.
    for key in ("NoNewPrivileges", "ProtectSystem", "ProtectHome", "SystemCallFilter", "UMask"):
        assert svc[key] == service(UNIT.read_text())[key], key


def _exposure(unit: Path) -> float:
    run = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", "--no-pager", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", run.stdout + run.stderr)
    assert m, run.stdout + run.stderr
    return float(m.group(1))


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="needs systemd-analyze")
def test_systemd_analyze_security_scores_ok(tmp_path: Path) -> None:
    assert _exposure(UNIT) <= MAX_EXPOSURE
    # The unit with the hardware drop-in applied (a drop-in's settings come after the unit's).
    body = UNIT.read_text().split("[Install]")[0]
    merged = tmp_path / "activetouch.service"
    merged.write_text(body + HARDWARE.read_text().replace("[Service]", "", 1) + "\n")
    assert _exposure(merged) <= MAX_EXPOSURE
