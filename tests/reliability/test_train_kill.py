"""Finding 7 of the reliability issue: kill -9 of `train` at random moments leaves no worker
behind and loses no saved grasp; a resumed run completes the dataset."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from activetouch import paths
from activetouch.recognition.dataset import Dataset

OBJECTS = "cup,sphere,bottle"


def _children(pid: int) -> set[int]:
    """Every descendant of `pid` (from /proc)."""
    out: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                kids = (task / "children").read_text().split()
            except OSError:
                continue
            for k in map(int, kids):
                if k not in out:
                    out.add(k)
                    todo.append(k)
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[-120:]
    except OSError:
        return "?"


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")  # a zombie has stopped; only its parent may reap it


def _train(home: Path, err: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "activetouch",
            "train",
            "--objects",
            OBJECTS,
            "--workers",
            "2",
            "--data",
            str(home),
        ],
        stdout=subprocess.DEVNULL,
        stderr=err.open("wb"),  # what a train that fails on its own said
    )


def _grasps(home: Path) -> int:
    try:
        ds = Dataset.open(paths.default_dataset(home))
    except Exception:
        return 0
    return sum(ds.n_grasps(n) for n in ds.object_names())


@pytest.mark.slow
def test_kill_9_of_train_leaves_nothing_running_and_loses_nothing(tmp_path: Path) -> None:
    from activetouch.objects.library import ObjectLibrary

    home = tmp_path / "home"
    # The meshes first: generating them takes longer than the kills below wait.
    ObjectLibrary(paths.objects_dir(home)).ensure_builtins(OBJECTS.split(","))
    rng = random.Random(7)
    saved = 0
    for i in range(5):
        err = tmp_path / f"train-{i}.err"
        proc = _train(home, err)
        kids: set[int] = set()
        try:
            # Once the workers run, a random moment later. With the default grid an object
            # takes longer than the check below waits, so a worker that goes on is seen.
            deadline = time.monotonic() + 60.0
            while len(kids) < 2 and time.monotonic() < deadline and proc.poll() is None:
                kids |= _children(proc.pid)
                time.sleep(0.05)
            deadline = time.monotonic() + rng.uniform(0.2, 4.0)
            while time.monotonic() < deadline and proc.poll() is None:
                kids |= _children(proc.pid)
                time.sleep(0.05)
            kids |= _children(proc.pid)
            before = _grasps(home)
            # `proc.poll()` above reaps a train that already finished (it can, on a fast or a
            # lucky run): then there is nothing to kill, and it must have ended well.
            proc.send_signal(signal.SIGKILL)
            rc = proc.wait(10)
            said = err.read_text(errors="replace")[-2000:]
            assert rc in (0, -signal.SIGKILL), f"train failed on its own (exit {rc}): {said}"
            finished_alone = rc == 0
        finally:
            if proc.poll() is None:
                proc.kill()
        # A worker still starting (importing, seconds on a loaded machine) notices once its
        # watch runs; one already collecting notices within a fraction of a second.
        end = time.monotonic() + 20.0
        while any(_running(k) for k in kids) and time.monotonic() < end:
            time.sleep(0.05)
        left = {k: _cmdline(k) for k in kids if _running(k)}
        for k in left:  # leave the machine clean even when the test fails
            os.kill(k, signal.SIGKILL)
        assert not left, f"{len(left)} process(es) outlived the killed train: {left}"
        after = _grasps(home)
        assert after >= before >= saved, "saved grasps were lost"
        saved = after
        if finished_alone:
            break
    err = tmp_path / "train-last.err"
    proc = _train(home, err)
    assert proc.wait(300) == 0, err.read_text(errors="replace")[-2000:]
    Dataset.open(paths.default_dataset(home)).verify()
    assert _grasps(home) >= saved
