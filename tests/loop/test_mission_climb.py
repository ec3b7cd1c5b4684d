"""The take-off in a watched mission: predicted as the autopilot flies it, a climb where it is, then the legs.

A mission from the ground (take-off to 5 m, a waypoint 20 m north) watched in mavsim lockstep,
with a static obstacle where a straight line from the ground to the waypoint would pass
(4 m north, 1 m up) and 4 m below the path PX4 really flies (up, then north at 5 m).
"""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from companion.offline.harness import run_lockstep
from tests.loop.test_mission_jumps import _placed
from tests.loop.test_mission_watch import ROOT
from tests.support.missions import plan_dict, plan_text

WAYPOINT = (20.0, 0.0, -5.0)
UNDER_THE_DIAGONAL = [4.0, 0.0, -1.0]


def test_that_on_the_takeoff_the_path_climbs_where_the_vehicle_is_then_flies_the_legs():
    goal = _placed(plan_dict([WAYPOINT, (20.0, 10.0, -5.0)], final=None))
    seq, top = goal.takeoff
    assert seq == 0 and np.allclose(top, [0.0, 0.0, -5.0], atol=1e-6)
    route, speeds = goal.climb_route(0, np.array([1.0, 2.0, -0.5]), 1.5, 4.0)
    np.testing.assert_allclose(route, [[1.0, 2.0, -5.0], [0.0, 0.0, -5.0], WAYPOINT, [20.0, 10.0, -5.0]], atol=1e-6)
    np.testing.assert_allclose(speeds, [1.5, 4.0, 4.0, 4.0])
    assert goal.climb_route(1, np.zeros(3), 1.5, 4.0)[0].shape == (0, 3)       # past the take-off: the legs alone


def _watched_from_the_ground(tmp_path, climb_mps: float = 1.5):
    plan = tmp_path / "m.plan"
    plan.write_text(plan_text([WAYPOINT], final=None))
    data = tomllib.loads((ROOT / "configs" / "antipodal.toml").read_text())
    data["scenario"]["duration_s"] = 20.0
    data["vehicle"]["start_ned_m"] = [0.0, 0.0, 0.0]
    far = {k: v for k, v in data["world"]["obstacles"][0].items() if k not in ("waypoints_ned_m", "speed_mps")}
    data["world"]["obstacles"] = [{**far, "start_ned_m": [-40.0, -40.0, -5.0], "velocity_ned_mps": [0.0, 0.0, 0.0]}]
    data["map"] = {"static_obstacles": [{"center_ned_m": UNDER_THE_DIAGONAL, "radius_m": 0.5}]}
    data["mission"] = {"goal_tolerance_m": 0.5, "plan_file": str(plan), "autopilot_speed_mps": 3.0,
                       "autopilot_climb_mps": climb_mps}
    data["offboard"] = {"arm": True, "takeover": "watch"}
    return run_lockstep(data, seed=0, stop_after_goal_s=1.0)


def test_that_a_takeoff_from_the_ground_raises_no_conflict_with_what_is_under_the_diagonal(tmp_path):
    run = _watched_from_the_ground(tmp_path)
    report = run.companion.watch.summary()
    progress = run.companion.progress.summary()
    assert 0 in progress["autopilot_items_reached"] and 1 in progress["autopilot_items_reached"]
    assert report["watch_evaluations"] > 10
    assert report["watch_conflicts_count"] == 0, report["watch_conflicts"]
    assert not run.truth["collided"]


@pytest.mark.parametrize("climb_mps", [0.5])
def test_that_a_climb_slower_than_the_vehicles_still_predicts_no_diagonal(tmp_path, climb_mps):
    """The climb rate only sets when the legs are predicted to start; the path stays above the obstacle."""
    assert _watched_from_the_ground(tmp_path, climb_mps).companion.watch.summary()["watch_conflicts_count"] == 0
