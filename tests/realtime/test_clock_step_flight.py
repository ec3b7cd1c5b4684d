"""``companion fly`` rides through steps of the system clock, against mavsim over loopback.

A companion computer without a real-time clock (a Raspberry Pi) has its clock stepped when a
time sync first arrives, often minutes after boot: by seconds, hours or years, forward or
back. Here fly's process sees its clock (``time.time``) stepped 30 s forward 6 s after its
start and 60 s back 4 s later, in the middle of the antipodal encounter
(``tests/support/stepped_clock.py``; the machine's clock and mavsim's are not touched). The
flight must go on as if nothing happened: no setpoint gap, no failsafe, the goal, and a
tlog whose stamps never go back and replay exactly. Before the stream's clock advanced
with the monotonic clock (``companion.realtime.clock``), this test failed: the step forward
made the autopilot look silent for 30.5 s (LINK_LOST, no more setpoints) and mavsim's
offboard-loss failsafe took the vehicle, exit 7.
About 20 s of wall time: marked realtime.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from companion.loop.config import load_scenario
from companion.offline.replay import replay
from tests.support.fly_udp import fly_beside_mavsim, streamed_setpoints
from tests.support.ports import free_udp_port

pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
STEPS = ("6:+30", "10:-60")   # seconds after fly's start : seconds added to its clock


def test_that_fly_rides_through_steps_of_the_system_clock(tmp_path):
    launcher = ("-m", "tests.support.stepped_clock", *(a for s in STEPS for a in ("--step", s)), "--")
    run = fly_beside_mavsim(SCENARIO, tmp_path, autopilot_port=free_udp_port(), duration_s=60, launcher=launcher)
    assert "Traceback" not in run.err, run.err[-3000:]
    assert run.returncode == 0, run.err[-3000:]
    report = json.loads(run.out)
    print(json.dumps({k: report.get(k) for k in ("outcome", "setpoint_rate_hz", "setpoint_gap_max_ms", "cpu_share_in_flight", "cpu_share", "max_rss_mb", "planner_process", "stream_fifo_priority")}))
    assert report["outcome"] == "goal reached"
    assert report["setpoint_gap_max_ms"] < 150.0 and report["setpoint_gaps_over_150ms"] == 0
    assert report["stale_events"] == 0 and report["old_plan_events"] == 0   # nothing looked old after the forward step
    # mavsim (its own, unstepped clock): the vehicle stayed in OFFBOARD until the hand-back to Hold
    truth = run.sim.summary()
    modes = [m["mode"] for m in truth["mode_changes"]]
    assert modes[-2:] == ["OFFBOARD", "AUTO.LOITER"], modes
    assert min(truth["min_clearance_m"].values()) > 0.0
    # the tlog's stamps never went back, and the setpoints in it came every tick
    t_s, _ = streamed_setpoints(run.tlog)
    gaps = np.diff(t_s)
    assert gaps.min() >= 0.0 and gaps.max() < 0.15, (gaps.min(), gaps.max())
    assert t_s[-1] - t_s[0] < 40.0                       # no 30 s jump inside the log either
    offboard = dataclasses.replace(load_scenario(SCENARIO).offboard, hold_after_goal_s=1.0)  # fly_beside_mavsim's flags
    res = replay(run.tlog, SCENARIO, offboard=offboard)
    assert res.commands_compared == res.commands_recorded > 100
    assert res.max_abs_diff_mps == 0.0 and res.unmatched_commands == 0
