"""The rmw_zenoh wire protocol, low level: key expressions, liveliness tokens, attachments, CDR
payloads and RIHS01 type hashes, so that a plain Zenoh session appears in a ROS 2 graph whose
nodes run rmw_zenoh (the daemon's ROS 2 face, activetouch/daemon/ros2_face.py; docs/api.md).

Facts (from ros2/rmw_zenoh: docs/design.md, src/detail/liveliness_utils.cpp, qos.cpp,
attachment_helpers.cpp, rmw_client_data.cpp, rmw_service_data.cpp):

- Data key of a topic or service: ``<domain>/<name without its leading '/'>/<DDS type>/<hash>``,
  the DDS type written ``pkg::msg::dds_::Name_`` (a service: ``pkg::srv::dds_::Name_``, its
  Request / Response type without the suffix) and the hash ``RIHS01_<64 hex>``, the type's
  (for a service: the whole service's) RIHS01 hash.
- Liveliness tokens: ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/<NN|MP|MS|SS|SC>/<enclave>/
  <namespace>/<node>`` and, for everything but a node, ``/<name>/<DDS type>/<hash>/<qos>``;
  every ``/`` inside a part written ``%`` (the root namespace and enclave ``/`` become ``%``).
  The QoS part lists each policy that differs from rmw_zenoh's defaults (reliable, volatile,
  keep last 42, infinite deadline / lifespan / lease, automatic liveliness), empty otherwise:
  ``reliability:durability:history,depth:deadline_s,ns:lifespan_s,ns:liveliness,s,ns``.
- Clients query with target ALL_COMPLETE (a server's queryable must be declared complete) and
  drop replies without an attachment; a server replies on its service key with the client's
  sequence number and GID and its own timestamp.
- Attachment ("gid", rmw_zenoh Jazzy >= 0.2.4 / Rolling >= 0.6.0): int64 sequence number,
  int64 source timestamp (ns), the GID as a sequence (length byte 16, then 16 bytes): 33 bytes,
  little endian. Before ("legacy"): each value preceded by its label as a length-prefixed
  string: ``sequence_number``, ``source_timestamp``, ``source_gid``.
- Payloads are CDR with the 4-byte encapsulation header (rosbags' typestore writes it).

GIDs: rmw_zenoh derives an entity's GID from an XXH3-128 hash of its liveliness key; this
module uses BLAKE2b-128 of the same key (no xxhash here). A GID is opaque to its peers: clients
get their own back, subscribers only report it, so nothing depends on which hash made it.
"""

from __future__ import annotations

import hashlib
import re
import struct
import time
from dataclasses import dataclass
from typing import Any, Literal

from activetouch.errors import MessageError

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION, SERVICE, CLIENT = "NN", "MP", "MS", "SS", "SC"
ENTITY_KINDS = (NODE, PUBLISHER, SUBSCRIPTION, SERVICE, CLIENT)
GID_SIZE = 16
AttachmentFormat = Literal["gid", "legacy"]
ATTACHMENT_FORMATS: tuple[str, ...] = ("gid", "legacy")
CDR_LE_HEADER = b"\x00\x01\x00\x00"

# rmw's QoS enums (rmw/types.h) and rmw_zenoh's defaults (qos.cpp).
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2
DEFAULT_DEPTH = 42

_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(msg|srv)/([A-Za-z][A-Za-z0-9_]*)$")


# --------------------------------------------------------------------------- names and keys


def mangle(name: str) -> str:
    """A name as one key chunk: every ``/`` written ``%``."""
    return name.replace("/", "%")


def demangle(part: str) -> str:
    return part.replace("%", "/")


