"""The shipped patrol (configs/patrol.toml): laps for ever through traffic that comes and goes.

Flown in mavsim lockstep for its 300 s (``companion demo patrol``), the flight ``make soak``
flies for 30 minutes in real time: laps in order until the run ends, every obstacle met
(within 4 m) and left (beyond the sensing range) again and again, no collision, the
promise kept, and memory that does not grow with the flight where the report keeps things.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.offline.harness import run_lockstep

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def patrol():
    return run_lockstep(ROOT / "configs" / "patrol.toml", seed=0, stop_after_goal_s=None, tlog_path=None)


def test_that_laps_are_flown_in_order_until_the_run_ends(patrol):
    s = patrol.companion.goal.summary()
    assert s["mission_jumps_taken"] >= 5                       # 7 laps in 300 s at seed 0
    reached = s["mission_items_reached"]
    assert reached == [1, 2, 3, 4] * (len(reached) // 4) + [1, 2, 3, 4][:len(reached) % 4]
    assert s["mission_items_reached_count"] == len(reached)
    assert patrol.companion.state.goal_reached_t_s is None     # a patrol has no last waypoint


def test_that_the_traffic_comes_and_goes_and_is_passed_with_the_promise_kept(patrol):
    assert not patrol.truth["collided"]
    closest = patrol.truth["min_distance_m"]
    assert len(closest) == 3 and all(1.0 < d < 4.0 for d in closest.values()), closest
    c_min = patrol.companion.planner_config.c_min
    assert patrol.summary()["min_realised_contour"] >= c_min
    # tracks inside the sensing range, replan by replan: none at times, and some at others, many times over
    constrained = np.array([len(r.planned_contour) for r in patrol.companion.records])
    arrivals = np.flatnonzero((constrained[1:] > 0) & (constrained[:-1] == 0))
    assert (constrained == 0).any() and arrivals.size >= 5, arrivals.size
