"""The real-time loop's obstacle queue, when it backs up, keeps only each source's newest report.

Measured on PX4 SITL on a loaded 2-core machine: the loop handled five obstacle messages per
loop while thirty arrived per second, and the tracks fell three seconds behind the obstacles.
"""

from __future__ import annotations

from collections import deque

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.realtime import _keep_newest_per_source
from companion.mavlink.link import Received


def _report(sysid: int, t_s: float, link: str = "obstacles1", kind: str = "pos") -> Received:
    mav = mavlink2.MAVLink(None, sysid, 1)
    msg = (mavlink2.MAVLink_local_position_ned_message(int(t_s * 1000), t_s, 0, 0, 0, 0, 0) if kind == "pos"
           else mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
    raw = bytes(msg.pack(mav))
    return Received(t_s, mav.parse_buffer(raw)[0], raw, link)


def test_that_a_backed_up_queue_keeps_the_newest_report_of_each_kind_from_each_source_in_order():
    queue = deque([_report(101, 0.0), _report(102, 0.0), _report(101, 0.1), _report(101, 0.1, link="obstacles2"),
                   _report(102, 0.1, kind="hb"), _report(102, 0.2), _report(101, 0.3)])
    dropped = _keep_newest_per_source(queue)
    assert dropped == 3
    assert [(rx.link, rx.msg.get_srcSystem(), rx.msg.get_type(), rx.t_s) for rx in queue] == [
        ("obstacles2", 101, "LOCAL_POSITION_NED", 0.1), ("obstacles1", 102, "HEARTBEAT", 0.1),
        ("obstacles1", 102, "LOCAL_POSITION_NED", 0.2), ("obstacles1", 101, "LOCAL_POSITION_NED", 0.3)]


def test_that_a_queue_without_superseded_reports_is_left_as_it_is():
    queue = deque([_report(101, 0.0), _report(102, 0.0), _report(103, 0.0)])
    before = list(queue)
    assert _keep_newest_per_source(queue) == 0 and list(queue) == before
