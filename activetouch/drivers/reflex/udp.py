"""UDP socket for the TakkTile link: unicast or multicast receive, commands to a configurable
destination. The board sends state to 224.0.0.124:11333 and takes commands on the same group
and port; every address here is configurable so tests run on unicast 127.0.0.1."""

from __future__ import annotations

import ipaddress
import socket
import struct


def is_multicast(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_multicast
    except ValueError:
        return False


def _mreqn(group: str, interface: str) -> bytes:
    """struct ip_mreqn: group, local address, interface index (an interface name or IPv4
    address in `interface`; empty: let the kernel pick)."""
    local, index = "0.0.0.0", 0
    if interface:
        try:
            ipaddress.IPv4Address(interface)
            local = interface
        except ValueError:
            index = socket.if_nametoindex(interface)  # OSError for an unknown interface
    return socket.inet_aton(group) + socket.inet_aton(local) + struct.pack("@i", index)


def should_join(listen_host: str, group: str) -> bool:
    """Join `group` only when listening on the wildcard or on the group itself; a driver bound
    to a unicast address (127.0.0.1 in tests) never joins."""
    return bool(group) and listen_host in ("", "0.0.0.0", group)


def open_socket(
    listen: tuple[str, int],
    group: str,
    interface: str,
    command_to: tuple[str, int],
    rcvbuf: int = 1 << 20,
) -> socket.socket:
    """A bound UDP socket for state packets that also sends the commands."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        host, port = listen
        s.bind((host, port))
        if should_join(host, group):
            s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, _mreqn(group, interface))
        if is_multicast(command_to[0]):
            # Commands to the group leave on the hand's interface; do not hear them back.
            s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, _mreqn("0.0.0.0", interface))
            s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 0)
            s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    except BaseException:
        s.close()
        raise
    return s
