"""deploy/zenoh-tls-acl.json5 (mutual TLS + access control) as shipped, with certificates made
at test time by the `openssl` CLI (a CA; daemon, operator, monitor, node certificates; a
"stranger" signed by the same CA under an unknown common name; an "outsider" from another CA).

Only the certificate paths of the shipped files are filled in (deploy/README.md, "TLS and
access control"); the rules are used verbatim. Checked:
  * fast, on a bare Zenoh session that declares every daemon and node key with the shipped
    file: who may query, subscribe, watch and declare what; and, as a control, that the same
    probes do see everything once access control is switched off (so a denial below is the
    ACL's doing, not a probe that cannot see);
  * slow, on `activetouch serve` as a subprocess on tls/127.0.0.1: the operator's status and
    a short recognition succeed; the monitor's status succeeds, its recognize and estop are
    refused and change nothing; nobody reaches arm/joint_state or fakes a node's liveliness.
All on 127.0.0.1, scouting off; every process started here is stopped by its pid.
"""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from activetouch.daemon.client import open_client
from activetouch.daemon.serving import direct
from activetouch.errors import NodeUnavailableError
from activetouch.transport.keys import DAEMON_NODE, HAND_NODE, Keys
from activetouch.transport.messages import RecognizeRequest
from activetouch.transport.zenoh_session import ZenohSession, ZenohSettings
from tests.loopback import loopback_endpoint
from tests.service.test_daemon import START_TIMEOUT, DaemonProcess

ROOT = Path(__file__).resolve().parents[2]
DAEMON_TEMPLATE = ROOT / "deploy" / "zenoh-tls-acl.json5"
CLIENT_TEMPLATE = ROOT / "deploy" / "zenoh-tls-client.json5"
TLS_DIR = "/etc/activetouch/tls/"  # the per-deployment part of the shipped files
ROBOT = "tlsbot"
KEYS = Keys(ROBOT)
ROLES = ("daemon", "operator", "monitor", "node", "stranger")

pytestmark = pytest.mark.skipif(
    shutil.which("openssl") is None, reason="needs the openssl CLI to make certificates"
)


# --------------------------------------------------------------------------- certificates


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=30)


def _ca(d: Path, name: str) -> None:
    _openssl(
        "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
        "-keyout", f"{name}-key.pem", "-out", f"{name}.pem", "-days", "2",
        "-subj", f"/CN=activetouch-test-{name}", cwd=d,
    )  # fmt: skip


def _leaf(d: Path, name: str, ca: str = "ca") -> None:
    """`name`.pem / `name`-key.pem: CN activetouch-`name`, for 127.0.0.1 and localhost."""
    (d / f"{name}.ext").write_text(
        "basicConstraints=critical,CA:FALSE\n"
        "keyUsage=critical,digitalSignature\n"
        "extendedKeyUsage=serverAuth,clientAuth\n"
        "subjectAltName=DNS:localhost,IP:127.0.0.1\n"
    )
    _openssl(
        "req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
        "-keyout", f"{name}-key.pem", "-out", f"{name}.csr", "-subj", f"/CN=activetouch-{name}",
        cwd=d,
    )  # fmt: skip
    _openssl(
        "x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}-key.pem",
        "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", f"{name}.ext",
        cwd=d,
    )  # fmt: skip


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("tls")
    _ca(d, "ca")
    for role in ROLES:
        _leaf(d, role)
    _ca(d, "other-ca")
    _leaf(d, "outsider", ca="other-ca")  # CN activetouch-outsider, but not our CA
    return d


def fill(pki: Path, role: str) -> Path:
    """The shipped file for `role` with the certificate paths pointing into `pki`."""
    if role == "daemon":
        text = DAEMON_TEMPLATE.read_text()
    else:
        text = CLIENT_TEMPLATE.read_text()
        assert f"{TLS_DIR}client.pem" in text and f"{TLS_DIR}client-key.pem" in text
        text = text.replace(f"{TLS_DIR}client.pem", f"{TLS_DIR}{role}.pem")
        text = text.replace(f"{TLS_DIR}client-key.pem", f"{TLS_DIR}{role}-key.pem")
    assert TLS_DIR in text
    text = text.replace(TLS_DIR, f"{pki}/")
    for word in text.split('"'):
        if word.startswith(f"{pki}/"):
            assert Path(word).is_file(), word
    out = pki / f"{role}.json5"
    out.write_text(text)
    return out


# --------------------------------------------------------------------------- probes


