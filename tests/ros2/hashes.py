"""RIHS01 hashes computed in the tests from the files of ros2/activetouch_interfaces/ (and
std_srvs/Trigger from its definition), with rosbags alone: each .msg / .srv parsed with
`get_types_from_msg`, registered, and each service described as ROS 2 hashes one (request,
response, and the event message with service_msgs/ServiceEventInfo, whose ``char[16]
client_gid`` rosidl hashes as uint8)."""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DIR = ROOT / "ros2" / "activetouch_interfaces"
PKG = "activetouch_interfaces"

EVENT_INFO = """uint8 event_type
builtin_interfaces/msg/Time stamp
uint8[16] client_gid
int64 sequence_number
"""


def _as(defs: dict[str, Any], names: dict[str, str]) -> dict[str, Any]:
    def walk(o: Any) -> Any:
        if isinstance(o, str):
            return names.get(o, o)
        if isinstance(o, tuple | list):
            return type(o)(walk(x) for x in o)
        return o

    return {walk(k): walk(v) for k, v in defs.items()}


def srv_defs(pkg: str, name: str, text: str) -> dict[str, Any]:
    """Request, Response, Event and the service itself, named pkg/srv/..."""
    from rosbags.typesys import get_types_from_msg

    lines = text.splitlines()
    cut = next(i for i, line in enumerate(lines) if line.strip() == "---")
    m = f"{pkg}/msg/{name}"
    defs: dict[str, Any] = {}
    defs.update(get_types_from_msg("\n".join(lines[:cut]) + "\n", f"{m}_Request"))
    defs.update(get_types_from_msg("\n".join(lines[cut + 1 :]) + "\n", f"{m}_Response"))
    defs.update(
        get_types_from_msg(
            f"service_msgs/msg/ServiceEventInfo info\n{m}_Request[<=1] request\n"
            f"{m}_Response[<=1] response\n",
            f"{m}_Event",
        )
    )
    defs.update(
        get_types_from_msg(
            f"{m}_Request request_message\n{m}_Response response_message\n"
            f"{m}_Event event_message\n",
            m,
        )
    )
    names = {f"{m}{s}": f"{pkg}/srv/{name}{s}" for s in ("", "_Request", "_Response", "_Event")}
    return _as(defs, names)


def file_defs() -> dict[str, Any]:
    from rosbags.typesys import get_types_from_msg

    defs: dict[str, Any] = {}
    for f in sorted((PACKAGE_DIR / "msg").glob("*.msg")):
        defs.update(get_types_from_msg(f.read_text(), f"{PKG}/msg/{f.stem}"))
    for f in sorted((PACKAGE_DIR / "srv").glob("*.srv")):
        defs.update(srv_defs(PKG, f.stem, f.read_text()))
    return defs


@cache
def hashing_store() -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    jazzy = get_typestore(Stores.ROS2_JAZZY)
    store = get_typestore(Stores.EMPTY)
    defs = {k: v for k, v in jazzy.fielddefs.items() if not k.startswith("service_msgs/")}
    defs.update(get_types_from_msg(EVENT_INFO, "service_msgs/msg/ServiceEventInfo"))
    defs.update(srv_defs("std_srvs", "Trigger", "---\nbool success\nstring message\n"))
    defs.update(file_defs())
    store.register(defs)
    return store


def rihs01(type_name: str) -> str:
    return hashing_store().hash_rihs01(type_name)
