"""Three PX4 SITL instances swap places with one crossing ADS-B aircraft (issue 37's PX4 fleet).

:mod:`tests.px4.fleet` starts SIH instances 0..2 on a 12 m circle (each its own EKF origin),
one ``companion fly --fleet`` each, and a traffic player per vehicle that plays the aircraft
as ADS-B into its PX4 and records SIH's truth in the fleet's frame. Asserted (its
:func:`~tests.px4.fleet.judge`): no collision in truth between any pair or with the aircraft,
every realised contour (to the aircraft and to the peers) at least ``c_min``, every goal
within 35 s of the drone's OFFBOARD, every vehicle in Hold after its companion without a
failsafe, and every tlog replayed exactly. About 70 s; ``make px4-fleet-test`` alone, and in
``make px4-test`` (``.ci/run``).
"""

from __future__ import annotations

import json

import pytest

from tests.px4.fleet import fly_fleet, judge
from tests.px4.sitl import sitl_dir

# In .ci/run (through `make px4-test`) since it passed 20 of 20 in `make flake-check` (docs/TESTING.md).
pytestmark = [pytest.mark.px4, pytest.mark.px4_fleet]


def _record(record_property, result: dict) -> None:
    """The flight's smallest true clearance (m, between drones or to the aircraft) and one line
    for ``make flake-check`` (JUnit XML properties)."""
    drones = result.get("per_drone", [])
    clearances = [result.get("min_pair_clearance_m")] + [r.get("min_true_clearance_to_aircraft_m") for r in drones]
    clearances = [c for c in clearances if isinstance(c, (int, float))]
    if clearances:
        record_property("true_clearance_m", min(clearances))
    contours = [r.get(k) for r in drones for k in ("min_realised_contour", "min_peer_realised_contour")]
    contours = [c for c in contours if isinstance(c, (int, float))]
    goals = [r.get("time_to_goal_s") for r in drones]
    record_property("min_realised_contour", min(contours) if contours else None)
    record_property("flight", f"pairs {result.get('min_pair_clearance_m')} m, aircraft "
                              f"{[r.get('min_true_clearance_to_aircraft_m') for r in drones]} m, realised contour "
                              f"{min(contours) if contours else None}, goals {goals} s")


def test_three_px4_instances_swap_with_an_adsb_aircraft_without_collision_and_replay_exactly(tmp_path, record_property):
    if sitl_dir() is None:
        pytest.fail("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl (start-sih inside)")
    result = fly_fleet(tmp_path, 3)
    print(json.dumps(result, indent=1, default=str))
    _record(record_property, result)
    assert all(result["px4_alive"]), result["px4_alive"]
    assert all(r["intents_used"] and r["adsb_sent"] > 100 for r in result["per_drone"]), result["per_drone"]
    assert judge(result) == []
