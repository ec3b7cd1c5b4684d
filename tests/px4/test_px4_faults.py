"""Faults real PX4 SITL produces, mid-encounter: ``make px4-fault-test`` (out of the default
suite and of ``.ci/run``: three flights, 2 min 18 s, and CI's 30 min are spent).

docs/FAULTS.md, the GPS and restart rows against the real autopilot (:mod:`tests.px4.faults`):
PX4's GPS off for 5 s from 3 s into OFFBOARD, and the companion SIGKILLed 3 s into OFFBOARD and
started again, without and with ``--reengage``. Each is judged on SIH's ground truth.
"""

from __future__ import annotations

import json

import pytest

from tests.px4.faults import fly_gps_outage, fly_killed_and_restarted, judge_gps_outage, judge_restart
from tests.px4.sitl import sitl_dir
from tests.support.flight_summary import record_flight

pytestmark = pytest.mark.px4_faults


@pytest.fixture(autouse=True)
def _need_sitl():
    if sitl_dir() is None:
        pytest.fail("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl (start-sih inside)")


def test_that_a_gps_outage_mid_encounter_widens_the_margins_and_the_reset_after_it_is_replanned(tmp_path, record_property):
    result = fly_gps_outage(tmp_path / "flight")
    record_flight(record_property, result, kept_at=tmp_path / "flight")
    print(json.dumps(result, indent=1, default=str))
    assert result.get("world_errors") == [], result
    assert judge_gps_outage(result) == [], json.dumps(result, default=str)


@pytest.mark.parametrize("reengage", [False, True], ids=["gives-up", "reengage"])
def test_that_a_companion_killed_mid_encounter_and_restarted_leaves_px4s_failsafe_alone_unless_told(tmp_path, reengage):
    result = fly_killed_and_restarted(tmp_path / "flight", reengage=reengage)
    print(json.dumps(result, indent=1, default=str))
    assert judge_restart(result) == [], json.dumps(result, default=str)
