"""Real time over loopback UDP: mavsim and ``companion fly`` as two processes, like PX4 SITL (issue 6).

``companion demo --realtime`` picks free loopback ports, starts ``mavsim`` (sending to the
companion's port from its own, as PX4 SITL does) and ``companion fly --connect udpin:...``,
and stops both; every wait is bounded. About 20 s of wall time.
"""

from __future__ import annotations

import json

from companion.cli import main


def test_that_offboard_is_engaged_and_the_goal_reached_over_udp_in_real_time(capsys):
    assert main(["demo", "tests/data/short_hop.toml", "--realtime", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["mode"] == "realtime"
    assert any("ENGAGED" in text for _, text in summary["events"]), summary.get("events")  # confirmed from the HEARTBEAT
    assert summary["phase"] == "HELD", summary.get("events")   # handed back to Hold before the stream stopped
    assert summary["goal_reached"] is True, summary                  # mavsim's ground truth
    assert summary["collided"] is False
    assert summary["replans"] > 10
