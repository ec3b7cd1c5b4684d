"""``takeover = "watch"`` in mavsim lockstep: the autopilot flies its own mission, the companion
starts it, follows it, warns of the conflicts on its path ahead of time, and never commands."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import ConfigError
from companion.loop.app import Companion
from companion.loop.config import scenario_from_dict
from companion.loop.mission_watch import MissionProgress
from companion.mavlink import messages
from companion.mavlink.offboard import Phase
from companion.offline.harness import run_lockstep
from tests.support.missions import crossing_plan_text

ROOT = Path(__file__).resolve().parents[2]
#: the missions are flown at 1.5 m/s (DO_CHANGE_SPEED): one through the circle's centre meets the obstacles there


def _scenario(plan_path: Path, duration_s: float = 30.0, takeover: str = "watch") -> dict:
    """The antipodal encounter (its obstacles) with the mission of ``plan_path`` flown by the autopilot."""
    data = tomllib.loads((ROOT / "configs" / "antipodal.toml").read_text())
    data["scenario"]["duration_s"] = duration_s
    data["mission"] = {"goal_tolerance_m": 0.3, "plan_file": str(plan_path), "autopilot_speed_mps": 1.5}
    data["offboard"] = {"arm": True, "takeover": takeover}
    return data


def fly_mission(tmp_path: Path, waypoints, duration_s: float = 30.0, final: int | None = 20, takeover: str = "watch"):
    """Fly the crossing mission through ``waypoints`` in lockstep; the run and the messages sent to the vehicle."""
    plan = tmp_path / "m.plan"
    plan.write_text(crossing_plan_text(waypoints, final=final))
    sent = []
    run = run_lockstep(_scenario(plan, duration_s, takeover), seed=0, stop_after_goal_s=None, tlog_path=None,
                       drop=lambda t, d, p: sent.append((t, d, p)) and False)
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    to_vehicle = [(t, m) for t, d, p in sent if d == "to_vehicle" for m in (mav.parse_buffer(p) or [])]
    return run, to_vehicle


@pytest.fixture(scope="module")
def through(tmp_path_factory):
    """The mission straight through the antipodal encounter (24 m north of the start, 5 m up)."""
    return fly_mission(tmp_path_factory.mktemp("w"), [(24.0, 0.0, -5.0)])


def test_that_the_companion_starts_the_mission_and_never_commands(through):
    run, to_vehicle = through
    types = [m.get_type() for _, m in to_vehicle]
    assert "SET_POSITION_TARGET_LOCAL_NED" not in types
    commands = [m.command for _, m in to_vehicle if m.get_type() == "COMMAND_LONG"]
    assert commands.count(mavlink2.MAV_CMD_MISSION_START) == 1   # the vehicle hovers armed: started, not armed
    assert mavlink2.MAV_CMD_DO_SET_MODE not in commands and mavlink2.MAV_CMD_NAV_TAKEOFF not in commands
    texts = [text for _, text in run.companion.state.events]
    assert any("START_MISSION" in t for t in texts) and any("WATCHING: mission started" in t for t in texts)


def test_that_a_conflict_is_announced_seconds_before_the_encounter(through):
    run, _ = through
    c = run.companion
    report = c.watch.summary()
    assert report["watch_evaluations"] > 30
    assert report["watch_conflicts_count"] >= 1
    first = report["watch_conflicts"][0]
    assert first["min_contour"] < c.planner_config.c_min
    # the truth: the closest approach of the drone to any obstacle comes after the warning
    truth = run.extra["replan_truth"]
    assert not truth   # nothing was planned
    texts = [(t, text) for t, text in c.state.events if text.startswith("companion: conflict in")]
    assert texts and texts[0][0] == pytest.approx(first["start_s"])
    assert first["lead_s"] >= 2.0
    # flying straight through at 1.5 m/s, the obstacles arrive at the centre about 8 s in
    assert first["start_s"] < 8.0


def test_that_the_autopilots_progress_is_followed_once_per_item(through):
    run, _ = through
    progress = run.companion.progress.summary()
    reached = progress["autopilot_items_reached"]
    assert reached == sorted(set(reached)) and 2 in reached   # the waypoint (item 2), each item once
    assert progress["autopilot_items_reached_count"] == len(reached)


def test_that_repeated_reached_items_count_once_and_a_lap_counts_again():
    """PX4 repeats MISSION_ITEM_REACHED with its next ten MISSION_CURRENT: two items reached in one
    step interleave their repeats; a DO_JUMP back flies (and reaches) the items again."""
    p = MissionProgress()
    key = (1, 1)
    news = []
    for t, kind, seq in [(0.0, "cur", 2), (1.0, "hit", 2), (1.0, "cur", 3), (1.0, "hit", 3), (2.0, "hit", 2),
                         (2.0, "hit", 3), (3.0, "cur", 4), (3.5, "hit", 4), (4.0, "cur", 2),   # a jump back to 2
                         (4.0, "hit", 4), (5.0, "hit", 4), (6.0, "hit", 2), (6.0, "cur", 3)]:
        if kind == "cur":
            p.on_current(t, messages.MissionCurrent(key, seq, 5, 3))
        elif p.on_reached(t, seq):
            news.append(seq)
    assert news == [2, 3, 4, 2]
    assert p.summary()["autopilot_items_reached"] == [2, 3, 4, 2] and p.current_seq == 3


def test_that_a_clear_mission_raises_no_conflict(tmp_path):
    """The same mission 20 m west of the encounter: judged all along, never in conflict."""
    run, to_vehicle = fly_mission(tmp_path, [(0.0, -20.0, -5.0)], duration_s=20.0)
    report = run.companion.watch.summary()
    assert report["watch_evaluations"] > 30 and report["watch_conflicts_count"] == 0
    assert "SET_POSITION_TARGET_LOCAL_NED" not in [m.get_type() for _, m in to_vehicle]


def test_that_watch_without_a_mission_is_refused():
    data = tomllib.loads((ROOT / "configs" / "antipodal.toml").read_text())
    data["offboard"] = {"takeover": "watch"}
    with pytest.raises(ConfigError, match="takeover \"watch\" needs a mission"):
        Companion(scenario_from_dict(data, "<test>"))


def test_that_the_watch_ends_when_the_vehicle_lands_after_its_mission(tmp_path):
    run, _ = fly_mission(tmp_path, [(6.0, -8.0, -5.0)], duration_s=40.0, final=21)
    assert run.companion.sequencer.phase is Phase.WATCH_ENDED
    assert np.isfinite(run.truth["sim_time_s"])
