"""mavsim's serial link over its byte budget drops telemetry, never its HEARTBEAT or a COMMAND_ACK."""

from __future__ import annotations

import os
import pty
import select

from pymavlink.dialects.v20 import common as mavlink2

from mavsim.udp import SerialAddress, _essential, _SerialLink


def _packet(msg) -> bytes:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    return msg.pack(mav)


def test_essential_messages_are_told_from_their_ids():
    assert _essential(_packet(mavlink2.MAVLink_heartbeat_message(2, 12, 81, 393216, 4, 3)))
    assert _essential(_packet(mavlink2.MAVLink_command_ack_message(176, 0)))
    assert not _essential(_packet(mavlink2.MAVLink_local_position_ned_message(0, 1, 2, 3, 0, 0, 0)))
    assert not _essential(b"\x00garbage")


def test_over_budget_telemetry_is_dropped_and_counted_but_every_heartbeat_goes():
    master, slave = pty.openpty()
    try:
        stats: dict = {}
        link = _SerialLink(SerialAddress("api", os.ttyname(slave), baud=9600, budget_share=0.5), stats)
        pos = _packet(mavlink2.MAVLink_local_position_ned_message(0, 1, 2, 3, 0, 0, 0))
        hb = _packet(mavlink2.MAVLink_heartbeat_message(2, 12, 81, 393216, 4, 3))
        for _ in range(50):            # 50 x 36 B at once against 480 B/s with 48 B of burst
            link.send(pos)
        for _ in range(5):
            link.send(hb)
        got = b""
        while select.select([master], [], [], 0.2)[0]:      # a pty hands its bytes over in pieces
            got += os.read(master, 65536)
        assert stats["serial_budget_dropped"] >= 45
        assert got.count(hb) == 5
        os.close(link.fd)
    finally:
        os.close(master)
        os.close(slave)
