"""Real ArduCopter SITL in the loop: ``make ardupilot-test`` (deselected from the default suite).

Each test starts ArduCopter SITL (instance N >= 3 with free ports) in a fresh directory and flies
``companion fly --autopilot ardupilot --arm --takeoff-alt 5`` through the antipodal encounter
(``configs/antipodal_ardupilot.toml``), with the scenario's obstacles on the companion's obstacle link
and SIM_STATE truth on the ground link (:mod:`tests.ardupilot.ground`), then replays the recorded tlog.

Asserted for the encounter: engaged in GUIDED; the takeoff within 0.3 m of 5 m in the vehicle's own
estimate (the truth printed beside it); no collision in truth; the realised contour of touch never below
``c_min``; the goal within 25 s of ENGAGED; LOITER after the companion stops, the vehicle holding; the
replay exact. For a lost estimate (the vehicle's LOCAL_POSITION_NED dropped on the companion link) and a
stale plan (the planning process stopped), 5 s into the encounter: the vehicle brakes (within 2.5 m/s^2,
stopping in less distance than GUID_TIMEOUT's 3 s at the last velocity would take) and ends in LOITER,
holding; the replay exact. The same encounter with the obstacles as ADS-B traffic instead (ADSB_VEHICLE from each
obstacle's own system into SITL's ground link; ArduCopter, ``ADSB_TYPE`` 0, forwards it to the companion's
link, which has no obstacle link): the companion takes the three aircraft from its autopilot link and flies
the encounter to the same judgement. Everything started is stopped; about 1.5 minutes a flight.
"""

from __future__ import annotations

import json

import pytest

from tests.ardupilot.flight import TAKEOFF_ALT_M, fly_once, judge_brake, judge_encounter, judge_replay, judge_safety, \
    judge_takeoff
from tests.ardupilot.sitl import REPO, available

pytestmark = pytest.mark.ardupilot

SCENARIO = REPO / "configs" / "antipodal_ardupilot.toml"


def _need_sitl() -> None:
    if not available():
        pytest.fail("no ArduCopter SITL build: set ARDUPILOT_SITL_DIR or put one at ../shared/ardupilot-sitl "
                    "(start-arducopter and arducopter-sitl.tar.gz)")


def _show(result: dict) -> None:
    keys = ("instance", "companion_rc", "takeoff_said", "takeoff_height_estimate_m", "takeoff_height_truth_m",
            "min_true_clearance_m", "min_estimate_clearance_m", "time_to_goal_s", "modes_after_exit", "hold_drift_m", "hold_final_speed_mps",
            "trouble_speed_mps", "loiter_after_trouble_s", "stopped_after_trouble_s", "distance_to_stop_m",
            "distance_if_guid_timeout_m", "max_accel_after_trouble_mps2", "drift_in_loiter_m", "replay", "obstacles",
            "adsb_sent", "adsb_held", "obstacle_reports_accepted", "obstacle_reports_rejected")
    print(json.dumps({k: result.get(k) for k in keys} | {"companion": result.get("companion_report")}, indent=1, default=str))


def _record(record_property, result: dict) -> None:
    """The flight's figures for ``make flake-check``'s table: its smallest true clearance (m) and one line."""
    if result.get("min_true_clearance_m") is not None:
        record_property("true_clearance_m", float(result["min_true_clearance_m"]))
    report = result.get("companion_report") or {}
    record_property("flight", f"outcome {report.get('outcome')} | goal {result.get('time_to_goal_s')} s after ENGAGED | "
                              f"true clearance {result.get('min_true_clearance_m')} m | realised contour "
                              f"{report.get('min_realised_contour')} | kept in {result.get('work')}")


def test_that_the_companion_flies_arducopter_sitl_through_the_antipodal_encounter_hands_back_to_loiter_and_replays(
        tmp_path, record_property):
    _need_sitl()
    result = fly_once(tmp_path / "flight", SCENARIO)
    _show(result)
    _record(record_property, result)
    assert not result["companion_traceback"], (tmp_path / "flight" / "companion.stderr").read_text()[-3000:]
    assert result["engaged_after_start_s"] is not None and "GUIDED" in [m for _, m in result["modes"]]
    assert judge_takeoff(result) == [], result
    print(f"takeoff: {result['takeoff_height_estimate_m']} m in the estimate, {result['takeoff_height_truth_m']} m in "
          f"truth, asked {TAKEOFF_ALT_M} m")
    assert judge_safety(result) + judge_replay(result) + judge_encounter(result) == [], json.dumps(result, default=str)


@pytest.mark.ardupilot_adsb
def test_that_adsb_traffic_forwarded_by_arducopter_reaches_the_companion_and_the_encounter_is_flown(
        tmp_path, record_property):
    """In ``make ardupilot-test`` and CI since 6 December (20 of 20 in ``make flake-check`` with the
    planner's 0.5 m/s^2 bound; ``make ardupilot-adsb-test`` flies it alone). With 1.0 m/s^2, 1 of 4
    runs reached the goal 29.95 s after ENGAGED and 1 of 4 had the realised contour at 0.036."""
    _need_sitl()
    result = fly_once(tmp_path / "flight", SCENARIO, adsb=True)
    _show(result)
    _record(record_property, result)
    assert not result["companion_traceback"], (tmp_path / "flight" / "companion.stderr").read_text()[-3000:]
    accepted = result["obstacle_reports_accepted"]
    assert result["adsb_sent"] > 100 and len(accepted) == 3 and sum(accepted.values()) > 100, result
    assert judge_takeoff(result) == [], result
    assert judge_safety(result) + judge_replay(result) + judge_encounter(result) == [], json.dumps(result, default=str)


@pytest.mark.quarantine(reason="not yet through 20 rounds of make flake-check (the ArduCopter stage)")
@pytest.mark.parametrize("trouble", ["lost_estimate", "stale_plan"])
def test_that_on_trouble_the_companion_brakes_arducopter_and_hands_it_back_to_loiter(tmp_path, trouble):
    _need_sitl()
    result = fly_once(tmp_path / "flight", SCENARIO, trouble=trouble)
    _show(result)
    assert not result["companion_traceback"], (tmp_path / "flight" / "companion.stderr").read_text()[-3000:]
    report = result["companion_report"]
    assert report["outcome"] == "stopped" and report["exit_code"] == 3, report
    assert judge_brake(result) + judge_replay(result) == [], json.dumps(result, default=str)