def _session(config: Path, *, listen: str = "", connect: str = "", **extra: object) -> ZenohSession:
    return ZenohSession(
        ZenohSettings(
            listen=(listen,) if listen else (),
            connect=(connect,) if connect else (),
            config_file=config,
            extra=dict(extra),
        )
    )


# What must arrive is waited for up to HANG_S (a hang bound: the wait ends as soon as it
# arrives). What must not arrive is looked for after a round trip the role is allowed on the
# same link (`Link.sync`): messages on one link are handled in order and every callback here
# runs on Zenoh's own thread (`direct`), so anything sent before the round trip would have
# been handled by then. A role allowed nothing at all has no such round trip; only its
# "nothing arrived" rests on SETTLE_S.
HANG_S = 30.0
SETTLE_S = 1.0
MARK = f"{KEYS.prefix}/hand/probe-mark"  # a node key: a node may serve it, the daemon query it


def _answers(session: zenoh.Session, key: str, timeout: float = HANG_S) -> list[bytes]:
    """Payloads of the replies to a get on `key` (none when the ACL hides the queryable: the
    get then ends at once, there being nobody to ask)."""
    out = []
    for reply in session.get(key, timeout=timeout):
        if reply.ok is not None:
            out.append(reply.ok.payload.to_bytes())
    return out


def _wait(cond: Callable[[], bool], timeout: float = HANG_S) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def _until_answered(session: zenoh.Session, key: str) -> bool:
    """Ask `key` until it answers (a queryable declared by the far side becomes visible only
    once its declaration got here), up to HANG_S."""
    return _wait(lambda: bool(_answers(session, key, timeout=HANG_S)))


