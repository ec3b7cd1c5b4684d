"""DO_CHANGE_SPEED in a mission: the speed a watching or guarding companion predicts the autopilot's legs at.

The legs' speeds are read off a placed mission (pure); one lockstep flight shows the mission's
own DO_CHANGE_SPEED is what the watch predicts with, whatever ``[mission] autopilot_speed_mps``
says.
"""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.offline.harness import run_lockstep
from tests.loop.test_mission_jumps import _placed
from tests.loop.test_mission_watch import _scenario
from tests.support.missions import crossing_plan_text, plan_dict

LEGS = [(8.0, 0.0, -5.0), (8.0, 8.0, -5.0), (0.0, 8.0, -5.0), (0.0, 0.0, -5.0), (4.0, 4.0, -5.0)]


def _speed(kind: float, mps: float) -> dict:
    return {"type": "SimpleItem", "command": mavlink2.MAV_CMD_DO_CHANGE_SPEED, "frame": 2, "autoContinue": True,
            "params": [kind, mps, -1, 0, 0, 0, 0]}


def test_that_each_leg_gets_the_speed_set_before_its_waypoint():
    """Item order: takeoff, speed 1.5, WP, speed -1 (no change), WP, speed -2 (the default), WP,
    climb speed 0.5 (not horizontal), WP, ground speed 4, WP."""
    plan = plan_dict(LEGS, final=None)
    items = plan["mission"]["items"]
    changes = {1: _speed(1, 1.5), 3: _speed(0, -1), 5: _speed(0, -2), 7: _speed(2, 0.5), 9: _speed(1, 4.0)}
    for at in sorted(changes):
        items.insert(at, changes[at])
    for k, item in enumerate(items):
        item["doJumpId"] = k + 1
    goal = _placed(plan)
    assert [w.seq for w in goal.waypoints] == [2, 4, 6, 8, 10]
    np.testing.assert_allclose(goal.route_speeds(0, 5.0), [1.5, 1.5, 5.0, 5.0, 4.0])
    np.testing.assert_allclose(goal.route_speeds(6, 3.0), [3.0, 3.0, 4.0])      # from the third waypoint on
    assert goal.route_speeds(11, 5.0).shape == (0,)                              # past the last waypoint
    # the companion's own legs keep its planner's speed: for its flight the items are skipped
    assert [seq for seq, command in goal.skipped if command == mavlink2.MAV_CMD_DO_CHANGE_SPEED] == [1, 3, 5, 7, 9]


def test_that_a_mission_without_a_speed_is_predicted_at_the_scenarios():
    goal = _placed(plan_dict(LEGS[:2], final=None))
    np.testing.assert_allclose(goal.route_speeds(0, 2.5), [2.5, 2.5])


def _watched(tmp_path, autopilot_speed_mps: float | None):
    plan = tmp_path / "m.plan"
    plan.write_text(crossing_plan_text([(24.0, 0.0, -5.0)], speed_mps=1.5))
    data = _scenario(plan)
    if autopilot_speed_mps is None:
        del data["mission"]["autopilot_speed_mps"]
    else:
        data["mission"]["autopilot_speed_mps"] = autopilot_speed_mps
    return run_lockstep(data, seed=0, stop_after_goal_s=None, tlog_path=None).companion.watch.summary()


def test_that_the_watch_predicts_the_missions_own_speed_not_the_scenarios_default(tmp_path):
    """The mission through the antipodal encounter, flown by the autopilot at 1.5 m/s
    (its DO_CHANGE_SPEED), watched with the scenario's speed right (1.5) and left at the
    default (5 m/s, three times too fast): the same conflicts, at the same times and leads."""
    right = _watched(tmp_path, 1.5)
    default = _watched(tmp_path, None)
    assert right["watch_conflicts_count"] >= 1
    assert default["watch_conflicts"] == right["watch_conflicts"]
    assert default["watch_min_predicted_contour"] == pytest.approx(right["watch_min_predicted_contour"])
