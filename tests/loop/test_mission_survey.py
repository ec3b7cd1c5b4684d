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


@pytest.fixture(scope="module")
def guarded_survey():
    """The same survey flown by mavsim's autopilot itself, guarded (``demo mission_survey --takeover guard``)."""
    import dataclasses

    from companion.loop.config import load_scenario

    scenario = ROOT / "configs" / "mission_survey.toml"
    offboard = dataclasses.replace(load_scenario(scenario).offboard, takeover="guard", arm=True)
    return run_lockstep(scenario, seed=0, offboard=offboard, truth_every_tick=True)


def test_a_guarded_survey_is_taken_over_for_the_building_only(guarded_survey):
    """The autopilot flies the legs at 3 m/s ([sim] MPC_XY_CRUISE): the traffic, timed for the
    companion's own flight, passes clear of it, so the one takeover is for the building on the
    third leg (seen 8 s ahead), given back once round it."""
    c = guarded_survey.companion
    assert [w["track"] for w in c.watch.summary()["watch_conflicts"]] == ["fence"]
    (taken,) = c.guard.summary()["takeovers"]
    assert taken["item"] == 2 and taken["end_s"] is not None
    assert not guarded_survey.truth["collided"]
    assert c.state.min_realised_contour >= c.planner_config.c_min


def test_a_guarded_survey_keeps_the_fence_in_truth_and_flies_every_item(guarded_survey):
    radius = guarded_survey.companion.planner_config.drone_radius_m
    clearance = min(FENCE.clearance(p) for _, p in guarded_survey.extra["truth_trace"])
    assert clearance >= radius, clearance
    by = guarded_survey.companion.guard.items_reached()
    assert [seq for _, seq, _ in by if seq >= 1] == [1, 2, 3, 4, 5]    # the five waypoints in order, by either
    assert {who for _, _, who in by} == {"autopilot", "companion"}
