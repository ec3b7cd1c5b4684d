"""Issue 14's real-time must-show with a crowd: ``companion demo SCENE --realtime --crowd 200``.

mavsim and ``companion fly`` run as two processes over loopback UDP while 200 extra
systems report ODOMETRY at 1 Hz from 6-10 m beside the route to the companion's obstacle
port. The setpoint stream must hold 20 Hz with no gap over 150 ms, OFFBOARD must hold
until the goal, nothing may collide, and the crowd must really be tracked. 60-100 s of wall
time per scene. Both are marked realtime (``make realtime-test``, run by CI); ``crowd`` selects
them alone (``make crowd-test``). The corridor's crowd stands beyond its walls and costs the
planner nothing; its ``c_max`` flight rides the ``c_min`` boundary behind the leader. It touched
the leader in one of three quiet runs (true clearance -0.08 m) until real-time plans started
from where the drone would be when they take over (``Companion.plan_lead_s``), and once more
in CI (-0.25 m) until the corridor's replans could brake harder than ``accel_max`` when no
plan within it keeps ``c_min`` (``[planner] accel_emergency_mps2``; docs/REALTIME.md has the runs).

The corridor flight was in quarantine after one run in about forty missed its goal and grazed
its leader in truth at ea80b3b (issue 46). Back in the gate since it passed 20 of 20 in
``make flake-check`` once a leader beside the way stopped holding the drone back near its goal
(docs/notes/ci.md): goal after 28.1-37.1 s of the 60, true clearance 0.168 m at least.

Run: ``make realtime-test`` or ``make crowd-test`` (both scenes)
"""

from __future__ import annotations

import json

import pytest

from companion.cli import main
from companion.commands._argtypes import scenario_file
from companion.loop.config import load_scenario
from tests.support.flight_summary import record_flight

#: How far in truth the drone may stay outside the goal's tolerance when its estimate is
#: inside, m: the drone filter's 3-D position error at the replans of the lockstep corridor
#: (seeds 0-3, 644 replans) was 0.031 m median, 0.059 m p95, 0.081 m at most.
GOAL_ESTIMATE_ALLOWANCE_M = 0.1


@pytest.mark.realtime
@pytest.mark.crowd
@pytest.mark.parametrize("scene", ["antipodal", "corridor"])
def test_that_the_stream_holds_20_hz_and_the_flight_is_safe_with_200_extra_obstacle_systems(
        scene, capsys, tmp_path, record_property):
    out = tmp_path / "flight"
    assert main(["demo", scene, "--realtime", "--crowd", "200", "--json", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    record_flight(record_property, summary, kept_at=out)
    events = [text for _, text in summary.get("events", [])]
    assert any("ENGAGED" in t for t in events), summary.get("fly_error") or events
    assert summary["crowd_reports_sent"] > 2000
    # the crowd was tracked: left out of replans by the track limit (antipodal), or set apart
    # beyond the walls (corridor: a track beyond a wall for the whole horizon needs no rows)
    set_aside = summary["tracks_unconstrained_max"] + summary["tracks_beyond_walls_max"]
    assert summary["tracks"] >= 200 and set_aside >= 150, (summary["tracks"], set_aside)
    # OFFBOARD held to the goal: the companion reached it (on its estimate) and handed back in
    # Hold, never lost it first. In truth the drone came within the goal's tolerance plus
    # what the estimate may be off by: the corridor's plans crawl into the goal (the paper's
    # terminal-only cost), and five runs came to 0.253-0.297 m of a 0.3 m tolerance in truth;
    # one run in sixteen stayed outside in truth while its estimate was inside (by how much was not kept).
    tolerance = load_scenario(scenario_file(scene)).mission.goal_tolerance_m
    assert summary["goal_reached_companion_t_s"] is not None and summary["collided"] is False, (
        summary.get("min_true_clearance_m"), events)
    assert summary["min_true_goal_distance_m"] <= tolerance + GOAL_ESTIMATE_ALLOWANCE_M, summary["min_true_goal_distance_m"]
    lost = [t for t in events if t.startswith(("PILOT_TOOK_OVER", "LINK_LOST", "GAVE_UP"))]
    assert not lost, lost
    assert summary["setpoint_rate_hz"] >= 19.5, summary["setpoint_rate_hz"]
    # on failure, where the largest gap's time went (CPU, run-queue wait, host steal, longest loop step)
    assert summary["setpoint_gaps_over_150ms"] == 0, {k: summary.get(k) for k in (
        "setpoint_gap_max_ms", "setpoint_gap_max_detail", "tick_max_ms", "gc_pause_max_ms", "planner_process")}
