"""Loopback ports for tests that open real sockets: the helpers the commands use
(:mod:`companion.commands._loopback`), so tests and demos pick and probe ports alike."""

from __future__ import annotations

from companion.commands._loopback import free_port_run, free_udp_port, udp_port_taken, wait_for_udp_listener

__all__ = ["free_udp_port", "free_port_run", "udp_port_taken", "wait_for_udp_listener"]
