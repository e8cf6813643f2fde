"""Reliability figures of the daemon (docs/reliability.md): e-stop latency during the largest
plan a request may ask for, cancel latency, SIGTERM exit time in that state, and a killed
client's recognition being cancelled.

    python benchmarks/reliability.py [--data DIR] [--trials 10]

Trains a small model (cup, sphere, bottle; coarse grid) in `--data` if it has none, then runs
the daemon in this process on the fake devices (`hand.type=fake`, `arm.type=fake`), and once
as a subprocess for SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from activetouch import paths
from activetouch.cli.commands.serve import resolve_mode
from activetouch.config import load_config
from activetouch.daemon.client import open_client
from activetouch.daemon.process import Daemon, DaemonOptions
from activetouch.transport.messages import MAX_HORIZON, MAX_SIMULATIONS, RecognizeRequest
from activetouch.transport.zenoh_session import free_tcp_port

ROBOT = "benchbot"
OBJECTS = ["cup", "sphere", "bottle"]
COARSE = ["grid.step_deg=40"]


def ensure_model(home: Path) -> None:
    if (paths.default_model(home) / "model.json").is_file():
        return
    from activetouch.objects.library import ObjectLibrary
    from activetouch.pipelines.training import collect, fit_and_save

    cfg = load_config(None, COARSE)
    lib = ObjectLibrary(paths.objects_dir(home))
    lib.ensure_builtins(OBJECTS)
    ds = paths.default_dataset(home)
    collect(lib, ds, OBJECTS, cfg, workers=2)
    fit_and_save(ds, OBJECTS, cfg, paths.default_model(home))


def largest_request(seed: int) -> RecognizeRequest:
    return RecognizeRequest(
        policy="tree",
        max_moves=50,
        seed=seed,
        object="cup",
        simulations=MAX_SIMULATIONS,
        horizon=MAX_HORIZON,
    )


def in_process(home: Path, trials: int) -> dict[str, list[float]]:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    cfg = load_config(
        None,
        [
            "hand.type=fake",
            "arm.type=fake",
            "session.stable_grasps=1000",
            f"service.robot={ROBOT}",
            f'service.listen=["{ep}"]',
        ],
    )
    opts = DaemonOptions(resolve_mode(None, cfg), "all", home, paths.default_model(home), cfg)
    daemon = Daemon(opts)
    daemon.start()
    hand = daemon.devices.hand
    out: dict[str, list[float]] = {"estop_s": [], "cancel_s": [], "plan_s": []}
    try:
        with open_client([ep], ROBOT, timeout=10.0) as client:
            for i in range(trials):
                for what in ("estop", "cancel"):
                    done = threading.Event()
                    closes = hand.closes

                    def run(i: int = i, done: threading.Event = done) -> None:
                        with contextlib.suppress(Exception):  # aborted / cancelled: expected
                            client.recognize(largest_request(i), timeout=300.0)
                        done.set()

                    threading.Thread(target=run, daemon=True).start()
                    while hand.closes <= closes:  # the first grasp: the next plan starts
                        time.sleep(0.002)
                    t_plan = time.perf_counter()
                    time.sleep(0.1)
                    t0 = time.perf_counter()
                    if what == "estop":
                        client.estop("benchmark")
                        out["estop_s"].append(time.perf_counter() - t0)
                    else:
                        client.cancel()
                    done.wait(300.0)
                    if what == "cancel":
                        out["cancel_s"].append(time.perf_counter() - t0)
                        out["plan_s"].append(time.perf_counter() - t_plan)
    finally:
        daemon.close()
    return out


def sigterm(home: Path) -> float:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    args = [
        sys.executable, "-m", "activetouch", "serve", "--data", str(home), "--listen", ep,
        "--robot", ROBOT, "--set", "hand.type=fake", "--set", "arm.type=fake",
        "--set", "session.stable_grasps=1000",
    ]  # fmt: skip
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        with open_client([ep], ROBOT, timeout=10.0, wait=120.0) as client:
            seen = threading.Event()

            def run() -> None:
                with contextlib.suppress(Exception):  # the daemon's goodbye is an error
                    client.recognize(
                        largest_request(0), on_progress=lambda _e: seen.set(), timeout=300.0
                    )

            threading.Thread(target=run, daemon=True).start()
            seen.wait(120.0)
            time.sleep(0.2)
            t0 = time.perf_counter()
            os.kill(proc.pid, signal.SIGTERM)
            proc.wait(60.0)
            return time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=None, help="data directory (default: a temporary one)")
    p.add_argument("--trials", type=int, default=10)
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)  # the daemon's own log lines are not the figures
    with tempfile.TemporaryDirectory() as tmp:
        home = Path(a.data) if a.data else Path(tmp)
        print(f"model in {home} ...", flush=True)
        ensure_model(home)
        figs = in_process(home, a.trials)
        term = sigterm(home)

    def fmt(xs: list[float]) -> str:
        return (
            f"median {statistics.median(xs) * 1000:.1f} ms, max {max(xs) * 1000:.1f} ms "
            f"({len(xs)} trials)"
        )

    print(f"largest request: simulations {MAX_SIMULATIONS}, horizon {MAX_HORIZON}")
    print(f"e-stop answered and in force: {fmt(figs['estop_s'])}  (target < 100 ms)")
    print(f"cancel to reply (the running plan is interrupted): {fmt(figs['cancel_s'])}")
    print(f"SIGTERM to exit: {term:.2f} s  (target <= 5 s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
