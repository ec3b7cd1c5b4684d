"""``companion fly`` announces packets rejected for their MAVLink 2 signature (issue 14 item 5).

The link counts them; the stream hands the count to the companion before every tick, which
says so in a STATUSTEXT at most every 5 s. Over loopback UDP with a signed link, a stranger's
unsigned packets must be counted, announced and rate limited. The count goes into the tlog as
a mark (tests/realtime/test_tlog_plan_marks.py); a replay of a log from before that mark reads it
back from the announcement.
"""

from __future__ import annotations

import socket

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.app import Companion
from companion.loop.supervisor import SIGNATURE_TEXT
from companion.loop.config import load_scenario
from companion.realtime.stream import run_realtime
from companion.mavlink.link import open_link
from companion.offline.replay_stand_ins import signatures_rejected
from tests.support.ports import free_udp_port

SCENARIO = "tests/data/short_hop.toml"
KEY = bytes(range(32))


def test_that_rejections_are_announced_with_their_count_at_most_every_five_seconds():
    companion = Companion(load_scenario(SCENARIO))
    texts = []
    for i in range(200):  # 10 s at 20 Hz, one more rejection every tick
        t = 0.05 * i
        companion.on_signatures_rejected(i + 1)
        texts += [(t, m.text) for m in companion.tick(t) if m.get_type() == "STATUSTEXT" and m.text.startswith(SIGNATURE_TEXT)]
    assert [t for t, _ in texts] == [0.0, 5.0]
    assert texts[0][1] == f"{SIGNATURE_TEXT}1 rejected)" and texts[1][1] == f"{SIGNATURE_TEXT}101 rejected)"
    assert signatures_rejected([mavlink2.MAVLink_statustext_message(4, texts[1][1].encode())]) == 101


def test_that_a_signed_link_counts_and_announces_unsigned_packets_over_udp():
    port = free_udp_port()
    companion = Companion(load_scenario(SCENARIO))
    link = open_link(f"udpin:127.0.0.1:{port}", signing_key=KEY)
    stranger = mavlink2.MAVLink(None, 42, 1)  # unsigned
    ticks = [0]

    def stop(_c, _t) -> bool:  # a stranger's unsigned HEARTBEAT before each of the first 30 ticks
        ticks[0] += 1
        if ticks[0] <= 30:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(bytes(mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3).pack(stranger)), ("127.0.0.1", port))
        return False

    try:
        run_realtime(companion, link, duration_s=2.0, stop=stop)
    finally:
        link.close()
    assert link.stats.signature_rejected >= 20 and companion.autopilot is None  # nothing unsigned was taken
    announced = [text for _, text in companion.state.events if text.startswith(SIGNATURE_TEXT)]
    assert len(announced) == 1, announced  # the first at once, the next not before 5 s
    assert announced[0].startswith(f"{SIGNATURE_TEXT}") and int(announced[0][len(SIGNATURE_TEXT):].split()[0]) >= 1
