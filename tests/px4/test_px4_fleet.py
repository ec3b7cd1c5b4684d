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


def test_three_px4_instances_swap_with_an_adsb_aircraft_without_collision_and_replay_exactly(tmp_path):
    if sitl_dir() is None:
        pytest.fail("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl (start-sih inside)")
    result = fly_fleet(tmp_path, 3)
    print(json.dumps(result, indent=1, default=str))
    assert all(result["px4_alive"]), result["px4_alive"]
    assert all(r["intents_used"] and r["adsb_sent"] > 100 for r in result["per_drone"]), result["per_drone"]
    assert judge(result) == []
