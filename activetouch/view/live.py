"""The live side of `activetouch view`: the daemon's `progress` over Zenoh into a `SceneLogger`,
and Rerun's web viewer served on loopback.

`ProgressFeed` subscribes to ``activetouch/<robot>/progress`` and queues each decoded sample
(Zenoh's thread only decodes); `pump` / `run` hand them to the scene on the calling thread,
the one thread Rerun's timelines need. `RerunServer` runs Rerun's own server (the `rerun`
executable of the rerun-sdk wheel) as a child process bound to 127.0.0.1: its gRPC proxy
buffers what is logged for viewers that connect late, and its HTTP server hosts the web
viewer. (The SDK's in-process `serve_grpc` / `serve_web_viewer` listen on every interface.)
Rerun's usage analytics are switched off for the child (`RERUN_ANALYTICS=0`).

The web viewer's page, left alone, has the browser ask the internet for Google's fonts,
GitHub's latest Rerun release and Rerun's usage telemetry (tel.rerun.io). So the browser is
not pointed at Rerun's web server directly: `ViewerPage` serves the same files on the
`--port` (127.0.0.1) with a Content-Security-Policy that lets the page reach only itself and
the gRPC proxy, and the browser refuses everything else.
"""

from __future__ import annotations

import ctypes
import http.server
import os
import queue
import signal
import socket
import subprocess
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import Any

import zenoh

from activetouch.daemon.serving import direct
from activetouch.errors import ConfigError, MessageError, NodeUnavailableError
from activetouch.transport.keys import Keys
from activetouch.transport.messages import Progress, decode

LOOPBACK = "127.0.0.1"


class ProgressFeed:
    """Every `Progress` the daemon of `robot` publishes, for `on_progress` on one thread."""

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        on_progress: Callable[[Progress], None],
    ) -> None:
        self.keys = Keys(robot)
        self.on_progress = on_progress
        self.received = 0  # samples decoded
        self.delivered = 0  # samples handed to on_progress
        self.rejected = 0  # samples that did not decode
        self._q: queue.SimpleQueue[Progress] = queue.SimpleQueue()
        self._cv = threading.Condition()
        self._sub = session.declare_subscriber(self.keys.progress, direct(self._on_sample))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), Progress)
        except MessageError:
            self.rejected += 1
            return
        self.received += 1
        self._q.put(msg)

    def pump(self, timeout: float = 0.0) -> int:
        """Hand over the queued samples (waiting up to `timeout` s for the first); how many."""
        n = 0
        block = timeout > 0
        while True:
            try:
                msg = self._q.get(block=block, timeout=timeout if block else None)
            except queue.Empty:
                return n
            block = False
            self.on_progress(msg)
            n += 1
            with self._cv:
                self.delivered += 1
                self._cv.notify_all()

    def run(self, stop: threading.Event, poll_s: float = 0.2) -> None:
        """Pump until `stop` is set."""
        while not stop.is_set():
            self.pump(poll_s)

    def close(self) -> None:
        with suppress(Exception):
            self._sub.undeclare()


def free_port(host: str = LOOPBACK) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _check_port(port: int, what: str) -> int:
    if not 0 < int(port) < 65536:
        raise ConfigError(f"{what} must be a TCP port (1-65535), got {port}")
    return int(port)


def _listening(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.5)
        return s.connect_ex((LOOPBACK, port)) == 0


def rerun_executable() -> Path:
    """The `rerun` executable shipped in the rerun-sdk wheel (package `rerun_cli`)."""
    try:
        import rerun_cli  # optional: the `view` extra
    except ImportError:
        raise ConfigError("the live view needs Rerun: pip install 'activetouch[view]'") from None
    exe = Path(rerun_cli.__file__).parent / "rerun"
    if not exe.is_file():
        raise ConfigError(f"Rerun's executable is missing ({exe}): reinstall rerun-sdk")
    return exe


