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


def _answers(session: zenoh.Session, key: str, timeout: float = 2.0) -> list[bytes]:
    """Payloads of the replies to a get on `key` (none when the ACL hides the queryable)."""
    out = []
    for reply in session.get(key, timeout=timeout):
        if reply.ok is not None:
            out.append(reply.ok.payload.to_bytes())
    return out


def _wait(cond: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


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
            zs.closing(s.declare_queryable(key, self._answer(key)))
        zs.closing(s.liveliness().declare_token(KEYS.alive(DAEMON_NODE)))
        zs.closing(s.liveliness().declare_subscriber(f"{KEYS.prefix}/alive/**", self._seen))
        self.progress = zs.closing(s.declare_publisher(KEYS.progress))

    @staticmethod
    def _answer(key: str) -> Callable[[zenoh.Query], None]:
        return lambda q: q.reply(key, key.encode())

    def _seen(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.tokens_seen.append(f"{sample.kind} {sample.key_expr}")


def probe(client: zenoh.Session, daemon: FakeDaemon) -> dict[str, object]:
    """What `client` can do against `daemon`."""
    got: list[bytes] = []
    sub = client.declare_subscriber(KEYS.progress, lambda s: got.append(s.payload.to_bytes()))
    alive: list[str] = []
    live = client.liveliness().declare_subscriber(
        KEYS.alive(DAEMON_NODE), lambda s: alive.append(str(s.kind)), history=True
    )
    answered = {key: bool(_answers(client, key)) for key in FakeDaemon.KEYS}
    # Publish until the subscription got in (or 1 s): a denied one never does.
    deadline = time.monotonic() + 1.0
    while not got and time.monotonic() < deadline:
        daemon.progress.put(b"p")
        time.sleep(0.05)
    n = len(daemon.tokens_seen)
    token = client.liveliness().declare_token(KEYS.alive(HAND_NODE))
    time.sleep(0.3)
    token.undeclare()
    time.sleep(0.3)
    spoof = daemon.tokens_seen[n:]
    for x in (sub, live):
        x.undeclare()
    return {
        "answered": {k.removeprefix(KEYS.prefix + "/") for k, ok in answered.items() if ok},
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


def _probe_as(pki: Path, daemon: FakeDaemon, endpoint: str, role: str) -> dict[str, object]:
    with _session(fill(pki, role), connect=endpoint) as zs:
        return probe(zs.session, daemon)


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
    assert _probe_as(pki, *fake_daemons["acl"], "operator") == {
        "answered": {"status", "recognize", "cancel", "estop"},
        "progress": True,
        "daemon_alive": True,
        "spoofed_token_seen": False,
    }


def test_monitor_may_only_read_status_and_progress(pki, fake_daemons) -> None:
    assert _probe_as(pki, *fake_daemons["acl"], "monitor") == {
        "answered": {"status"},
        "progress": True,
        "daemon_alive": True,
        "spoofed_token_seen": False,
    }


@pytest.mark.parametrize("role", ["stranger", "outsider"])
def test_unknown_or_foreign_certificates_get_nothing(pki, fake_daemons, role) -> None:
    # stranger: our CA, a common name no subject lists -> default deny on every message;
    # outsider: another CA -> the TLS handshake fails, no session at all.
    assert _probe_as(pki, *fake_daemons["acl"], role) == NOTHING


def test_no_client_certificate_no_session(pki, fake_daemons) -> None:
    daemon, endpoint = fake_daemons["acl"]
    no_cert = {
        "transport/link/tls/enable_mtls": False,
        "transport/link/tls/connect_certificate": None,
        "transport/link/tls/connect_private_key": None,
    }
    with _session(fill(pki, "operator"), connect=endpoint, **no_cert) as zs:
        assert probe(zs.session, daemon) == NOTHING


def test_node_certificate_may_serve_node_keys_only(pki, fake_daemons) -> None:
    # A node process may declare its tokens (hand/arm/sim) but is no client of the API.
    daemon, endpoint = fake_daemons["acl"]
    with _session(fill(pki, "node"), connect=endpoint) as zs:
        got = probe(zs.session, daemon)
    assert got["answered"] == set() and not got["progress"] and not got["daemon_alive"]
    assert got["spoofed_token_seen"]  # the node's own token alive/hand gets through


def test_control_without_access_control_the_probes_see_everything(pki, fake_daemons) -> None:
    """The denials above are the ACL's: with it off, the same probes reach every key and a
    monitor's fake hand token reaches the daemon (finding 1 of issue 16)."""
    got = _probe_as(pki, *fake_daemons["no-acl"], "monitor")
    assert got["answered"] == {k.removeprefix(KEYS.prefix + "/") for k in FakeDaemon.KEYS}
    assert got["progress"] and got["daemon_alive"] and got["spoofed_token_seen"]


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
    with open_client([endpoint], ROBOT, zenoh_config=fill(pki, "monitor"), timeout=5.0) as mon:
        assert mon.status().robot == ROBOT
        for call in (
            lambda: mon.estop("monitor tries"),
            lambda: mon.recognize(
                RecognizeRequest(policy="random", max_moves=2, object="cup"), timeout=5.0
            ),
        ):
            # "no ... answers on <key>": refused (a timeout says "did not answer within")
            with pytest.raises(NodeUnavailableError, match="answers on"):
                call()
        # A monitor faking the hand node's death changes nothing (finding 1).
        token = mon._session.liveliness().declare_token(KEYS.alive(HAND_NODE))
        time.sleep(0.3)
        token.undeclare()
        time.sleep(0.3)
        assert not _answers(mon._session, KEYS.arm_joint_state, timeout=1.0)

    with open_client([endpoint], ROBOT, zenoh_config=fill(pki, "operator"), timeout=10.0) as op:
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
        assert not _answers(op._session, KEYS.arm_joint_state, timeout=1.0)
        assert not _answers(op._session, KEYS.hand_state, timeout=1.0)


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


def _ros2_probe(client: zenoh.Session, face: object, daemon: zenoh.Session) -> dict[str, object]:
    import os
    import struct

    from activetouch.transport.messages import JointStateMsg, encode

    answered = set()
    for name, ep in face.services.items():  # type: ignore[attr-defined]
        att = struct.pack("<qq", 1, time.time_ns()) + b"\x10" + os.urandom(16)
        for r in client.get(ep.key, payload=b"\x00\x01\x00\x00\x00", attachment=att,
                            target=zenoh.QueryTarget.ALL_COMPLETE, timeout=2.0):  # fmt: skip
            if r.ok is not None and r.ok.attachment is not None:
                answered.add(name)
    tokens = [
        str(r.ok.key_expr)
        for r in client.liveliness().get("@ros2_lv/0/**", timeout=2.0)
        if r.ok is not None
    ]
    got: list[bytes] = []
    sub = client.declare_subscriber(
        face.topics["joint_states"].key,  # type: ignore[attr-defined]
        lambda s: got.append(s.payload.to_bytes()),
    )
    deadline = time.monotonic() + 1.0
    while not got and time.monotonic() < deadline:
        daemon.put(KEYS.arm_joint_states, encode(JointStateMsg(names=["s0"], position=[0.1])))
        time.sleep(0.05)
    sub.undeclare()
    return {"answered": answered, "graph": bool(tokens), "joint_states": bool(got)}


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
        got = {}
        for role in ("operator", "monitor", "stranger"):
            with _session(fill(pki, role), connect=endpoint) as client:
                got[role] = _ros2_probe(client.session, face, zs.session)
    assert got["operator"] == {
        "answered": {"recognize", "cancel", "estop", "status"},
        "graph": True,
        "joint_states": True,
    }
    assert got["monitor"] == {"answered": {"status"}, "graph": True, "joint_states": True}
    assert got["stranger"] == {"answered": set(), "graph": False, "joint_states": False}