def dds_type(type_name: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``; a service
    ``std_srvs/srv/Trigger`` -> ``std_srvs::srv::dds_::Trigger_``."""
    m = _TYPE.fullmatch(type_name)
    if m is None:
        raise ValueError(f"not a ROS 2 type name (pkg/msg/Name or pkg/srv/Name): {type_name!r}")
    pkg, kind, name = m.groups()
    return f"{pkg}::{kind}::dds_::{name}_"


def data_key(domain_id: int, name: str, type_name: str, type_hash: str) -> str:
    """The data key of topic or service `name` (fully qualified, leading ``/``)."""
    return f"{int(domain_id)}/{name.strip('/')}/{dds_type(type_name)}/{type_hash}"


def qos_key(
    *,
    depth: int = 10,
    reliability: int = RELIABLE,
    durability: int = VOLATILE,
    history: int = KEEP_LAST,
) -> str:
    """The QoS part of a liveliness token (durations and liveliness at their defaults)."""
    rel = "" if reliability == RELIABLE else str(reliability)
    dur = "" if durability == VOLATILE else str(durability)
    hist = "" if history == KEEP_LAST else str(history)
    dep = "" if depth == DEFAULT_DEPTH else str(depth)
    return f"{rel}:{dur}:{hist},{dep}:,:,:,,"


@dataclass(frozen=True)
class NodeInfo:
    """Where a node's entities live: domain, this session's Zenoh id, node id, names."""

    domain_id: int
    zid: str
    node_id: int
    name: str
    namespace: str = "/"  # ROS namespace, "/" for the root
    enclave: str = "/"

    @property
    def fqn(self) -> str:
        """The node's fully qualified name, e.g. ``/activetouch`` or ``/lab/activetouch``."""
        return self.namespace.rstrip("/") + "/" + self.name

    def resolve(self, name: str) -> str:
        """A topic or service name made fully qualified: ``~/x`` under the node, ``x`` under
        the namespace, ``/x`` as it is."""
        if name.startswith("~/"):
            return self.fqn + name[1:]
        if name.startswith("/"):
            return name
        return self.namespace.rstrip("/") + "/" + name

    def _prefix(self, entity_id: int, kind: str) -> str:
        return "/".join(
            (
                ADMIN_SPACE,
                str(int(self.domain_id)),
                self.zid,
                str(int(self.node_id)),
                str(int(entity_id)),
                kind,
                mangle(self.enclave),
                mangle(self.namespace),
                mangle(self.name),
            )
        )

    def node_token(self) -> str:
        """The node's own liveliness key (kind NN; its entity id is its node id)."""
        return self._prefix(self.node_id, NODE)

    def entity_token(
        self, entity_id: int, kind: str, name: str, type_name: str, type_hash: str, qos: str
    ) -> str:
        """The liveliness key of a publisher, subscription, service or client of this node
        (`name` fully qualified)."""
        if kind not in ENTITY_KINDS or kind == NODE:
            raise ValueError(f"entity kind must be one of MP MS SS SC, got {kind!r}")
        return "/".join(
            (
                self._prefix(entity_id, kind),
                mangle(name),
                mangle(dds_type(type_name)),
                mangle(type_hash),
                qos,
            )
        )


def gid_of(token_key: str) -> bytes:
    """A 16-byte GID for the entity announced by `token_key` (see the module)."""
    return hashlib.blake2b(token_key.encode(), digest_size=GID_SIZE).digest()


# --------------------------------------------------------------------------- attachments


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to every request, reply and sample."""

    sequence_number: int
    timestamp_ns: int
    gid: bytes

    def __post_init__(self) -> None:
        if len(self.gid) != GID_SIZE:
            raise ValueError(f"a GID has {GID_SIZE} bytes, got {len(self.gid)}")

    def encode(self, fmt: str = "gid") -> bytes:
        seq = struct.pack("<q", self.sequence_number)
        ts = struct.pack("<q", self.timestamp_ns)
        gid = bytes([GID_SIZE]) + bytes(self.gid)
        if fmt == "gid":
            return seq + ts + gid
        if fmt == "legacy":
            return (
                _label("sequence_number")
                + seq
                + _label("source_timestamp")
                + ts
                + (_label("source_gid") + gid)
            )
        raise ValueError(f"attachment format must be one of {ATTACHMENT_FORMATS}, got {fmt!r}")


def _label(text: str) -> bytes:
    raw = text.encode()
    return bytes([len(raw)]) + raw  # the labels are < 128 bytes: a one-byte LEB128 length


_LEGACY_LABELS = ("sequence_number", "source_timestamp", "source_gid")
GID_ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
LEGACY_ATTACHMENT_SIZE = sum(1 + len(s) for s in _LEGACY_LABELS) + GID_ATTACHMENT_SIZE


def attachment_format(data: bytes) -> str:
    """Which format `data` is in ("gid" or "legacy"); MessageError if neither."""
    if len(data) == GID_ATTACHMENT_SIZE and data[16] == GID_SIZE:
        return "gid"
    if len(data) == LEGACY_ATTACHMENT_SIZE and data.startswith(_label(_LEGACY_LABELS[0])):
        return "legacy"
    raise MessageError(
        f"rmw_zenoh attachment of {len(data)} bytes is neither the 33-byte GID format nor "
        f"the {LEGACY_ATTACHMENT_SIZE}-byte labelled one (ros2.attachment)"
    )


def decode_attachment(data: bytes, fmt: str | None = None) -> tuple[Attachment, str]:
    """(the attachment, its format); `fmt` None accepts either. MessageError if malformed."""
    data = bytes(data)
    found = attachment_format(data)
    if fmt is not None and found != fmt:
        raise MessageError(f"rmw_zenoh attachment is in the {found} format, expected {fmt}")
    if found == "gid":
        seq, ts = struct.unpack_from("<qq", data, 0)
        return Attachment(seq, ts, data[17:]), found
    pos = 0
    values: list[bytes] = []
    for label, size in zip(_LEGACY_LABELS, (8, 8, 1 + GID_SIZE), strict=True):
        want = _label(label)
        if data[pos : pos + len(want)] != want:
            raise MessageError(f"legacy rmw_zenoh attachment: label {label!r} missing")
        pos += len(want)
        values.append(data[pos : pos + size])
        pos += size
    if values[2][0] != GID_SIZE:
        raise MessageError("legacy rmw_zenoh attachment: the GID is not 16 bytes")
    (seq,) = struct.unpack("<q", values[0])
    (ts,) = struct.unpack("<q", values[1])
    return Attachment(seq, ts, values[2][1:]), found


def now_ns() -> int:
    return time.time_ns()


# --------------------------------------------------------------------------- types and CDR


def _split(type_name: str) -> tuple[str, str, str]:
    m = _TYPE.fullmatch(type_name)
    if m is None:
        raise ValueError(f"not a ROS 2 type name: {type_name!r}")
    return m.group(1), m.group(2), m.group(3)


def _rename(obj: Any, old: str, new: str) -> Any:
    if isinstance(obj, str):
        return new if obj == old else obj
    if isinstance(obj, tuple):
        return tuple(_rename(x, old, new) for x in obj)
    if isinstance(obj, list):
        return [_rename(x, old, new) for x in obj]
    return obj


def parse_definitions(type_name: str, text: str) -> dict[str, Any]:
    """rosbags field definitions of one ``.msg`` (``pkg/msg/Name``) or ``.srv``
    (``pkg/srv/Name``: ``Name_Request`` and ``Name_Response``) text. Relative type names
    resolve to ``pkg/msg/...``, as rosidl resolves them."""
    # deferred: rosbags only when ROS messages are (de)serialised
    from rosbags.typesys import get_types_from_msg

    pkg, kind, name = _split(type_name)
    if kind == "msg":
        return dict(get_types_from_msg(text, type_name))
    lines = text.splitlines()
    cut = next((i for i, line in enumerate(lines) if line.strip() == "---"), None)
    if cut is None:
        raise ValueError(f"{type_name}: a .srv needs a '---' line between request and response")
    request, response = "\n".join(lines[:cut]) + "\n", "\n".join(lines[cut + 1 :]) + "\n"
    out: dict[str, Any] = {}
    for part, body in (("Request", request), ("Response", response)):
        as_msg, as_srv = f"{pkg}/msg/{name}_{part}", f"{pkg}/srv/{name}_{part}"
        for k, v in get_types_from_msg(body, as_msg).items():
            out[as_srv if k == as_msg else k] = v
    return out


def _service_description(type_name: str) -> dict[str, Any]:
    """The messages ROS 2 hashes a service as: ``Name_Event`` (service_msgs' event info, at
    most one request, at most one response) and ``Name`` (request, response, event)."""
    # deferred: rosbags only when ROS messages are (de)serialised
    from rosbags.typesys import get_types_from_msg

    pkg, _, name = _split(type_name)
    # rosbags files a name written pkg/srv/X under pkg/srv/msg/X: write pkg/msg/X, rename after.
    as_msg = {
        f"{pkg}/msg/{name}{s}": f"{type_name}{s}" for s in ("_Request", "_Response", "_Event", "")
    }
    req, resp, event, whole = as_msg
    defs: dict[str, Any] = {}
    defs.update(
        get_types_from_msg(
            f"service_msgs/msg/ServiceEventInfo info\n{req}[<=1] request\n{resp}[<=1] response\n",
            event,
        )
    )
    defs.update(
        get_types_from_msg(
            f"{req} request_message\n{resp} response_message\n{event} event_message\n", whole
        )
    )
    out: dict[str, Any] = {}
    for k, v in defs.items():
        for old, new in as_msg.items():
            k, v = _rename(k, old, new), _rename(v, old, new)
        out[k] = v
    return out


# std_srvs/srv/Trigger is not in rosbags' stores (they hold messages only).
TRIGGER = "std_srvs/srv/Trigger"
TRIGGER_SRV = "---\nbool success\nstring message\n"
# rosidl turns a .msg `char` into uint8 before hashing; rosbags' Jazzy store keeps service_msgs'
# `char[16] client_gid` as char, which changes every service hash. The hashing store uses this.
SERVICE_EVENT_INFO = (
    "uint8 REQUEST_SENT = 0\nuint8 REQUEST_RECEIVED = 1\nuint8 RESPONSE_SENT = 2\n"
    "uint8 RESPONSE_RECEIVED = 3\nuint8 event_type\nbuiltin_interfaces/msg/Time stamp\n"
    "uint8[16] client_gid\nint64 sequence_number\n"
)


class Ros2Types:
    """rosbags typestores (ROS 2 Jazzy) with extra definitions registered: CDR in and out, and
    RIHS01 hashes of messages and services."""

    def __init__(self, definitions: dict[str, str] | None = None) -> None:
        # deferred: rosbags only when ROS messages are (de)serialised
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        defs: dict[str, Any] = parse_definitions(TRIGGER, TRIGGER_SRV)
        self.services: set[str] = {TRIGGER}
        for type_name, text in (definitions or {}).items():
            defs.update(parse_definitions(type_name, text))
            if _split(type_name)[1] == "srv":
                self.services.add(type_name)
        self.store = get_typestore(Stores.ROS2_JAZZY)
        self.store.register(defs)
        # Hashing: the same types, service_msgs' event info as rosidl hashes it, and each
        # service's description.
        self._hashing = get_typestore(Stores.EMPTY)
        base = {k: v for k, v in self.store.fielddefs.items() if not k.startswith("service_msgs/")}
        base.update(get_types_from_msg(SERVICE_EVENT_INFO, "service_msgs/msg/ServiceEventInfo"))
        for srv in sorted(self.services):
            base.update(_service_description(srv))
        self._hashing.register(base)
        self._hashes: dict[str, str] = {}

    def hash(self, type_name: str) -> str:
        """``RIHS01_<hex>`` of a message type or of a whole service (``pkg/srv/Name``)."""
        h = self._hashes.get(type_name)
        if h is None:
            h = self._hashes[type_name] = self._hashing.hash_rihs01(type_name)
        return h

    def new(self, type_name: str, **fields: Any) -> Any:
        """A message of `type_name` (every field given: nested messages made by the caller)."""
        return self.store.types[type_name](**fields)

    def serialize(self, msg: Any, type_name: str) -> bytes:
        """CDR (little endian) with its encapsulation header."""
        return bytes(self.store.serialize_cdr(msg, type_name))

    def deserialize(self, data: bytes, type_name: str) -> Any:
        """A message from CDR; MessageError naming the type if the bytes are not one."""
        if len(data) < 4 or data[:2] not in (b"\x00\x00", b"\x00\x01"):
            raise MessageError(
                f"invalid {type_name}: {len(data)} bytes without a CDR encapsulation header"
            )
        try:
            return self.store.deserialize_cdr(bytes(data), type_name)
        except Exception as e:
            raise MessageError(f"invalid {type_name}: not valid CDR ({type(e).__name__})") from None
