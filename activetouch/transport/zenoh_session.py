"""Opening Zenoh sessions from explicit settings, closed deterministically.

Defaults are the safe ones: peer mode, multicast and gossip scouting off, listening only on
``tcp/127.0.0.1:7457`` (`DEFAULT_PORT`: not Zenoh's own 7447, which a ROS 2 robot's
``rmw_zenohd`` router takes). Nothing is discovered implicitly: peers find each other only through
the listen/connect endpoints given. A Zenoh JSON5 file (`config_file`, e.g. with TLS or access
control) can be the starting point; the explicit settings are applied on top of it.

`ZenohSession` is a context manager: on exit it closes everything registered with
`closing()` (nodes, clients, subscribers; last registered first) and then the session.
An unclosed session can hang interpreter exit, so always use it (or call `close()`).
Open sessions after any fork(): Zenoh's runtime does not survive it.
"""

from __future__ import annotations

import atexit
import json
import logging
import re
import socket
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

import zenoh

from activetouch.errors import ConfigError

log = logging.getLogger(__name__)

# Not 7447 (Zenoh's default, rmw_zenohd's tcp/[::]:7447) nor 7448 (a second router's usual).
DEFAULT_PORT = 7457
MODES = ("peer", "client")
_ENDPOINT = re.compile(r"^[a-z][a-z0-9\-]*/\S+$")
_HOST_PORT = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.]+\]|[^:\[\]/]+):(?P<port>\d+)$")

Obj = TypeVar("Obj")


def loopback_endpoint(port: int = DEFAULT_PORT) -> str:
    return f"tcp/127.0.0.1:{port}"


def validate_endpoint(endpoint: str) -> str:
    """`endpoint` if it looks like a Zenoh locator (``tcp/127.0.0.1:7457``), else ConfigError."""
    if not isinstance(endpoint, str) or not _ENDPOINT.fullmatch(endpoint):
        raise ConfigError(
            f"Zenoh endpoint {endpoint!r} is invalid: expected PROTOCOL/ADDRESS, "
            "e.g. tcp/127.0.0.1:7457"
        )
    proto, addr = endpoint.split("/", 1)
    if proto in ("tcp", "udp", "tls", "quic", "ws"):
        addr = re.split(r"[?#]", addr, maxsplit=1)[0]  # strip locator metadata / config
        m = _HOST_PORT.fullmatch(addr)
        if not m or not 0 <= int(m.group("port")) <= 65535:
            raise ConfigError(f"Zenoh endpoint {endpoint!r} is invalid: expected {proto}/HOST:PORT")
    return endpoint


@dataclass(frozen=True)
class ZenohSettings:
    """Everything that decides who a session talks to. See the module docstring."""

    listen: tuple[str, ...] = (loopback_endpoint(),)
    connect: tuple[str, ...] = ()
    mode: str = "peer"
    multicast_scouting: bool = False
    gossip_scouting: bool = False
    config_file: Path | None = None  # Zenoh JSON5 base config (TLS, access control ...)
    # Raw "key": JSON5-value inserts applied last, for options not modelled here.
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"Zenoh mode {self.mode!r} is invalid: use one of {MODES}")
        object.__setattr__(self, "listen", tuple(validate_endpoint(e) for e in self.listen))
        object.__setattr__(self, "connect", tuple(validate_endpoint(e) for e in self.connect))

    @classmethod
    def server(cls, port: int = DEFAULT_PORT, **kw: Any) -> ZenohSettings:
        """Listen on 127.0.0.1:`port` only."""
        return cls(listen=(loopback_endpoint(port),), **kw)

    @classmethod
    def client(cls, *connect: str, **kw: Any) -> ZenohSettings:
        """Connect to the given endpoints; listen on nothing."""
        return cls(listen=(), connect=tuple(connect), **kw)


