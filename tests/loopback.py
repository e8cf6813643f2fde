"""Loopback endpoints for the suite: every Zenoh peer in a test listens on 127.0.0.1 only, on a
port that was free a moment ago (scouting is off in `ZenohSettings`, so nothing leaves the host)."""

from __future__ import annotations

from activetouch.transport.zenoh_session import free_tcp_port


def loopback_endpoint(scheme: str = "tcp") -> str:
    """``tcp/127.0.0.1:<free port>`` (or ``tls/...``)."""
    return f"{scheme}/127.0.0.1:{free_tcp_port()}"
