"""activetouch.storage: atomic writes are all-or-nothing, locks serialise writers."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import activetouch
from activetouch import storage
from activetouch.storage import (
    atomic_write_bytes,
    atomic_write_text,
    locked,
    replace_dir,
)

REPO = Path(activetouch.__file__).resolve().parents[1]


def _run(script: str, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-c", script, *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _leftovers(d: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name not in keep)


def test_write_replaces_and_is_private(tmp_path: Path) -> None:
    f = tmp_path / "a.json"
    atomic_write_text(f, "old\n")
    atomic_write_bytes(f, b"new\n")
    assert f.read_bytes() == b"new\n"
    # mkstemp's mode, which every writer this replaced gave its files.
    assert stat.S_IMODE(f.stat().st_mode) == 0o600
    assert _leftovers(tmp_path, {"a.json"}) == []


def test_text_is_utf8(tmp_path: Path) -> None:
    f = tmp_path / "r.md"
    atomic_write_text(f, "± 0.5 → ok")
    assert f.read_bytes() == "± 0.5 → ok".encode()


def test_failed_write_keeps_old_content(tmp_path: Path, monkeypatch) -> None:
    f = tmp_path / "manifest.json"
    f.write_bytes(b"old")

    def broken_fsync(fd: int) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(storage.os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(f, b"new" * 1000)
    monkeypatch.undo()
    assert f.read_bytes() == b"old"
    assert _leftovers(tmp_path, {"manifest.json"}) == []


def test_interrupted_write_keeps_old_content(tmp_path: Path, monkeypatch) -> None:
    f = tmp_path / "x.bin"
    f.write_bytes(b"old")
    real_replace = os.replace

    def interrupted(src, dst):  # Ctrl-C just before the rename
        raise KeyboardInterrupt

    monkeypatch.setattr(storage.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_bytes(f, b"new")
    monkeypatch.setattr(storage.os, "replace", real_replace)
    assert f.read_bytes() == b"old"
    assert _leftovers(tmp_path, {"x.bin"}) == []


def test_killed_writer_leaves_old_content(tmp_path: Path) -> None:
    """SIGKILL after the new bytes are in the temp file and before the rename: no cleanup
    runs, and the target must still hold the old content, whole."""
    f = tmp_path / "data.npz"
    old = os.urandom(1 << 16)
    f.write_bytes(old)
    script = (
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from activetouch import storage\n"
        "storage.os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)\n"
        "storage.atomic_write_bytes(Path(sys.argv[1]), b'n' * (1 << 20))\n"
    )
    r = _run(script, str(f))
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert f.read_bytes() == old
    # The dead writer's temp file stays behind under a hidden, recognisable name.
    strays = _leftovers(tmp_path, {"data.npz"})
    assert len(strays) == 1 and strays[0].startswith(".data.npz.") and strays[0].endswith(".tmp")


def test_reader_never_sees_a_partial_file(tmp_path: Path) -> None:
    f = tmp_path / "big.bin"
    contents = [bytes([i]) * (1 << 20) for i in (1, 2)]
    atomic_write_bytes(f, contents[0])
    stop = threading.Event()
    bad: list[int] = []

    def read() -> None:
        while not stop.is_set():
            data = f.read_bytes()
            if data not in contents:
                bad.append(len(data))

    t = threading.Thread(target=read)
    t.start()
    try:
        for i in range(30):
            atomic_write_bytes(f, contents[i % 2])
    finally:
        stop.set()
        t.join()
    assert bad == []


_COUNTER = (
    "import sys, time\n"
    "from pathlib import Path\n"
    "from activetouch.storage import locked\n"
    "counter = Path(sys.argv[1])\n"
    "for _ in range(int(sys.argv[2])):\n"
    "    with locked(counter.with_name('.lock')):\n"
    "        n = int(counter.read_text())\n"
    "        time.sleep(0.001)  # widen the read-modify-write window\n"
    "        counter.write_text(str(n + 1))\n"
)


def test_lock_serialises_processes(tmp_path: Path) -> None:
    counter = tmp_path / "counter"
    counter.write_text("0")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _COUNTER, str(counter), "40"],
            env=env,
            stderr=subprocess.PIPE,
        )
        for _ in range(3)
    ]
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err.decode()
    assert int(counter.read_text()) == 120
    assert (tmp_path / ".lock").exists()  # never removed: see the module docstring


def test_lock_serialises_threads(tmp_path: Path) -> None:
    counter = tmp_path / "counter"
    counter.write_text("0")

    def work() -> None:
        for _ in range(25):
            with locked(tmp_path / ".lock"):
                n = int(counter.read_text())
                time.sleep(0.0005)
                counter.write_text(str(n + 1))

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert int(counter.read_text()) == 100


def test_on_wait_names_the_holder(tmp_path: Path) -> None:
    lock = tmp_path / ".collect.lock"
    heard: list[str] = []
    with locked(lock, on_wait=heard.append, note="1"):
        pass
    assert heard == []  # free: no waiting, no call
    assert lock.read_text() == "1"

    held, release = threading.Event(), threading.Event()

    def holder() -> None:
        with locked(lock, note="4242"):
            held.set()
            release.wait(10)

    t = threading.Thread(target=holder)
    t.start()
    assert held.wait(10)
    threading.Timer(0.2, release.set).start()
    with locked(lock, on_wait=heard.append, note="7"):
        assert release.is_set()  # it waited for the holder
    t.join()
    assert heard == ["4242"]
    assert lock.read_text() == "7"


def _fill(files: dict[str, bytes]):
    def fill(d: Path) -> None:
        for name, data in files.items():
            (d / name).write_bytes(data)

    return fill


def test_replace_dir(tmp_path: Path) -> None:
    dest = tmp_path / "model"
    replace_dir(dest, _fill({"a": b"1", "b": b"2"}))
    assert sorted(p.name for p in dest.iterdir()) == ["a", "b"]
    assert stat.S_IMODE(dest.stat().st_mode) == 0o700  # mkdtemp's, as before
    replace_dir(dest, _fill({"c": b"3"}))
    assert sorted(p.name for p in dest.iterdir()) == ["c"]
    assert _leftovers(tmp_path, {"model"}) == []


def test_replace_dir_failing_fill_keeps_old(tmp_path: Path) -> None:
    dest = tmp_path / "cup"
    replace_dir(dest, _fill({"visual.obj": b"old"}))

    def half(d: Path) -> None:
        (d / "visual.obj").write_bytes(b"new")
        raise RuntimeError("decomposition failed")

    with pytest.raises(RuntimeError, match="decomposition failed"):
        replace_dir(dest, half)
    assert (dest / "visual.obj").read_bytes() == b"old"
    assert _leftovers(tmp_path, {"cup"}) == []


def test_replace_dir_failing_swap_puts_old_back(tmp_path: Path, monkeypatch) -> None:
    dest = tmp_path / "model"
    replace_dir(dest, _fill({"model.json": b"old"}))
    real_replace = os.replace

    def fail_swap_in(src, dst):  # moving the old one aside works, the new one in does not
        if Path(src).name.startswith(".model.tmp-"):
            raise OSError("simulated crash")
        return real_replace(src, dst)

    monkeypatch.setattr(storage.os, "replace", fail_swap_in)
    with pytest.raises(OSError, match="simulated crash"):
        replace_dir(dest, _fill({"model.json": b"new"}))
    monkeypatch.setattr(storage.os, "replace", real_replace)
    assert (dest / "model.json").read_bytes() == b"old"
    assert _leftovers(tmp_path, {"model"}) == []
