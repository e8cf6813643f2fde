"""systemd integration of the daemon: sd_notify(3) readiness and watchdog pings."""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger("activetouch.daemon")


def sd_notify(state: str) -> bool:
    """Send `state` (e.g. ``READY=1``) to systemd's ``$NOTIFY_SOCKET``; False if there is none.

    The sd_notify(3) protocol: one datagram on a unix socket; an address starting with ``@``
    is in the abstract namespace."""
    addr = os.environ.get("NOTIFY_SOCKET")
    if not addr:
        return False
    if addr.startswith("@"):
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
            s.setblocking(False)  # a receiver that does not read must never stall the daemon
            s.connect(addr)
            s.send(state.encode())
        return True
    except OSError as e:
        log.warning("sd_notify failed", extra={"state": state, "error": str(e)})
        return False


def watchdog_period() -> float | None:
    """systemd's watchdog interval (s) for this process from ``$WATCHDOG_USEC``, or None."""
    usec = os.environ.get("WATCHDOG_USEC", "")
    pid = os.environ.get("WATCHDOG_PID", "")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    try:
        value = int(usec)
    except ValueError:
        return None
    return value / 1e6 if value > 0 else None
