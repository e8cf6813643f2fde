"""How soon the daemon serves: seconds from `activetouch serve` being started to its "ready"
log line (the model loaded, the planner warmed up: its grasp-likelihood table computed or read
from beside the model, the search compiled or loaded from numba's cache), and to the first
answer of `activetouch status` (issue 24: ready within 5 s).

    ACTIVETOUCH_HOME=DIR python benchmarks/daemon_start.py [--model DIR] [--repeats 3]
        [--port 7481] [--json FILE]

Each start is a fresh process on the twin (listening on 127.0.0.1 only, no scouting); the
first start after training may compute what later ones read. Prints one row per start and
the median."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def one_start(model: str | None, port: int, timeout_s: float) -> dict:
    endpoint = f"tcp/127.0.0.1:{port}"
    cmd = [sys.executable, "-m", "activetouch", "serve", "--log-format", "json"]
    cmd += ["--set", f'service.listen=["{endpoint}"]']
    if model:
        cmd += ["--model", model]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    row: dict = {}
    try:
        assert proc.stderr is not None
        deadline = t0 + timeout_s
        for line in proc.stderr:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            msg, now = rec.get("msg", rec.get("message", "")), time.perf_counter() - t0
            if msg == "model loaded":
                row["model_loaded_s"] = now
            elif msg == "planner warmed up":
                row["planner_warm_up_s"] = float(rec.get("s", np.nan))
            elif msg == "ready":
                row["ready_s"] = now
                break
            if time.perf_counter() > deadline:
                break
        status = [sys.executable, "-m", "activetouch", "status", "--json", "--connect", endpoint]
        r = subprocess.run(status, capture_output=True, text=True, timeout=timeout_s)
        if r.returncode != 0:
            row["status_error"] = (r.stderr or r.stdout).strip()[-300:]
        row["status_answered_s"] = time.perf_counter() - t0
        row["status_ok"] = r.returncode == 0
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default=None, help="model directory (default: the data's)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--port", type=int, default=7481)
    ap.add_argument("--timeout-s", type=float, default=180.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rows = []
    print(
        "(status answered: from the start to `activetouch status` returning, a process of its own)"
    )
    print("| start | model loaded s | planner warm-up s | ready s | status answered s |")
    print("|---|---|---|---|---|")
    for i in range(args.repeats):
        r = one_start(args.model, args.port, args.timeout_s)
        rows.append(r)
        print(
            f"| {i + 1} | {r.get('model_loaded_s', np.nan):.2f} | "
            f"{r.get('planner_warm_up_s', np.nan):.2f} | {r.get('ready_s', np.nan):.2f} | "
            f"{r.get('status_answered_s', np.nan):.2f}"
            f"{'' if r.get('status_ok') else ' (failed)'} |",
            flush=True,
        )
    ready = [r["ready_s"] for r in rows if "ready_s" in r]
    if ready:
        print(f"median ready {np.median(ready):.2f} s over {len(ready)} starts")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