def make_config(settings: ZenohSettings) -> zenoh.Config:
    """The zenoh.Config for `settings`."""
    if settings.config_file is not None:
        path = Path(settings.config_file)
        if not path.is_file():
            raise ConfigError(f"Zenoh config file {path} does not exist")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as e:  # zenoh raises its own ZError with the parser's message
            raise ConfigError(f"Zenoh config file {path} is invalid: {e}") from None
    else:
        conf = zenoh.Config()
    inserts: list[tuple[str, Any]] = [
        ("mode", settings.mode),
        ("scouting/multicast/enabled", settings.multicast_scouting),
        ("scouting/gossip/enabled", settings.gossip_scouting),
        # An empty list matters: a peer's default is to listen on tcp/[::]:0, all interfaces.
        ("listen/endpoints", list(settings.listen)),
        ("connect/endpoints", list(settings.connect)),
        *settings.extra.items(),
    ]
    for key, value in inserts:
        try:
            conf.insert_json5(key, json.dumps(value))
        except Exception as e:
            raise ConfigError(f"Zenoh setting {key}={value!r} is invalid: {e}") from None
    return conf


EXIT_GRACE_S = 0.25  # see _close_leftovers
_exit_lock = threading.Lock()
_exit_refs: list[weakref.ref] = []


def undeclare_quietly(*objs: Any) -> None:
    """Undeclare Zenoh entities (None skipped); failures are logged, never raised, because at
    shutdown the session may already be closed."""
    for obj in objs:
        if obj is None:
            continue
        try:
            obj.undeclare()
        except Exception:
            log.debug("undeclare failed", exc_info=True)


def close_at_exit(obj: Any) -> None:
    """Close `obj` (weakly held) at interpreter exit if it is still open then.

    Objects are closed last-registered first (nodes before the session they use). Why: a
    daemon thread still calling into Zenoh while the interpreter finalises aborts the process
    ("FATAL: exception not rethrown"), so worker threads must be stopped before that."""
    with _exit_lock:
        _exit_refs[:] = [r for r in _exit_refs if r() is not None]
        _exit_refs.append(weakref.ref(obj))


@atexit.register
def _close_leftovers() -> None:
    with _exit_lock:
        objs = [r() for r in reversed(_exit_refs)]
        _exit_refs.clear()
    closed_a_session = False
    for obj in objs:
        if obj is not None:
            try:
                closed_a_session |= isinstance(obj, ZenohSession) and not obj.closed
                obj.close()
            except Exception:
                log.debug("closing %r at exit failed", obj, exc_info=True)
    if closed_a_session:
        # Zenoh's runtime threads drop the Python callbacks of closed entities a little after
        # close() returns; one that takes the GIL once finalisation has begun aborts the
        # process ("FATAL: exception not rethrown", seen ~1 in 50 exits on a loaded machine).
        # Releasing the GIL here lets them finish while the interpreter is still whole.
        time.sleep(EXIT_GRACE_S)


class ZenohSession:
    """An open Zenoh session plus the objects to close before it (LIFO)."""

    def __init__(self, settings: ZenohSettings | None = None) -> None:
        self.settings = settings or ZenohSettings()
        self._closers: list[Callable[[], Any]] = []
        try:
            self._session: zenoh.Session | None = zenoh.open(make_config(self.settings))
        except ConfigError:
            raise
        except Exception as e:  # e.g. the listen port is taken
            raise ConfigError(
                f"cannot open a Zenoh session (listen={list(self.settings.listen)}, "
                f"connect={list(self.settings.connect)}): {e}"
            ) from None
        close_at_exit(self)

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("the Zenoh session is closed")
        return self._session

    @property
    def closed(self) -> bool:
        return self._session is None

    def closing(self, obj: Obj) -> Obj:
        """Register `obj` (anything with close() or undeclare()) to be closed before the session."""
        fn = getattr(obj, "close", None) or getattr(obj, "undeclare", None)
        if fn is None:
            raise TypeError(f"{type(obj).__name__} has neither close() nor undeclare()")
        self._closers.append(fn)
        return obj

    def close(self) -> None:
        """Close the registered objects (last first), then the session. Idempotent."""
        while self._closers:
            fn = self._closers.pop()
            try:
                fn()
            except Exception:
                log.exception("closing %r failed", fn)
        session, self._session = self._session, None
        if session is not None:
            session.close()

    def __enter__(self) -> ZenohSession:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def open_session(settings: ZenohSettings | None = None) -> ZenohSession:
    """Open a session; use as ``with open_session(s) as zs: ... zs.session ...``."""
    return ZenohSession(settings)


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on `host` a moment ago (for tests and ad-hoc daemons)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])
