"""A ROS 2 client over Zenoh written for the tests from rmw_zenoh's documented behaviour
(ros2/rmw_zenoh docs/design.md, liveliness_utils.cpp, rmw_client_data.cpp), sharing no code with
the daemon's face: its own keys, tokens and attachments; rosbags for CDR.

It does what an rmw_zenoh node does: declares its node (NN) and client (SC) liveliness tokens,
waits for a service's SS token before calling (``wait_for_service``), queries with target
ALL_COMPLETE and a 33-byte attachment (int64 sequence number, int64 timestamp, 16, 16-byte
GID), keeps only replies that carry an attachment echoing its sequence number and GID, and
subscribes to topics on their data keys. Loopback only, scouting off.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import struct
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

DOMAIN = 0
# Published value (several independent implementations agree; the tests recompute it).
TRIGGER_HASH = "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"


def wire_type(type_name: str) -> str:
    pkg, kind, name = type_name.split("/")
    return pkg + "::" + kind + "::dds_::" + name + "_"


def key_of(name: str, type_name: str, type_hash: str, domain: int = DOMAIN) -> str:
    return "/".join([str(domain), name.lstrip("/"), wire_type(type_name), type_hash])


def make_attachment(seq: int, gid: bytes, stamp_ns: int | None = None) -> bytes:
    stamp = time.time_ns() if stamp_ns is None else stamp_ns
    return struct.pack("<q", seq) + struct.pack("<q", stamp) + bytes([16]) + gid


def make_legacy_attachment(seq: int, gid: bytes) -> bytes:
    out = b""
    for label, value in (
        ("sequence_number", struct.pack("<q", seq)),
        ("source_timestamp", struct.pack("<q", time.time_ns())),
        ("source_gid", bytes([16]) + gid),
    ):
        out += bytes([len(label)]) + label.encode() + value
    return out


def read_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, timestamp, gid) of a 33-byte attachment."""
    assert len(data) == 33 and data[16] == 16, data
    seq, stamp = struct.unpack("<qq", data[:16])
    return seq, stamp, data[17:]


@dataclass
class Token:
    """One parsed liveliness token of the graph."""

    zid: str
    kind: str
    namespace: str
    node: str
    name: str = ""
    type: str = ""
    hash: str = ""
    qos: str = ""


def parse_token(key: str) -> Token | None:
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != "@ros2_lv":
        return None

    def un(p: str) -> str:
        return p.replace("%", "/")

    tok = Token(zid=parts[2], kind=parts[5], namespace=un(parts[7]), node=un(parts[8]))
    if len(parts) >= 13:
        tok.name, tok.type, tok.hash, tok.qos = un(parts[9]), un(parts[10]), parts[11], parts[12]
    return tok


@dataclass
class Reply:
    payload: bytes
    attachment: bytes


@dataclass
class RosTestClient:
    """Node ``/test_client`` of ROS 2 domain 0, connected to one loopback endpoint."""

    endpoint: str
    node: str = "test_client"
    domain: int = DOMAIN
    session: Any = None
    _tokens: list = field(default_factory=list)
    _subs: list = field(default_factory=list)
    _seq: int = 0
    gid: bytes = field(default_factory=lambda: os.urandom(16))

    def __enter__(self) -> RosTestClient:
        conf = zenoh.Config()
        for k, v in (
            ("mode", "peer"),
            ("scouting/multicast/enabled", False),
            ("scouting/gossip/enabled", False),
            ("listen/endpoints", []),
            ("connect/endpoints", [self.endpoint]),
        ):
            conf.insert_json5(k, json.dumps(v))
        self.session = zenoh.open(conf)
        self.zid = str(self.session.zid())
        self._declare(f"@ros2_lv/{self.domain}/{self.zid}/0/0/NN/%/%/{self.node}")
        return self

    def __exit__(self, *exc: object) -> None:
        for obj in (*self._tokens, *self._subs):
            with contextlib.suppress(Exception):
                obj.undeclare()
        self.session.close()

    def _declare(self, key: str) -> None:
        self._tokens.append(self.session.liveliness().declare_token(key))

    def graph(self, timeout: float = 10.0) -> list[Token]:
        replies = self.session.liveliness().get(f"@ros2_lv/{self.domain}/**", timeout=timeout)
        out = []
        for r in replies:
            if r.ok is not None:
                tok = parse_token(str(r.ok.key_expr))
                if tok is not None:
                    out.append(tok)
        return out

    def wait_for_service(self, name: str, type_name: str, timeout: float = 30.0) -> Token:
        """Block until an SS token for `name` of `type_name` is in the graph (as rclcpp does)."""
        found: queue.SimpleQueue = queue.SimpleQueue()

        def on_token(sample: Any) -> None:
            tok = parse_token(str(sample.key_expr))
            if (
                sample.kind == zenoh.SampleKind.PUT
                and tok is not None
                and tok.kind == "SS"
                and tok.name == name
                and tok.type == wire_type(type_name)
            ):
                found.put(tok)

        sub = self.session.liveliness().declare_subscriber(
            f"@ros2_lv/{self.domain}/**", on_token, history=True
        )
        try:
            return found.get(timeout=timeout)
        finally:
            sub.undeclare()

    def call(
        self,
        name: str,
        type_name: str,
        type_hash: str,
        request: bytes,
        legacy: bool = False,
        timeout: float = 60.0,
    ) -> list[Reply]:
        """One service call: every reply that carries an attachment (rmw_zenoh drops others)."""
        self._seq += 1
        eid = 100 + self._seq
        self._declare(
            f"@ros2_lv/{self.domain}/{self.zid}/0/{eid}/SC/%/%/{self.node}/"
            f"{name.replace('/', '%')}/"
            f"{wire_type(type_name)}/{type_hash}/::,10:,:,:,,"
        )
        att = (make_legacy_attachment if legacy else make_attachment)(self._seq, self.gid)
        out = []
        for r in self.session.get(
            key_of(name, type_name, type_hash, self.domain),
            payload=request,
            attachment=att,
            target=zenoh.QueryTarget.ALL_COMPLETE,
            timeout=timeout,
        ):
            if r.ok is None or r.ok.attachment is None:
                continue
            out.append(Reply(r.ok.payload.to_bytes(), r.ok.attachment.to_bytes()))
        return out

    def subscribe(self, name: str, type_name: str, type_hash: str) -> queue.SimpleQueue:
        """Samples of a topic, as (payload, attachment) pairs, in a queue."""
        q: queue.SimpleQueue = queue.SimpleQueue()
        key = key_of(name, type_name, type_hash, self.domain)
        eid = 500 + len(self._subs)
        self._declare(
            f"@ros2_lv/{self.domain}/{self.zid}/0/{eid}/MS/%/%/{self.node}/"
            f"{name.replace('/', '%')}/"
            f"{wire_type(type_name)}/{type_hash}/::,10:,:,:,,"
        )

        def on_sample(sample: Any) -> None:
            att = sample.attachment
            q.put((sample.payload.to_bytes(), att.to_bytes() if att is not None else None))

        self._subs.append(self.session.declare_subscriber(key, on_sample))
        return q