def _die_with_parent() -> Callable[[], None] | None:
    """What the child runs before exec: on Linux, SIGTERM when its parent dies (even killed),
    so no server is left behind listening. Everything is looked up here, in the parent: the
    child of a threaded process may only call into C."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    sigterm = int(signal.SIGTERM)

    def set_pdeathsig() -> None:
        prctl(1, sigterm)  # PR_SET_PDEATHSIG

    return set_pdeathsig


class RerunServer:
    """Rerun's gRPC proxy and web viewer on 127.0.0.1, a child process stopped by `close`."""

    def __init__(
        self,
        web_port: int,
        grpc_port: int | None = None,
        memory_limit: str = "512MiB",
        start_timeout_s: float = 60.0,
    ) -> None:
        self.web_port = _check_port(web_port, "--port")
        self.grpc_port = _check_port(grpc_port, "the gRPC port") if grpc_port else free_port()
        if self.grpc_port == self.web_port:
            raise ConfigError(f"the web and gRPC ports must differ (both {self.web_port})")
        for port in (self.web_port, self.grpc_port):
            if _listening(port):
                raise ConfigError(f"port {port} on {LOOPBACK} is taken: choose another --port")
        self.page: ViewerPage | None = None
        self._rerun_web_port = free_port()  # Rerun's own web server, behind `ViewerPage`
        env = dict(os.environ, RERUN_ANALYTICS="0")
        self.proc = subprocess.Popen(
            [
                str(rerun_executable()),
                "--serve-web",
                "--bind",
                LOOPBACK,
                "--port",
                str(self.grpc_port),
                "--web-viewer-port",
                str(self._rerun_web_port),
                "--server-memory-limit",
                memory_limit,
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env,
            preexec_fn=_die_with_parent(),
            start_new_session=True,  # Ctrl-C in the terminal is ours to handle, not its
        )
        deadline = time.monotonic() + start_timeout_s
        while not (_listening(self.grpc_port) and _listening(self._rerun_web_port)):
            if self.proc.poll() is not None:
                err = (self.proc.stderr.read() if self.proc.stderr else b"").decode(
                    errors="replace"
                )
                last = err.strip().splitlines()[-1:] or ["no output"]
                raise NodeUnavailableError(f"Rerun's server exited: {last[0]}")
            if time.monotonic() > deadline:
                self.close()
                raise NodeUnavailableError(
                    f"Rerun's server did not listen on {LOOPBACK}:{self.grpc_port} and "
                    f":{self._rerun_web_port} within {start_timeout_s:.0f} s"
                )
            time.sleep(0.1)
        # Its log goes nowhere from now on (a full pipe would block it).
        threading.Thread(target=self._drain, daemon=True).start()
        try:
            self.page = ViewerPage(self.web_port, self._rerun_web_port, self.grpc_port)
        except OSError as e:
            self.close()
            raise ConfigError(f"cannot serve the viewer on {LOOPBACK}:{self.web_port}: {e}") from e

    def _drain(self) -> None:
        if self.proc.stderr is not None:
            with suppress(Exception):
                while self.proc.stderr.read(65536):
                    pass

    @property
    def pid(self) -> int:
        return int(self.proc.pid)

    @property
    def grpc_url(self) -> str:
        return f"rerun+http://{LOOPBACK}:{self.grpc_port}/proxy"

    @property
    def viewer_url(self) -> str:
        """What a browser opens: the web viewer, told where the data is."""
        q = urllib.parse.quote(self.grpc_url, safe="")
        return f"http://{LOOPBACK}:{self.web_port}/?url={q}&hide_welcome_screen"

    def close(self, timeout: float = 10.0) -> None:
        if self.page is not None:
            self.page.close()
            self.page = None
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout)

    def __enter__(self) -> RerunServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def content_security_policy(grpc_port: int) -> str:
    """The page may load and connect to itself and the gRPC proxy on loopback, nothing else."""
    grpc = f"http://{LOOPBACK}:{grpc_port}"
    return "; ".join(
        (
            "default-src 'self'",
            "script-src 'self' 'unsafe-inline' 'unsafe-eval' 'wasm-unsafe-eval'",
            "style-src 'self' 'unsafe-inline'",
            "img-src 'self' data: blob:",
            "font-src 'self' data:",
            f"connect-src 'self' {grpc} blob: data:",
            "worker-src 'self' blob:",
            "frame-src 'none'",
            "object-src 'none'",
        )
    )


_KEEP_HEADERS = ("content-type", "cache-control", "last-modified", "etag")


class ViewerPage:
    """Rerun's web-viewer files (fetched once from its server on `upstream_port`) served on
    127.0.0.1:`port` with `content_security_policy`; GET and HEAD only."""

    def __init__(self, port: int, upstream_port: int, grpc_port: int) -> None:
        cache: dict[str, tuple[int, list[tuple[str, str]], bytes]] = {}
        lock = threading.Lock()
        csp = content_security_policy(grpc_port)
        upstream = f"http://{LOOPBACK}:{upstream_port}"

        def fetch(path: str) -> tuple[int, list[tuple[str, str]], bytes]:
            with lock:
                hit = cache.get(path)
                if hit is not None:
                    return hit
                try:
                    with urllib.request.urlopen(upstream + path, timeout=60) as r:
                        body = r.read()
                        headers = [
                            (k, v) for k, v in r.headers.items() if k.lower() in _KEEP_HEADERS
                        ]
                        out = (int(r.status), headers, body)
                except urllib.error.HTTPError as e:
                    return int(e.code), [("Content-Type", "text/plain")], b"not found"
                cache[path] = out
                return out

        class Handler(http.server.BaseHTTPRequestHandler):
            def _answer(self, with_body: bool) -> None:
                path = urllib.parse.urlsplit(self.path).path or "/"
                status, headers, body = fetch(path)
                self.send_response(status)
                for k, v in headers:
                    self.send_header(k, v)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Content-Security-Policy", csp)
                self.send_header("Referrer-Policy", "no-referrer")
                self.end_headers()
                if with_body:
                    self.wfile.write(body)

            def do_GET(self) -> None:
                self._answer(True)

            def do_HEAD(self) -> None:
                self._answer(False)

            def log_message(self, format: str, *args: Any) -> None:
                pass  # quiet

        self.server = http.server.ThreadingHTTPServer((LOOPBACK, port), Handler)
        self.server.daemon_threads = True
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self._thread.join(10.0)
