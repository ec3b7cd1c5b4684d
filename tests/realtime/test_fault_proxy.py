"""The fault-injection proxy itself: forwarding both ways, and each fault doing what it says.

Two plain sockets stand for the vehicle and the companion; every wait is bounded.
"""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from tests.support.fault_proxy import Fault, FaultProxy, message_name
from tests.support.ports import free_udp_port



class _Ends:
    """A vehicle socket sending to the proxy and a companion socket it forwards to."""

    def __init__(self, faults, seed=0):
        self.companion = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.companion.bind(("127.0.0.1", 0))
        self.companion.settimeout(1.0)
        self.listen = free_udp_port()
        self.proxy = FaultProxy(self.listen, self.companion.getsockname()[1], faults, seed=seed)
        self.vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vehicle.bind(("127.0.0.1", 0))
        self.vehicle.settimeout(1.0)
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)

    def packet(self, msg) -> bytes:
        return msg.pack(self.mav)

    def down(self, data: bytes) -> None:
        self.vehicle.sendto(data, ("127.0.0.1", self.listen))

    def received(self, sock, wait_s=0.3) -> list[bytes]:
        out, deadline = [], time.monotonic() + wait_s
        sock.settimeout(0.02)
        while time.monotonic() < deadline:
            try:
                out.append(sock.recvfrom(65535)[0])
            except socket.timeout:
                pass
        return out

    def close(self):
        self.proxy.stop()
        self.companion.close()
        self.vehicle.close()


@pytest.fixture
def ends(request):
    made = []

    def make(faults=(), seed=0):
        e = _Ends(list(faults), seed)
        e.proxy.start()
        made.append(e)
        return e

    yield make
    for e in made:
        e.close()


def _heartbeat(ends):
    return ends.packet(mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3))


def _ack(ends):
    return ends.packet(mavlink2.MAVLink_command_ack_message(176, 0))


def test_that_the_proxy_forwards_both_ways_and_answers_the_last_vehicle_sender(ends):
    e = ends()
    hb = _heartbeat(e)
    e.down(hb)
    got = e.received(e.companion)
    assert got == [hb] and message_name(hb) == "HEARTBEAT"
    addr = None
    e.companion.settimeout(1.0)
    # the companion answers to whoever sent to it: the proxy's own socket
    e.down(hb)
    data, addr = e.companion.recvfrom(65535)
    e.companion.sendto(_ack(e), addr)
    assert e.received(e.vehicle) == [_ack(e)]
    assert e.proxy.stats["down", "forwarded"] == 2 and e.proxy.stats["up", "forwarded"] == 1


def test_that_a_cut_drops_everything_in_its_window_only(ends):
    e = ends([Fault("cut", "down", start_s=0.3, end_s=0.6)])
    hb = _heartbeat(e)
    e.down(hb)
    assert len(e.received(e.companion, 0.2)) == 1
    time.sleep(max(0.0, 0.35 - e.proxy.elapsed_s()))
    for _ in range(3):
        e.down(hb)
    assert e.received(e.companion, 0.1) == []
    time.sleep(max(0.0, 0.65 - e.proxy.elapsed_s()))
    e.down(hb)
    assert len(e.received(e.companion, 0.2)) == 1
    assert e.proxy.stats["down", "cut"] == 3


def test_that_a_drop_rule_takes_only_the_named_messages(ends):
    e = ends([Fault("drop", "down", messages=frozenset({"HEARTBEAT"}))])
    e.down(_heartbeat(e))
    e.down(_ack(e))
    assert [message_name(d) for d in e.received(e.companion)] == ["COMMAND_ACK"]


def test_that_delay_duplicate_and_corrupt_do_what_they_say(ends):
    e = ends([Fault("delay", "down", delay_s=0.25)])
    sent = time.monotonic()
    e.down(_heartbeat(e))
    e.companion.settimeout(2.0)
    e.companion.recvfrom(65535)
    assert 0.22 <= time.monotonic() - sent < 0.6

    e2 = ends([Fault("duplicate", "down")])
    e2.down(_heartbeat(e2))
    assert len(e2.received(e2.companion)) == 2

    e3 = ends([Fault("corrupt", "down")], seed=3)
    e3.down(_heartbeat(e3))
    (bad,) = e3.received(e3.companion)
    assert bad != _heartbeat(e3) and len(bad) == len(_heartbeat(e3))
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    msgs = [m for m in parser.parse_buffer(bad) or [] if m.get_type() != "BAD_DATA"]
    assert msgs == []  # its CRC no longer matches


def test_that_reorder_swaps_a_datagram_with_the_next_one(ends):
    e = ends([Fault("reorder", "down", p=1.0)])
    hb, ack = _heartbeat(e), _ack(e)
    e.down(hb)
    time.sleep(0.05)
    e.down(ack)
    assert e.received(e.companion) == [ack, hb]


def test_that_bad_rules_are_refused():
    with pytest.raises(ValueError, match="action"):
        Fault("explode")
    with pytest.raises(ValueError, match="direction"):
        Fault("drop", "sideways")
    with pytest.raises(ValueError):
        Fault("drop", p=1.5)
