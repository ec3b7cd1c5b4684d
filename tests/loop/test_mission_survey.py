"""The shipped survey (configs/mission_survey.toml): a mission in a geofence, round a building, through traffic.

Flown in mavsim lockstep as ``companion demo mission_survey`` flies it: all five waypoints in
order, the building and the fence kept in truth, and both crossings real encounters
(each obstacle within 4 m of the drone at its closest) flown with no collision.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.core.fence import Fence, PolygonZone
from companion.offline.harness import run_lockstep

ROOT = Path(__file__).resolve().parents[2]
FENCE = Fence(polygons=(PolygonZone(np.array([(-6.0, -8.0), (-6.0, 28.0), (46.0, 28.0), (46.0, -8.0)]), True),
                        PolygonZone(np.array([(18.0, 7.0), (18.0, 13.0), (24.0, 13.0), (24.0, 7.0)]), False)))


@pytest.fixture(scope="module")
def survey():
    return run_lockstep(ROOT / "configs" / "mission_survey.toml", seed=0)


def test_every_waypoint_is_reached_in_order_and_the_truth_ends_at_the_last(survey):
    s = survey.summary()
    assert s["mission_items_reached"] == [1, 2, 3, 4, 5]
    assert survey.truth["goal_reached"]                      # mavsim's goal: the plan's last waypoint
    assert survey.truth["time_to_goal_s"] < 90.0


def test_the_fence_holds_in_truth_and_the_traffic_is_met_and_passed(survey):
    radius = survey.companion.planner_config.drone_radius_m
    clearance = min(FENCE.clearance(p) for _, p, _ in survey.extra["replan_truth"])
    assert clearance >= radius, clearance
    assert not survey.truth["collided"]
    closest = survey.truth["min_distance_m"]
    assert len(closest) == 2 and all(1.0 < d < 4.0 for d in closest.values()), closest
    assert survey.summary()["min_realised_contour"] >= survey.companion.planner_config.c_min
