"""Loopback ports for tests that open real sockets."""

from __future__ import annotations

import socket


def free_udp_port() -> int:
    """A loopback UDP port free at the time of asking (bind one, read its number, close it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
