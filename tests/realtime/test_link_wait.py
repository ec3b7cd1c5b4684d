"""The stream's wait between polls (companion/realtime/link_wait.py): asleep until a link has bytes.

Real loopback sockets and a pseudo-terminal, no flight: a wait ends when a datagram or serial
bytes arrive, runs to the next tick when nothing does, falls back to the poll period for
in-memory links and injected sleeps, and never spins on a descriptor that stays readable
with nothing to parse.
"""

from __future__ import annotations

import os
import socket
import time

import pytest

from companion.mavlink.link import MemoryLink, open_link
from companion.realtime.link_wait import LinkWait
from tests.support.ports import free_udp_port


@pytest.fixture
def udp_link():
    port = free_udp_port()
    link = open_link(f"udpin:127.0.0.1:{port}", clock=time.time)
    yield link, port
    link.close()


def _timed(fn) -> float:
    t0 = time.monotonic()
    fn()
    return time.monotonic() - t0


def test_that_a_wait_ends_when_a_datagram_arrives_and_runs_to_the_tick_otherwise(udp_link):
    link, port = udp_link
    wait = LinkWait([link], time.sleep, poll_period_s=0.002)
    try:
        assert wait.on_descriptors and link.fileno() is not None
        assert 0.045 <= _timed(lambda: wait.wait(0.05)) < 0.2    # nothing came: the whole 50 ms
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"\xfd\x00", ("127.0.0.1", port))
            assert _timed(lambda: wait.wait(2.0)) < 0.1           # a packet: at once, not after 2 s
    finally:
        wait.close()


def test_that_a_link_that_stays_readable_is_polled_once_a_poll_period_never_in_a_spin(udp_link):
    link, port = udp_link
    wait = LinkWait([link], time.sleep, poll_period_s=0.2)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"not mavlink", ("127.0.0.1", port))   # left unread: the socket stays readable
            time.sleep(0.02)
            assert _timed(lambda: wait.wait(5.0)) < 0.1            # woke on it
            for _ in range(3):                                      # still readable: once a poll period
                assert 0.19 <= _timed(lambda: wait.wait(5.0)) < 0.5
    finally:
        wait.close()


def test_that_serial_bytes_end_a_wait():
    master, slave = os.openpty()
    link = open_link(os.ttyname(slave))
    wait = LinkWait([link], time.sleep, poll_period_s=0.002)
    try:
        assert wait.on_descriptors
        assert _timed(lambda: wait.wait(0.05)) >= 0.045
        os.write(master, b"\xfd")
        assert _timed(lambda: wait.wait(2.0)) < 0.1
    finally:
        wait.close()
        link.close()
        os.close(slave)
        os.close(master)


def test_that_a_tcpin_link_is_waited_on_through_its_connection_once_the_peer_connects():
    port = free_udp_port()
    link = open_link(f"tcpin:127.0.0.1:{port}")
    wait = LinkWait([link], time.sleep, poll_period_s=0.002)
    try:
        listening = link.fileno()
        with socket.create_connection(("127.0.0.1", port), timeout=5) as peer:
            assert _timed(lambda: wait.wait(2.0)) < 0.1     # the connection itself ends the wait
            link.poll()                                     # pymavlink accepts it on a read
            assert link.fileno() not in (None, listening)   # now the connection's descriptor
            assert 0.045 <= _timed(lambda: wait.wait(0.05)) < 0.2
            peer.sendall(b"\xfd")
            assert _timed(lambda: wait.wait(2.0)) < 0.1     # bytes on the connection end it
    finally:
        wait.close()
        link.close()


def test_that_in_memory_links_and_injected_sleeps_sleep_the_poll_period(udp_link):
    slept = []
    memory = MemoryLink(clock=lambda: 0.0)
    assert memory.fileno() is None
    for links, sleep in (([memory], time.sleep), ([udp_link[0]], slept.append)):
        wait = LinkWait(links, sleep, poll_period_s=0.002)
        assert not wait.on_descriptors
        if sleep is slept.append:
            wait.wait(0.05)
            wait.wait(0.001)
            assert slept == [0.002, 0.001]                 # the poll period, never past the tick
        else:
            assert _timed(lambda: wait.wait(0.05)) < 0.03
