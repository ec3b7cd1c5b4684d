"""A fleet companion's tlog: a peer that sends as our own (system, component) is still inbound.

Every ``companion fly`` sends to its autopilot as (1, 191), and announces on the fleet link
as its vehicle's system id with component 191. So drone 2's tlog holds its own setpoints
from (1, 191) and drone 1's announcements, heard on the fleet link, also from (1, 191).
The recording marks every message heard on a fleet or obstacle link (``rx_link``), and the
replay must take that mark over the source key: before it did, drone 1's announcements
were counted as drone 2's own packets, never reached the replayed companion, and a
real-time two-drone flight did not replay (0.389 m/s, docs/notes/fleet.md).
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.intake.traffic_config import FLEET_LINK
from companion.mavlink import fleet
from companion.mavlink.tlog import TlogWriter, read_tlog
from companion.offline.replay import _parse, _Rec, _TickMark
from companion.realtime.tlog_marks import TlogMarks

T0 = 1_780_000_000.0  # a real-time log: Unix time


def _pack(system: int, component: int, msg) -> bytes:
    return bytes(msg.pack(mavlink2.MAVLink(None, system, component)))


def _drone2_log(path):
    """Drone 2's companion (vehicle link as (1, 191)) hearing drone 1's companion (fleet link as (1, 191))."""
    tlog = TlogWriter(path)
    marks = TlogMarks(tlog, (1, 191))
    tlog.write(T0, _pack(2, 1, mavlink2.MAVLink_heartbeat_message(2, 12, 157, 0, 4, 3)))  # vehicle 2's autopilot
    marks.tick(T0 + 0.01)
    tlog.write(T0 + 0.01, _pack(1, 191, mavlink2.MAVLink_set_position_target_local_ned_message(
        10, 2, 1, 1, 0b110111000111, 0, 0, 0, 1.0, 0.0, 0.0, 0, 0, 0, 0, 0)))
    marks.received(T0 + 0.02, FLEET_LINK)
    tlog.write(T0 + 0.02, _pack(1, 191, fleet.encode_state(
        5_000_000, np.array([3.0, 0.0, -5.0]), np.array([-1.0, 0.0, 0.0]), 0.01 * np.eye(3), 0.01 * np.eye(3))))
    tlog.write(T0 + 0.03, _pack(2, 1, mavlink2.MAVLink_heartbeat_message(2, 12, 157, 0, 4, 3)))
    tlog.close()


def test_that_a_peer_heard_on_the_fleet_link_as_our_own_key_is_replayed_as_inbound(tmp_path):
    path = tmp_path / "drone2.tlog"
    _drone2_log(path)
    records = list(read_tlog(path))
    parsed = _parse(path, records, 0, (1, 191))
    kinds = [(out, rec.msg.get_type() if isinstance(rec, _Rec) else "tick", getattr(rec, "link", None))
             for out, rec in parsed.stream]
    assert kinds == [
        (False, "HEARTBEAT", None),
        (True, "tick", None),
        (True, "SET_POSITION_TARGET_LOCAL_NED", None),
        (False, "ODOMETRY", FLEET_LINK),   # the peer's announcement, on the link it came on
        (False, "HEARTBEAT", None),
    ]
    assert parsed.inbound == 3 and parsed.outbound == 1
    assert isinstance(parsed.stream[1][1], _TickMark)
