"""``companion fly`` through MAVProxy, the router many companion computers run: mavsim -> MAVProxy -> fly.

MAVProxy (``tests/support/mavproxy.py``) holds the autopilot's link and hands it to fly on a
UDP output, as on a vehicle where it owns TELEM2 and feeds the companion, the ground station
and a logger. Nothing in fly knows: it connects to MAVProxy's output as to any UDP link.
The antipodal encounter must fly as it does directly: the goal, no failsafe, no setpoint
gap, Hold at the end, a tlog that replays exactly.
About 20 s: `make mavproxy-test` (it installs MAVProxy into out/mavproxy-venv first).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from companion.loop.config import load_scenario
from companion.offline.replay import replay
from tests.support.fly_udp import fly_beside_mavsim
from tests.support.mavproxy import MavProxy, find_mavproxy
from tests.support.ports import free_udp_port

pytestmark = [pytest.mark.mavproxy]

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"


def test_that_fly_through_mavproxy_flies_the_encounter_as_directly(tmp_path):
    executable = find_mavproxy()
    assert executable is not None, "no mavproxy.py: set MAVPROXY, or run `make mavproxy-test`"
    master, out = free_udp_port(), free_udp_port()
    router = MavProxy(executable, master, out, tmp_path / "mavproxy")
    router.start()
    try:
        run = fly_beside_mavsim(SCENARIO, tmp_path, autopilot_port=master, fly_port=out, duration_s=60)
    finally:
        router.stop()
    assert "Traceback" not in run.err, run.err[-3000:]
    assert run.returncode == 0, run.err[-3000:] + router.output()[-2000:]
    report = json.loads(run.out)
    print(json.dumps({k: report.get(k) for k in ("outcome", "setpoint_rate_hz", "setpoint_gap_max_ms", "cpu_share_in_flight", "cpu_share", "max_rss_mb", "planner_process", "stream_fifo_priority")}))
    assert report["outcome"] == "goal reached" and report["phase"] == "HELD"
    assert report["setpoint_gap_max_ms"] < 150.0
    truth = run.sim.summary()
    modes = [m["mode"] for m in truth["mode_changes"]]
    assert modes[-2:] == ["OFFBOARD", "AUTO.LOITER"], modes             # no failsafe on the way
    assert not truth["collided"] and min(truth["min_clearance_m"].values()) > 0.0
    # the link went through MAVProxy (mavsim sends only to its master port; fly listens only on its output)
    assert "Detected vehicle 1:1" in router.output(), router.output()[-2000:]
    offboard = dataclasses.replace(load_scenario(SCENARIO).offboard, hold_after_goal_s=1.0)  # fly_beside_mavsim's flags
    res = replay(run.tlog, SCENARIO, offboard=offboard)
    assert res.commands_compared == res.commands_recorded > 100
    assert res.max_abs_diff_mps == 0.0 and res.unmatched_commands == 0
