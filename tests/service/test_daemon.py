"""The recognition daemon as a subprocess on 127.0.0.1 (scouting off), used through the CLI
and `DaemonClient`: results equal the in-process run, one recognition at a time, cancel,
emergency stop, SIGTERM mid-recognition, a killed node, no model, systemd notifications."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from activetouch.cli.main import main as cli_main
from activetouch.daemon.client import (
    BusyError,
    DaemonClient,
    RecognitionAbortedError,
    open_client,
)
from activetouch.daemon.process import LogfmtFormatter, sd_notify, watchdog_period
from activetouch.errors import ActiveTouchError, DataError, MessageError, NodeUnavailableError
from activetouch.transport.messages import Progress, RecognizeRequest
from activetouch.transport.zenoh_session import free_tcp_port

ROBOT = "testbot"
START_TIMEOUT = 60.0  # a cold start imports numba, pybullet and loads the model
PATIENT = ("--set", "service.sim_motion_delay_s=0.03", "--set", "session.stable_grasps=100")


class DaemonProcess:
    """`python -m activetouch serve ...` with its output in a file; stopped by its own pid."""

    def __init__(self, args: list[str], log: Path, env: dict[str, str] | None = None) -> None:
        self.log = log
        child_env = {
            k: v for k, v in os.environ.items() if not k.startswith(("NOTIFY_", "WATCHDOG_"))
        }
        child_env.update(env or {})
        self._out = open(log, "w")  # noqa: SIM115 - closed in stop()/kill()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "activetouch", "serve", *args],
            stdout=self._out,
            stderr=subprocess.STDOUT,
            env=child_env,
        )
        self.pid = self.proc.pid

    def running(self) -> bool:
        return self.proc.poll() is None

    def signal(self, sig: int) -> None:
        if self.running():
            os.kill(self.pid, sig)

    def stop(self, timeout: float = 5.0, sig: int | None = None) -> int:
        """`sig` (SIGTERM) and wait; the exit code (raises if it does not exit in `timeout`)."""
        try:
            self.signal(signal.SIGTERM if sig is None else sig)
            return self.proc.wait(timeout)
        finally:
            self.kill()

    def kill(self) -> None:
        if self.running():
            os.kill(self.pid, signal.SIGKILL)
            self.proc.wait(10)
        self._out.close()

    def text(self) -> str:
        return self.log.read_text()


def serve_args(home: Path, port: int, *extra: str) -> list[str]:
    return [
        "--sim",
        "--data",
        str(home),
        "--robot",
        ROBOT,
        "--listen",
        f"tcp/127.0.0.1:{port}",
        *extra,
    ]


@pytest.fixture(scope="module")
def notify_socket() -> Iterator[tuple[str, list[str]]]:
    """A fake systemd: a datagram socket read by a thread into a list."""
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "notify")
        s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        s.bind(path)
        s.settimeout(0.1)
        got: list[str] = []
        done = threading.Event()

        def drain() -> None:
            while not done.is_set():
                try:
                    got.append(s.recv(4096).decode())
                except TimeoutError:
                    continue

        t = threading.Thread(target=drain, daemon=True)
        t.start()
        try:
            yield path, got
        finally:
            done.set()
            t.join(2.0)
            s.close()


@pytest.fixture(scope="module")
def daemon(
    trained_home: Path, tmp_path_factory: pytest.TempPathFactory, notify_socket
) -> Iterator[tuple[DaemonProcess, str]]:
    """A daemon under a fake systemd (NOTIFY_SOCKET, 1 s watchdog). The twin is paced at 30 ms
    per motion and recognitions never stop early for confidence, so one lasts long enough to
    be looked at and interrupted."""
    port = free_tcp_port()
    d = DaemonProcess(
        serve_args(trained_home, port, *PATIENT, "--log-format", "json"),
        tmp_path_factory.mktemp("daemon") / "daemon.log",
        env={"NOTIFY_SOCKET": notify_socket[0], "WATCHDOG_USEC": "1000000"},
    )
    try:
        wait_ready(d, f"tcp/127.0.0.1:{port}")
        yield d, f"tcp/127.0.0.1:{port}"
        assert d.stop() == 0, d.text()
    finally:
        d.kill()


def wait_ready(d: DaemonProcess, endpoint: str, robot: str = ROBOT) -> None:
    with open_client([endpoint], robot, wait=START_TIMEOUT) as _client:
        pass
    assert d.running(), d.text()


@pytest.fixture
def client(daemon) -> Iterator[DaemonClient]:
    _d, endpoint = daemon
    with open_client([endpoint], ROBOT, timeout=10.0) as c:
        yield c


def run_in_thread(fn: Any) -> tuple[threading.Thread, dict[str, Any]]:
    out: dict[str, Any] = {}

    def target() -> None:
        try:
            out["result"] = fn()
        except BaseException as e:
            out["error"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    return t, out


def first_progress_then(
    client: DaemonClient, request: RecognizeRequest, timeout: float = 60.0
) -> tuple[threading.Thread, dict[str, Any], threading.Event, list[Progress]]:
    """Start `request` in a thread; return once its first progress sample has arrived."""
    seen = threading.Event()
    samples: list[Progress] = []

    def on_progress(p: Progress) -> None:
        samples.append(p)
        seen.set()

    t, out = run_in_thread(lambda: client.recognize(request, on_progress, timeout=timeout))
    assert seen.wait(30.0), out
    return t, out, seen, samples


# --------------------------------------------------------------------------- in-process units


def test_sd_notify_speaks_the_datagram_protocol(monkeypatch, tmp_path: Path) -> None:
    path = str(tmp_path / "n")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
        s.bind(path)
        monkeypatch.setenv("NOTIFY_SOCKET", path)
        assert sd_notify("READY=1")
        assert s.recv(100) == b"READY=1"
    monkeypatch.delenv("NOTIFY_SOCKET")
    assert not sd_notify("READY=1")  # not under systemd: nothing to do
    monkeypatch.setenv("WATCHDOG_USEC", "4000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert watchdog_period() == 4.0
    monkeypatch.setenv("WATCHDOG_PID", "1")  # meant for another process
    assert watchdog_period() is None


def test_logfmt_lines_carry_the_fields() -> None:
    import logging

    rec = logging.LogRecord("activetouch.daemon", logging.INFO, "", 0, "recognition done", (), None)
    rec.session = "ab12"
    rec.label = "mug cup"
    line = LogfmtFormatter().format(rec)
    assert 'msg="recognition done"' in line
    assert "session=ab12" in line
    assert 'label="mug cup"' in line
    assert "level=info" in line


def test_hardware_mode_fails_with_one_line(trained_home: Path, capsys) -> None:
    assert cli_main(["serve", "--hardware", "--data", str(trained_home)]) == 2
    err = capsys.readouterr().err
    assert "needs real devices" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ('[service]\nrobot = "a/b"\n', "service.robot"),
        ('[service]\nlisten = "tcp/127.0.0.1:1"\n', "expected a list"),
        ('[service]\nlisten = ["127.0.0.1:7447"]\n', "service.listen"),
        ("[service]\nstate_hz = -1\n", "service.state_hz must be >= 0"),
        ("[service]\nmax_queue = 2\n", "unknown setting 'service.max_queue'"),
        ("[service\n", "not valid TOML"),
    ],
)
def test_bad_config_is_one_line_naming_file_and_key(
    tmp_path: Path, capsys, toml: str, expected: str
) -> None:
    cfg = tmp_path / "daemon.toml"
    cfg.write_text(toml)
    assert cli_main(["serve", "--config", str(cfg), "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert expected in err
    assert "daemon.toml" in err
    assert "Traceback" not in err


DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_deploy_files_are_valid() -> None:
    import zenoh

    from activetouch.config import load_config
    from activetouch.daemon.process import check_service_config

    cfg = load_config(DEPLOY / "activetouch.toml")  # every key known, every type right
    check_service_config(cfg.service)
    assert cfg.service.listen == ["tcp/127.0.0.1:7457"]  # loopback, not rmw_zenohd's 7447
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh-tls-acl.json5"))  # Zenoh's own schema
    assert json.loads(conf.get_json("access_control/default_permission")) == "deny"
    unit = (DEPLOY / "activetouch.service").read_text()
    for line in ("Type=notify", "NotifyAccess=main", "WatchdogSec=", "Restart=on-failure"):
        assert f"\n{line}" in unit, line


# --------------------------------------------------------------------------- the daemon


def test_ready_and_watchdog_notifications(daemon, notify_socket) -> None:
    _path, got = notify_socket
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and "WATCHDOG=1" not in got:
        time.sleep(0.1)
    assert any(g.startswith("READY=1") for g in got), got
    assert "WATCHDOG=1" in got, got


def test_status_reports_nodes_model_and_no_session(client: DaemonClient) -> None:
    st = client.status()
    assert st.robot == ROBOT
    assert st.mode == "sim"
    assert st.model_loaded and "cup" in (st.model or "")
    assert {n: h.alive for n, h in st.nodes.items()} == {
        "daemon": True,
        "hand": True,
        "arm": True,
        "sim": True,
    }
    assert st.session is None


def test_cli_recognition_matches_in_process(daemon, trained_home: Path, capsys) -> None:
    _d, endpoint = daemon
    common = ["--data", str(trained_home), "--object", "cup", "--seed", "3", "--json"]
    common += ["--max-moves", "6", *PATIENT]
    assert cli_main(["recognize", *common]) == 0
    local = json.loads(capsys.readouterr().out)
    assert cli_main(["recognize", "--connect", endpoint, "--robot", ROBOT, *common]) == 0
    captured = capsys.readouterr()
    remote = json.loads(captured.out)
    # Live progress on stderr, one line per grasp, as in-process.
    assert captured.err.count("move ") == remote["moves"] >= 1
    for key in ("label", "labels", "pose_ids", "moves", "skipped", "stop_reason", "seed"):
        assert remote[key] == local[key], key
    assert remote["probability"] == pytest.approx(local["probability"], abs=1e-9)
    assert remote["correct"] == (remote["label"] == "cup")


def test_status_and_cli_commands_during_a_recognition(client: DaemonClient, daemon, capsys):
    _d, endpoint = daemon
    req = RecognizeRequest(policy="random", max_moves=40, seed=5, object="bottle")
    t, out, _seen, _samples = first_progress_then(client, req)
    st = client.status()
    assert st.session is not None
    assert st.session.object == "bottle" and st.session.move >= 1
    assert cli_main(["status", "--connect", endpoint, "--robot", ROBOT, "--json"]) == 0
    status = json.loads(capsys.readouterr().out)
    assert status["session"]["session_id"] == st.session.session_id
    assert cli_main(["cancel", "--connect", endpoint, "--robot", ROBOT]) == 0
    assert "cancelled recognition" in capsys.readouterr().out
    t.join(30.0)
    assert not t.is_alive()
    assert "error" not in out, out
    assert out["result"].stop_reason == "cancelled"
    assert client.status().session is None


def test_second_request_is_busy_and_cancel_by_id(client: DaemonClient) -> None:
    req = RecognizeRequest(policy="random", max_moves=40, seed=6, object="cup", session_id="first")
    t, out, _seen, samples = first_progress_then(client, req)
    with pytest.raises(BusyError, match=r"busy: recognition first .* one recognition at a time"):
        client.recognize(RecognizeRequest(policy="tree", max_moves=3, seed=1, object="sphere"))
    assert not client.cancel("nonexistent").cancelled
    res = client.cancel("first")
    assert res.cancelled and res.session_id == "first"
    t.join(30.0)
    assert out["result"].stop_reason == "cancelled"
    assert out["result"].session_id == "first"
    assert [p.move for p in samples] == list(range(1, len(samples) + 1))
    assert all(p.session_id == "first" for p in samples)


def test_estop_aborts_the_recognition_and_the_daemon_goes_on(client: DaemonClient) -> None:
    req = RecognizeRequest(policy="random", max_moves=40, seed=7, object="sphere")
    t, out, _seen, _samples = first_progress_then(client, req)
    res = client.estop("test")
    assert res.arm_stopped and res.hand_opened and res.errors == []
    t.join(30.0)
    assert isinstance(out.get("error"), RecognitionAbortedError), out
    assert "emergency stop (test)" in str(out["error"])
    # Not latched: the next recognition runs.
    again = client.recognize(
        RecognizeRequest(policy="greedy", max_moves=3, seed=1, object="cup"), timeout=60.0
    )
    assert again.moves >= 1


def test_errors_from_the_daemon_keep_their_type(client: DaemonClient) -> None:
    with pytest.raises(MessageError, match="`object`"):
        client.recognize(RecognizeRequest(policy="tree", max_moves=3, seed=1))
    with pytest.raises(DataError, match="unknown object 'nosuch'"):
        client.recognize(RecognizeRequest(policy="tree", max_moves=3, seed=1, object="nosuch"))
    with pytest.raises(MessageError, match="max_moves"):
        client.recognize(RecognizeRequest(policy="tree", max_moves=-1, seed=1, object="cup"))
    assert client.status().session is None


def test_queue_then_sigterm_mid_recognition_exits_cleanly(
    trained_home: Path, tmp_path: Path
) -> None:
    """service.max_queued = 1: a second request waits, a third is busy. Then SIGTERM while the
    first runs: the daemon exits with status 0 within 5 s and both callers get an error."""
    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    d = DaemonProcess(
        serve_args(
            trained_home,
            port,
            *("--set", "service.sim_motion_delay_s=0.2", "--set", "session.stable_grasps=100"),
            *("--set", "service.max_queued=1"),
        ),
        tmp_path / "daemon.log",
    )
    try:
        wait_ready(d, endpoint)
        with open_client([endpoint], ROBOT) as c:
            req = RecognizeRequest(policy="tree", max_moves=40, seed=2, object="cup")
            t, out, _seen, _samples = first_progress_then(c, req)
            queued_req = RecognizeRequest(policy="greedy", max_moves=3, seed=1, object="sphere")
            t2, out2 = run_in_thread(lambda: c.recognize(queued_req, timeout=60.0))
            while c.status().queued < 1:  # the second request is in the queue
                time.sleep(0.05)
            with pytest.raises(BusyError, match=r"1 are queued \(service.max_queued = 1\)"):
                c.recognize(RecognizeRequest(policy="tree", max_moves=3, seed=1, object="cup"))
            assert c.status().session is not None  # mid-recognition
            d.signal(signal.SIGTERM)
            assert d.proc.wait(5.0) == 0, d.text()  # TimeoutExpired if it hangs
            t.join(10.0)
            t2.join(10.0)
            assert not t.is_alive() and not t2.is_alive()
        err = out.get("error")
        assert isinstance(err, RecognitionAbortedError | NodeUnavailableError), out
        err2 = out2.get("error")
        assert isinstance(err2, RecognitionAbortedError | NodeUnavailableError), out2
        log = d.text()
        assert "shutting down" in log and "stopped" in log
        assert "Traceback" not in log
    finally:
        d.kill()


def test_killed_node_fails_the_pending_request(trained_home: Path, tmp_path: Path) -> None:
    """The twin's nodes in their own process (--role nodes), the service in another
    (--role daemon): SIGKILL the nodes mid-recognition."""
    node_port, daemon_port = free_tcp_port(), free_tcp_port()
    nodes = DaemonProcess(
        [
            *serve_args(trained_home, node_port, "--role", "nodes"),
            "--set",
            "service.sim_motion_delay_s=0.2",
        ],
        tmp_path / "nodes.log",
    )
    svc = DaemonProcess(
        [
            *serve_args(trained_home, daemon_port, "--role", "daemon"),
            "--connect",
            f"tcp/127.0.0.1:{node_port}",
            "--set",
            "service.node_wait_s=30",
        ],
        tmp_path / "daemon.log",
    )
    endpoint = f"tcp/127.0.0.1:{daemon_port}"
    try:
        wait_ready(svc, endpoint)
        with open_client([endpoint], ROBOT) as c:
            assert all(h.alive for h in c.status().nodes.values()), c.status()
            req = RecognizeRequest(policy="tree", max_moves=40, seed=2, object="cup")
            t, out, _seen, _samples = first_progress_then(c, req, timeout=120.0)
            nodes.kill()  # SIGKILL by its pid: no goodbye
            t.join(20.0)  # far less than the request's 120 s and the 60 s motion timeout
            assert not t.is_alive(), "the request hangs after its node died"
            err = out.get("error")
            assert isinstance(err, NodeUnavailableError), out
            assert "node of robot 'testbot'" in str(err)
            # Both nodes' liveliness tokens go with the killed process; the hand's death may be
            # seen (through the failed request) a moment before the arm's token is dropped.
            deadline = time.monotonic() + 5.0
            st = c.status()
            while (st.nodes["hand"].alive or st.nodes["arm"].alive) and time.monotonic() < deadline:
                time.sleep(0.1)
                st = c.status()
            assert not st.nodes["hand"].alive and not st.nodes["arm"].alive
            assert st.session is None
            assert st.nodes["hand"].state == "lost" and "went away" in st.nodes["hand"].detail
            # The daemon goes on serving: a new request fails at once, with the reason.
            # (refused at admission: a timeout would say so, not this)
            with pytest.raises(NodeUnavailableError, match=r"the hand is lost.*nothing was moved"):
                c.recognize(RecognizeRequest(policy="tree", max_moves=3, object="cup"), timeout=30)
        assert svc.stop() == 0, svc.text()
    finally:
        nodes.kill()
        svc.kill()


def test_daemon_without_model_says_so(tmp_path: Path) -> None:
    """No model in the data dir (and --hardware --role daemon: no nodes either)."""
    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    d = DaemonProcess(
        [
            "--hardware",
            "--role",
            "daemon",
            "--data",
            str(tmp_path / "empty"),
            "--robot",
            ROBOT,
            "--listen",
            endpoint,
            "--set",
            "service.node_wait_s=0.2",
        ],
        tmp_path / "daemon.log",
    )
    try:
        wait_ready(d, endpoint)
        with open_client([endpoint], ROBOT) as c:
            st = c.status()
            assert not st.model_loaded
            assert "train" in (st.model_error or "")
            assert st.mode == "hardware"
            assert not st.nodes["hand"].alive and "never seen" in st.nodes["hand"].detail
            assert "sim" not in st.nodes
            with pytest.raises(ActiveTouchError, match="no model: run `activetouch train`"):
                c.recognize(RecognizeRequest(policy="tree", max_moves=3))
        assert d.stop(sig=signal.SIGINT) == 0, d.text()  # Ctrl-C stops it cleanly too
    finally:
        d.kill()
