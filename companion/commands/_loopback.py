"""Loopback UDP ports for the commands that start processes side by side (``demo --realtime``,
``demo swap --realtime``) and for the tests that do the same.

A port found free can be taken by someone else before it is used; the callers start on
fresh ports when that happens, or wait (bounded) for the process meant to bind it.
"""

from __future__ import annotations

import socket
import subprocess
import time

from companion.errors import ConfigError

__all__ = ["free_udp_port", "free_port_run", "udp_port_taken", "wait_for_udp_listener"]

_HOST = "127.0.0.1"


def free_udp_port() -> int:
    """A loopback UDP port free at the time of asking (bind one, read its number, close it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((_HOST, 0))
        return int(s.getsockname()[1])


def free_port_run(n: int) -> int:
    """A loopback UDP port p with p .. p+n-1 free now (mavsim shifts vehicle i's ports by i).

    Raises :class:`ConfigError` after 100 tries without such a run."""
    for _ in range(100):
        base = free_udp_port()
        if base + n > 65535:
            continue
        socks: list[socket.socket] = []
        try:
            for k in range(n):
                sk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(sk)
                sk.bind((_HOST, base + k))
            return base
        except OSError:
            continue
        finally:
            for sk in socks:
                sk.close()
    raise ConfigError(f"no run of {n} free loopback UDP ports")


def udp_port_taken(port: int) -> bool:
    """Whether something holds UDP ``127.0.0.1:port`` now (binding it fails)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((_HOST, int(port)))
        except OSError:
            return True
    return False


def wait_for_udp_listener(port: int, proc: subprocess.Popen, timeout_s: float, poll_s: float = 0.05) -> bool:
    """Wait until ``proc`` (or anyone) holds UDP ``port`` on loopback, at most ``timeout_s``
    seconds (monotonic clock); stop early when ``proc`` has exited. Returns whether it is held."""
    deadline = time.monotonic() + timeout_s
    while True:
        if udp_port_taken(port):
            return True
        if proc.poll() is not None or time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)
