"""PX4 SITL flies the survey an operator uploaded, guarded by the companion (``--takeover guard``).

The flight of :mod:`tests.px4.survey_flight`: the survey's mission (with a landing) and its fence
(an inclusion rectangle and a building on the third leg) uploaded on PX4's ground link as
QGroundControl does; traffic across the first leg (the companion's obstacle link) and the last
(ADS-B through PX4); ``companion fly --mission vehicle --fence vehicle --takeover guard --arm``.
About 2.5 minutes.

Asserted, on SIH's truth and PX4's own words: no collision; the drone's body never outside the
fence; the realised contour never below ``c_min`` while taken over; at least one takeover,
each given back, the building's among them (PX4 alone flies into it: its fence failsafe fired
at the building in the baseline); every item reached in order, "Mission finished, landed",
disarmed; no failsafe; the companion exits 0.
"""

from __future__ import annotations

import pytest

from tests.px4.sitl import sitl_dir
from tests.px4.survey_flight import fly_survey

pytestmark = pytest.mark.px4   # in .ci/run: 20 of 20 in make flake-check on 7 December (docs/TESTING.md)

C_MIN = 0.9


def test_that_a_guarded_survey_keeps_clear_of_traffic_and_building_and_px4_finishes_it(tmp_path):
    if sitl_dir() is None:
        pytest.fail("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl (start-sih inside)")
    r = fly_survey(tmp_path, seed=0, takeover="guard")
    c, work = r["companion"], r["work"]
    print({k: r[k] for k in ("companion_rc", "min_true_clearance_m", "min_true_fence_clearance_m", "flight_s",
                             "failsafe_texts", "mode_switch_after_s")}, c["takeovers"])
    assert r["upload"]["mission_ack"] == 0 and r["upload"]["fence_ack"] == 0
    assert r["companion_rc"] == 0 and not r["companion_traceback"], work
    assert r["min_true_clearance_m"] > 0.0
    assert r["min_true_fence_clearance_m"] > 0.0
    assert c["min_realised_contour"] >= C_MIN
    takeovers = c["takeovers"]
    assert takeovers and all(k["end_s"] is not None and k["offboard_s"] is not None for k in takeovers), work
    conflicts = [w["track"] for w in c["watch_conflicts"]]
    assert "fence" in conflicts
    reached = [row["item"] for row in c["mission_items_reached_by"]]
    assert reached == list(range(r["upload"]["mission_items"])), reached
    texts = [text for _, text in r["px4_texts"]]
    assert "Mission finished, landed" in texts and any(t.startswith("Disarmed") for t in texts)
    assert r["failsafe_texts"] == []
