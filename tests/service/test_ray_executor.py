"""`eval` and `train` on a real Ray (started by the code itself, on this machine, listening on
127.0.0.1 only) give what the local process pool gives. Ray is in the dev extra; the tests
skip where it is not installed. One Ray serves the module and is shut down at its end, its
processes gone."""

from __future__ import annotations

import importlib.util
import json
import os
import socket
import sys
import time
from pathlib import Path

import pytest

from activetouch.cli.main import main
from activetouch.pipelines.executors import RAY_LOCAL_ONLY_ENV
from activetouch.recognition.dataset import Dataset

# Not imported here: the code must be the first to import Ray (executors.RAY_LOCAL_ONLY_ENV).
pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="the Ray executor's tests need Ray (pip install -e '.[dev]')",
)

# Record fields measured in wall-clock seconds (the policy's search, the belief updates, the
# run, and the robot time totals that add planning seconds to them): they differ between runs.
WALL_CLOCK_FIELDS = (
    "planning_s",
    "belief_s",
    "search_s",
    "elapsed_s",
    "total_s",
    "robot_s_to_first_correct",
)


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, ...
        if fields[0] != "Z":
            kids.setdefault(int(fields[1]), []).append(int(entry.name))
    return kids


def descendants() -> set[int]:
    """Live (not zombie) processes below this one: Ray's GCS, raylet, workers, agents."""
    kids, out, todo = _children(), set(), [os.getpid()]
    while todo:
        for k in kids.get(todo.pop(), []):
            out.add(k)
            todo.append(k)
    return out


def _socket_inodes(pid: int) -> set[str]:
    out = set()
    try:
        for fd in (Path("/proc") / str(pid) / "fd").iterdir():
            link = os.readlink(fd)
            if link.startswith("socket:["):
                out.add(link[8:-1])
    except OSError:  # the process ended meanwhile
        pass
    return out


def listening_ips(pids: set[int], exclude: set[str] = frozenset()) -> set[str]:
    """The IP addresses TCP sockets of `pids` listen on (from /proc/net/tcp and tcp6), but
    for the sockets (inodes) in `exclude`."""
    inodes = set().union(*(_socket_inodes(p) for p in pids)) - exclude
    ips = set()
    for table, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        for line in Path(f"/proc/net/{table}").read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] != "0A" or cols[9] not in inodes:  # 0A: LISTEN
                continue
            raw = bytes.fromhex(cols[1].split(":")[0])
            # The kernel prints each 32-bit word in host (little-endian) order.
            raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
            ips.add(socket.inet_ntop(family, raw))
    return ips


def is_loopback(ip: str) -> bool:
    return ip.startswith("127.") or ip in ("::1", "::ffff:127.0.0.1")


@pytest.fixture(scope="module")
def ray_listens_on():
    """Lets the code start Ray itself, with its own settings; yields a function giving the
    addresses Ray's processes (this one's Ray sockets included) listen on. At the end, shuts
    Ray down and checks that every process it started has gone."""
    assert "ray" not in sys.modules, "Ray was imported before the code could set it up"
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv(RAY_LOCAL_ONLY_ENV, raising=False)  # the code sets it (and must)
        before = descendants()
        own = _socket_inodes(os.getpid())  # this process's sockets from other tests

        def addresses() -> set[str]:
            return listening_ips((descendants() - before) | {os.getpid()}, exclude=own)

        yield addresses
        started = {p for p in descendants() - before if is_ray(_cmdline(p))}
        import ray

        ray.shutdown()
        deadline = time.monotonic() + 20
        while started & descendants() and time.monotonic() < deadline:
            time.sleep(0.2)
    left = {p: _cmdline(p) for p in started & descendants()}
    assert started and not left, f"Ray processes still running after shutdown: {left}"


def is_ray(cmdline: str) -> bool:
    """Ray's GCS, raylet, agents (under site-packages/ray/) and workers ("ray::...")."""
    return "/ray/" in cmdline or cmdline.startswith("ray::")


def _cmdline(pid: int) -> str:
    try:
        return (Path("/proc") / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return "?"


def without_wall_clock(run: dict) -> dict:
    assert set(WALL_CLOCK_FIELDS) <= set(run)  # a renamed field would make the test vacuous
    return {k: v for k, v in run.items() if k not in WALL_CLOCK_FIELDS}


@pytest.mark.slow  # 16-25 s with the Ray start: 8 recognitions on each executor
def test_eval_on_ray_gives_the_local_records(trained_home, tmp_path, ray_listens_on):
    base = ["eval", "--data", str(trained_home), "--workers", "2", "--seeds", "0-1"]
    base += ["--max-moves", "3", "--policies", "tree,greedy", "--objects", "cup,sphere"]
    base += ["--set", "grid.step_deg=40"]
    assert main([*base, "--out", str(tmp_path / "local")]) == 0
    assert main([*base, "--out", str(tmp_path / "ray"), "--executor", "ray"]) == 0
    local = json.loads((tmp_path / "local" / "results.json").read_text())
    on_ray = json.loads((tmp_path / "ray" / "results.json").read_text())
    assert len(on_ray["runs"]) == 2 * 2 * 2
    assert [without_wall_clock(r) for r in on_ray["runs"]] == [
        without_wall_clock(r) for r in local["runs"]
    ]
    assert on_ray["summary"]["executor"] == "ray"
    ips = ray_listens_on()
    assert ips and all(is_loopback(ip) for ip in ips), ips


@pytest.mark.slow  # 9-13 s (5-7 s more if it starts the Ray): 2 objects on each executor
def test_train_on_ray_collects_the_local_dataset(tmp_path, ray_listens_on):
    base = ["train", "--objects", "sphere,cup", "--data", str(tmp_path), "--workers", "2"]
    base += ["--set", "grid.step_deg=45"]
    for executor in ("local", "ray"):
        out = ["--dataset", str(tmp_path / f"ds-{executor}"), "--out", str(tmp_path / executor)]
        assert main([*base, *out, "--executor", executor]) == 0
    local, on_ray = Dataset.open(tmp_path / "ds-local"), Dataset.open(tmp_path / "ds-ray")
    assert on_ray.object_names() == local.object_names() == ["cup", "sphere"]
    assert on_ray.meta == local.meta
    # Every object's arrays (pose ids, poses, contacts, pressures, ...) and attrs.
    assert on_ray.checksum() == local.checksum()
    assert on_ray.read("cup").n_grasps > 0
    # ... and so the same model.
    docs = [json.loads((tmp_path / e / "model.json").read_text()) for e in ("local", "ray")]
    for key in ("dataset_checksum", "classifier", "observation", "class_histograms"):
        assert docs[0][key] == docs[1][key]
    assert all(is_loopback(ip) for ip in ray_listens_on())
