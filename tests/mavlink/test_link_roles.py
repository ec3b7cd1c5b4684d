"""Link roles: receive-only obstacle links, and a udpin autopilot link that answers the autopilot only."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import LinkError
from companion.mavlink import messages
from companion.mavlink.link import MemoryLink, open_link
from tests.support.ports import free_udp_port


def _peer(sysid: int, compid: int) -> tuple[socket.socket, mavlink2.MAVLink]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.05)
    return sock, mavlink2.MAVLink(None, sysid, compid)


def _drain(sock: socket.socket) -> int:
    n = 0
    try:
        while True:
            sock.recv(65535)
            n += 1
    except (TimeoutError, socket.timeout):
        return n


def _hear(link, n: int) -> set:
    """Poll ``link`` until ``n`` messages arrived (2 s at most); the senders' system ids."""
    deadline, seen, count = time.monotonic() + 2.0, set(), 0
    while count < n and time.monotonic() < deadline:
        got = link.poll()
        count += len(got)
        seen |= {rx.msg.get_srcSystem() for rx in got}
        time.sleep(0.01)
    return seen


def test_that_an_obstacle_link_is_receive_only_and_tags_what_it_receives():
    link = MemoryLink(clock=lambda: 0.0, name="obstacles1", receive_only=True)
    sender = mavlink2.MAVLink(None, 101, 197)
    link.deliver(1.0, mavlink2.MAVLink_heartbeat_message(0, 8, 0, 0, 4, 3).pack(sender))
    (rx,) = link.poll()
    assert rx.link == "obstacles1" and rx.msg.get_srcSystem() == 101
    with pytest.raises(LinkError, match="receive-only"):
        link.send(messages.companion_heartbeat())
    assert link.take_outbound() == [] and link.stats.sent == 0


def test_that_a_udpin_link_sends_only_to_the_autopilots_address_never_to_every_address_it_heard():
    port = free_udp_port()
    link = open_link(f"udpin:127.0.0.1:{port}", clock=time.time)
    autopilot, ap_mav = _peer(1, 1)
    rogue, rogue_mav = _peer(150, 197)
    try:
        autopilot.sendto(mavlink2.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3).pack(ap_mav), ("127.0.0.1", port))
        time.sleep(0.05)
        rogue.sendto(mavlink2.MAVLink_heartbeat_message(0, 8, 0, 0, 4, 3).pack(rogue_mav), ("127.0.0.1", port))
        assert _hear(link, 2) == {1, 150}
        assert all(rx.link == "autopilot" for rx in link.poll())
        link.peer = (1, 1)  # the loop sets the autopilot it follows
        for _ in range(5):
            link.send(messages.companion_heartbeat())
        assert _drain(autopilot) == 5
        assert _drain(rogue) == 0  # pymavlink's own udpin writer would have sent it all five
        link.peer = (7, 1)  # an autopilot not heard on this link: nothing goes anywhere, and it is counted
        link.send(messages.companion_heartbeat())
        assert link.stats.unaddressed == 1 and _drain(autopilot) == 0 and _drain(rogue) == 0
    finally:
        link.close()
        autopilot.close()
        rogue.close()


def test_that_before_the_autopilot_is_known_a_udpin_link_sends_to_nobody_and_counts_it():
    """A rogue heard first must not get the companion's HEARTBEATs (a clean-clone CI run caught
    three going to an obstacle source on the autopilot port before PX4 was heard)."""
    port = free_udp_port()
    link = open_link(f"udpin:127.0.0.1:{port}", clock=time.time)
    rogue, rogue_mav = _peer(150, 197)
    autopilot, ap_mav = _peer(1, 1)
    try:
        rogue.sendto(mavlink2.MAVLink_heartbeat_message(0, 8, 0, 0, 4, 3).pack(rogue_mav), ("127.0.0.1", port))
        assert _hear(link, 1) == {150}
        link.send(messages.companion_heartbeat())
        assert _drain(rogue) == 0 and link.stats.unaddressed == 1
        autopilot.sendto(mavlink2.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3).pack(ap_mav), ("127.0.0.1", port))
        assert _hear(link, 1) == {1}
        link.peer = (1, 1)
        link.send(messages.companion_heartbeat())
        assert _drain(autopilot) == 1 and _drain(rogue) == 0
    finally:
        link.close()
        rogue.close()
        autopilot.close()