class FakeDaemon:
    """A bare session with the daemon's file: every daemon and node key declared, answering
    its own name; the daemon's token; progress published; node tokens seen recorded."""

    KEYS = (
        KEYS.status, KEYS.recognize, KEYS.cancel, KEYS.estop,
        KEYS.hand_state, KEYS.hand_open, KEYS.arm_joint_state, KEYS.arm_move_wrist,
        KEYS.sim_place,
    )  # fmt: skip

    def __init__(self, zs: ZenohSession) -> None:
        self.zs = zs
        s = zs.session
        self.tokens_seen: list[str] = []
        self._lock = threading.Lock()
        for key in self.KEYS:
            zs.closing(s.declare_queryable(key, direct(self._answer(key))))
        zs.closing(s.liveliness().declare_token(KEYS.alive(DAEMON_NODE)))
        zs.closing(s.liveliness().declare_subscriber(f"{KEYS.prefix}/alive/**", direct(self._seen)))
        self.progress = zs.closing(s.declare_publisher(KEYS.progress))

    @staticmethod
    def _answer(key: str) -> Callable[[zenoh.Query], None]:
        return lambda q: q.reply(key, key.encode())

    def _seen(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.tokens_seen.append(f"{sample.kind} {sample.key_expr}")

    def seen_since(self, n: int) -> list[str]:
        with self._lock:
            return self.tokens_seen[n:]


class Link:
    """The round trip `client` may make with `daemon` under `expect` (the outcome the test
    asserts, which decides nothing else): a status query if status is to be answered, else,
    if the client may declare into the daemon (a node), the daemon querying a node key the
    client serves; else none (`sync` waits SETTLE_S)."""

    def __init__(self, client: zenoh.Session, daemon: FakeDaemon, expect: dict) -> None:
        self.client, self.daemon = client, daemon
        self.kind: str | None = None
        if "status" in expect["answered"]:
            self.kind = "status"
        elif expect["spoofed_token_seen"]:
            self.kind = "node"
        self._mark = None
        if self.kind == "node":
            self._mark = client.declare_queryable(MARK, direct(lambda q: q.reply(MARK, b"mark")))

    def _round_trip(self) -> bool:
        if self.kind == "status":
            return _until_answered(self.client, KEYS.status)
        return _until_answered(self.daemon.zs.session, MARK)

    def sync(self) -> None:
        """Everything either side sent before has been handled. Two round trips: the first
        flushes what the client sent, the second what the daemon sent in answer to it."""
        if self.kind is None:
            time.sleep(SETTLE_S)
            return
        for _ in range(2):
            assert self._round_trip(), f"no {self.kind} round trip within {HANG_S} s"

    def close(self) -> None:
        if self._mark is not None:
            self._mark.undeclare()


def probe(client: zenoh.Session, daemon: FakeDaemon, expect: dict) -> dict[str, object]:
    """What `client` can do against `daemon`: each item of `expect` that is true is waited
    for (up to HANG_S), each that is false looked for after `Link.sync`."""
    link = Link(client, daemon, expect)
    got: list[bytes] = []
    sub = client.declare_subscriber(
        KEYS.progress, direct(lambda s: got.append(s.payload.to_bytes()))
    )
    alive: list[str] = []
    live = client.liveliness().declare_subscriber(
        KEYS.alive(DAEMON_NODE), direct(lambda s: alive.append(str(s.kind))), history=True
    )
    n = len(daemon.seen_since(0))
    token = client.liveliness().declare_token(KEYS.alive(HAND_NODE))
    link.sync()  # the declarations above got in (or were refused) and were answered

    replies: dict[str, list[bytes]] = {key: [] for key in FakeDaemon.KEYS}

    def on_reply(key: str) -> Callable[[zenoh.Reply], None]:
        def record(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                replies[key].append(reply.ok.payload.to_bytes())

        return record

    for key in FakeDaemon.KEYS:
        client.get(key, direct(on_reply(key)))
    daemon.progress.put(b"p")
    link.sync()  # every reply and the publication, if let through, are here
    for key in FakeDaemon.KEYS:
        wanted = key.removeprefix(KEYS.prefix + "/") in expect["answered"]
        if wanted and not replies[key] and _until_answered(client, key):
            replies[key].append(b"")
    if expect["progress"]:

        def published() -> bool:
            daemon.progress.put(b"p")  # until the subscription got in
            return bool(got)

        _wait(published)
    if expect["daemon_alive"]:
        _wait(lambda: str(zenoh.SampleKind.PUT) in alive)
    if expect["spoofed_token_seen"]:
        _wait(lambda: bool(daemon.seen_since(n)))
    token.undeclare()
    link.sync()  # the undeclaration too: no late sample reaches a later test
    spoof = daemon.seen_since(n)
    for x in (sub, live):
        x.undeclare()
    link.close()
    return {
        "answered": {k.removeprefix(KEYS.prefix + "/") for k, r in replies.items() if r},
        "progress": bool(got),
        "daemon_alive": str(zenoh.SampleKind.PUT) in alive,
        "spoofed_token_seen": bool(spoof),
    }


@pytest.fixture(scope="module")
def fake_daemons(pki: Path) -> Iterator[dict[str, tuple[FakeDaemon, str]]]:
    """The same fake daemon twice: with the shipped access control, and with it off."""
    out: dict[str, tuple[FakeDaemon, str]] = {}
    sessions = []
    try:
        for name, extra in (("acl", {}), ("no-acl", {"access_control/enabled": False})):
            endpoint = loopback_endpoint("tls")
            zs = _session(fill(pki, "daemon"), listen=endpoint, **extra)
            sessions.append(zs)
            out[name] = (FakeDaemon(zs), endpoint)
        yield out
    finally:
        for zs in reversed(sessions):
            zs.close()


def _probe_as(
    pki: Path, daemon: FakeDaemon, endpoint: str, role: str, expect: dict
) -> dict[str, object]:
    with _session(fill(pki, role), connect=endpoint) as zs:
        return probe(zs.session, daemon, expect)


NOTHING = {
    "answered": set(),
    "progress": False,
    "daemon_alive": False,
    "spoofed_token_seen": False,
}


def test_shipped_files_parse_and_name_real_files(pki: Path) -> None:
    for role in ("daemon", "operator"):
        zenoh.Config.from_file(str(fill(pki, role)))  # raises on a schema error


def test_operator_may_operate_and_observe_but_not_touch_nodes(pki, fake_daemons) -> None:
    expect = {
        "answered": {"status", "recognize", "cancel", "estop"},
        "progress": True,
        "daemon_alive": True,
        "spoofed_token_seen": False,
    }
    assert _probe_as(pki, *fake_daemons["acl"], "operator", expect) == expect


def test_monitor_may_only_read_status_and_progress(pki, fake_daemons) -> None:
    expect = {
        "answered": {"status"},
        "progress": True,
        "daemon_alive": True,
        "spoofed_token_seen": False,
    }
    assert _probe_as(pki, *fake_daemons["acl"], "monitor", expect) == expect


@pytest.mark.parametrize("role", ["stranger", "outsider"])
def test_unknown_or_foreign_certificates_get_nothing(pki, fake_daemons, role) -> None:
    # stranger: our CA, a common name no subject lists -> default deny on every message;
    # outsider: another CA -> the TLS handshake fails, no session at all.
    assert _probe_as(pki, *fake_daemons["acl"], role, NOTHING) == NOTHING


def test_no_client_certificate_no_session(pki, fake_daemons) -> None:
    daemon, endpoint = fake_daemons["acl"]
    no_cert = {
        "transport/link/tls/enable_mtls": False,
        "transport/link/tls/connect_certificate": None,
        "transport/link/tls/connect_private_key": None,
    }
    with _session(fill(pki, "operator"), connect=endpoint, **no_cert) as zs:
        assert probe(zs.session, daemon, NOTHING) == NOTHING


def test_node_certificate_may_serve_node_keys_only(pki, fake_daemons) -> None:
    # A node process may declare its tokens (hand/arm/sim) but is no client of the API.
    expect = {**NOTHING, "spoofed_token_seen": True}  # its own token alive/hand gets through
    assert _probe_as(pki, *fake_daemons["acl"], "node", expect) == expect


def test_control_without_access_control_the_probes_see_everything(pki, fake_daemons) -> None:
    """The denials above are the ACL's: with it off, the same probes reach every key and a
    monitor's fake hand token reaches the daemon (finding 1 of issue 16)."""
    expect = {
        "answered": {k.removeprefix(KEYS.prefix + "/") for k in FakeDaemon.KEYS},
        "progress": True,
        "daemon_alive": True,
        "spoofed_token_seen": True,
    }
    assert _probe_as(pki, *fake_daemons["no-acl"], "monitor", expect) == expect


# --------------------------------------------------------------------------- the real daemon


@pytest.fixture(scope="module")
def tls_daemon(
    pki: Path, trained_home: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[str]:
    endpoint = loopback_endpoint("tls")
    d = DaemonProcess(
        [
            "--sim", "--data", str(trained_home), "--robot", ROBOT, "--listen", endpoint,
            "--set", f"service.zenoh_config={fill(pki, 'daemon')}",
        ],
        tmp_path_factory.mktemp("tls-daemon") / "daemon.log",
    )  # fmt: skip
    try:
        with open_client([endpoint], ROBOT, zenoh_config=fill(pki, "operator"), wait=START_TIMEOUT):
            pass
        assert d.running(), d.text()
        yield endpoint
        # Generous: the SIGTERM time itself is promised and tested elsewhere
        # (test_daemon_hostile); a loaded CI machine takes longer to tear down.
        assert d.stop(timeout=20.0) == 0, d.text()
    finally:
        d.kill()


@pytest.mark.slow
def test_daemon_over_mutual_tls_obeys_the_roles(pki: Path, tls_daemon: str) -> None:
    endpoint = tls_daemon
    # The monitor: status yes; recognize and estop never reach the daemon.
    with open_client([endpoint], ROBOT, zenoh_config=fill(pki, "monitor"), timeout=HANG_S) as mon:
        assert mon.status().robot == ROBOT
        for call in (
            lambda: mon.estop("monitor tries"),
            lambda: mon.recognize(
                RecognizeRequest(policy="random", max_moves=2, object="cup"), timeout=HANG_S
            ),
        ):
            # "no ... answers on <key>": refused (a timeout says "did not answer within")
            with pytest.raises(NodeUnavailableError, match="answers on"):
                call()
        # A monitor faking the hand node's death changes nothing (finding 1).
        # Each status call is a round trip on the monitor's link: the daemon has handled the
        # token's declaration (then its undeclaration) before it answers.
        token = mon._session.liveliness().declare_token(KEYS.alive(HAND_NODE))
        assert mon.status().robot == ROBOT
        token.undeclare()
        assert mon.status().robot == ROBOT
        # Ends at once: the node's queryable was never declared to the monitor.
        assert not _answers(mon._session, KEYS.arm_joint_state)

    with open_client([endpoint], ROBOT, zenoh_config=fill(pki, "operator"), timeout=HANG_S) as op:
        status = op.status()
        assert status.robot == ROBOT and status.model_loaded and status.session is None
        assert status.nodes[HAND_NODE].alive, status
        seen = []
        result = op.recognize(
            RecognizeRequest(policy="random", max_moves=2, seed=1, object="cup"),
            on_progress=seen.append,
            timeout=120.0,
        )
        assert 1 <= result.moves <= 2 and len(seen) == result.moves, result
        # Node keys stay out of reach for the operator too.
        assert not _answers(op._session, KEYS.arm_joint_state)
        assert not _answers(op._session, KEYS.hand_state)


# --------------------------------------------------------------------------- the ROS 2 face


class _AnsweringService:
    """Stands in for the recognition service behind a real `Ros2Face`: answers every request."""

    keys = KEYS

    def __init__(self) -> None:
        self.observers: list = []

    def submit(self, key: str, query: object) -> None:
        from activetouch.transport.messages import EStopResult, Reply, encode

        with query:  # type: ignore[attr-defined]
            query.reply(key, encode(Reply.success(EStopResult(arm_stopped=True, hand_opened=True))))  # type: ignore[attr-defined]


class _Ros2Caller:
    """Service requests as an rmw_zenoh client sends them (CDR payload, ROS attachment)."""

    def __init__(self, client: zenoh.Session, face: object) -> None:
        self.client = client
        self.keys = {name: ep.key for name, ep in face.services.items()}  # type: ignore[attr-defined]
        self._seq = 0

    def request(self, name: str, handler: object, timeout: float = HANG_S) -> object:
        import os
        import struct

        self._seq += 1
        att = struct.pack("<qq", self._seq, time.time_ns()) + b"\x10" + os.urandom(16)
        return self.client.get(self.keys[name], handler, payload=b"\x00\x01\x00\x00\x00",
                               attachment=att, target=zenoh.QueryTarget.ALL_COMPLETE,
                               timeout=timeout)  # fmt: skip

    @staticmethod
    def is_answer(reply: zenoh.Reply) -> bool:
        return reply.ok is not None and reply.ok.attachment is not None

    def answers(self, name: str) -> bool:
        return any(self.is_answer(r) for r in self.request(name, None))  # type: ignore[attr-defined]

    def until_answered(self, name: str) -> bool:
        return _wait(lambda: self.answers(name))


def _ros2_probe(
    client: zenoh.Session, face: object, daemon: zenoh.Session, expect: dict
) -> dict[str, object]:
    """As `probe`: what `expect` says arrives is waited for; what it says does not is looked
    for after a status call (the face answers its requests one at a time, in order), or,
    for a role allowed no call, SETTLE_S."""
    from activetouch.transport.messages import JointStateMsg, encode

    caller = _Ros2Caller(client, face)

    def sync() -> None:
        if "status" in expect["answered"]:
            assert caller.until_answered("status"), f"no status answer within {HANG_S} s"
        else:
            time.sleep(SETTLE_S)

    got: list[bytes] = []
    sub = client.declare_subscriber(
        face.topics["joint_states"].key,  # type: ignore[attr-defined]
        direct(lambda s: got.append(s.payload.to_bytes())),
    )
    sync()  # the face's declarations are here, the subscription got in (or was refused)
    answered: set[str] = set()

    def on_reply(name: str) -> Callable[[zenoh.Reply], None]:
        def record(reply: zenoh.Reply) -> None:
            if caller.is_answer(reply):
                answered.add(name)

        return record

    for name in caller.keys:
        caller.request(name, direct(on_reply(name)))
    state = encode(JointStateMsg(names=["s0"], position=[0.1]))
    daemon.put(KEYS.arm_joint_states, state)
    sync()  # every answer and the joint state, if let through, are here
    answered |= {name for name in expect["answered"] - answered if caller.until_answered(name)}
    if expect["joint_states"]:

        def published() -> bool:
            daemon.put(KEYS.arm_joint_states, state)  # until the subscription got in
            return bool(got)

        _wait(published)
    sub.undeclare()
    liveliness = client.liveliness()

    def graph() -> bool:
        return any(r.ok is not None for r in liveliness.get("@ros2_lv/0/**", timeout=HANG_S))

    seen_graph = _wait(graph) if expect["graph"] else graph()
    return {"answered": answered, "graph": seen_graph, "joint_states": bool(got)}


def test_ros2_face_keys_obey_the_roles(pki: Path) -> None:
    """The real ROS 2 face on a session with the shipped daemon file: operators may call all
    four services and see the graph and the topics, monitors only status and the rest of it,
    a stranger nothing."""
    from activetouch.config import load_config
    from activetouch.daemon.ros2_face import Ros2Face

    endpoint = loopback_endpoint("tls")
    with _session(fill(pki, "daemon"), listen=endpoint) as zs:
        face = Ros2Face(zs.session, _AnsweringService(), load_config(None, ["ros2.enabled=true"]))
        zs.closing(face)
        face.start()
        expect = {
            "operator": {
                "answered": {"recognize", "cancel", "estop", "status"},
                "graph": True,
                "joint_states": True,
            },
            "monitor": {"answered": {"status"}, "graph": True, "joint_states": True},
            "stranger": {"answered": set(), "graph": False, "joint_states": False},
        }
        got = {}
        for role in expect:
            with _session(fill(pki, role), connect=endpoint) as client:
                got[role] = _ros2_probe(client.session, face, zs.session, expect[role])
    assert got == expect
