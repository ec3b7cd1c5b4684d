"""``[sim] gps_degradations``: a noisy GPS the estimator still fuses.

For the spell the estimate the autopilot reports carries an extra horizontal error of the
configured standard deviation, ODOMETRY's horizontal variance says so (an honest estimator), and
GPS_RAW_INT's horizontal accuracy grows with it; no reset, no failsafe, and before and after it
every message is what it would have been without it.
"""

from __future__ import annotations

import numpy as np
import pytest

from mavsim.scenario import ScenarioError, scenario_from_dict
from tests.support.mavsim_client import hover_record

START, LENGTH, SD = 2.0, 6.0, 1.5
BASE_VAR = 0.0001


def _hover(seed: int, seconds: float = 10.0, **sim) -> tuple[np.ndarray, list[tuple[float, object]]]:
    """The true hover point and (sim time s, message) of ODOMETRY and GPS_RAW_INT while hovering."""
    scenario = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
                "sim": {"position_noise_cov_m2": (BASE_VAR * np.eye(3)).tolist(), "stream_rates_hz": {"GPS_RAW_INT": 5.0},
                        "gps_degradations": [[START, LENGTH, SD]], **sim}}
    return hover_record(scenario, seed, seconds, ("ODOMETRY", "GPS_RAW_INT"))


def test_that_a_degraded_gps_adds_the_error_its_covariance_reports_and_nothing_else():
    scaled = []          # horizontal errors over the reported standard deviation, white, ten seeds
    for seed in range(10):
        truth, out, modes = _hover(seed, gps_degradation_correlation_s=0.0)
        odo = [(t, m) for t, m in out if m.get_type() == "ODOMETRY"]
        during = [m for t, m in odo if START + 0.05 < t < START + LENGTH - 0.05]
        outside = [m for t, m in odo if t < START - 0.05 or t > START + LENGTH + 0.05]
        for m in during:
            assert m.pose_covariance[0] == pytest.approx(BASE_VAR + SD ** 2) and m.pose_covariance[6] == pytest.approx(BASE_VAR + SD ** 2)
            assert m.pose_covariance[11] == pytest.approx(BASE_VAR) and abs(m.z - truth[2]) < 0.1
            scaled += [(m.x - truth[0]) / np.sqrt(m.pose_covariance[0]), (m.y - truth[1]) / np.sqrt(m.pose_covariance[6])]
        assert all(m.pose_covariance[0] == pytest.approx(BASE_VAR) for m in outside)
        assert max(np.hypot(m.x - truth[0], m.y - truth[1]) for m in outside) < 0.1
        assert {m.reset_counter for _, m in odo} == {0} and modes == ["AUTO.LOITER"]
        gps = [(t, m) for t, m in out if m.get_type() == "GPS_RAW_INT"]
        assert {m.fix_type for _, m in gps} == {3}
        assert {m.h_acc for t, m in gps if START + 0.05 < t < START + LENGTH - 0.05} == {round(1000 * np.hypot(0.7, SD))}
        assert {m.h_acc for t, m in gps if t < START - 0.05} == {700}
    scaled = np.array(scaled)
    assert len(scaled) > 3000 and abs(scaled.mean()) < 0.1 and scaled.std() == pytest.approx(1.0, abs=0.05)


def test_that_the_error_is_correlated_in_time_and_seeded_from_a_stream_of_its_own():
    truth, a, _ = _hover(3)
    _, b, _ = _hover(3)
    _, none, _ = _hover(3, gps_degradations=[[100.0, 1.0, SD]])
    pos = lambda out, lo, hi: [(m.x, m.y, m.z) for t, m in out if m.get_type() == "ODOMETRY" and lo <= t < hi]  # noqa: E731
    assert pos(a, 0, 10) == pos(b, 0, 10)
    assert pos(a, 0, START) == pos(none, 0, START)          # nothing else moved
    e = np.array(pos(a, START + 0.1, START + LENGTH - 0.1))[:, :2] - truth[:2]
    lag1 = np.corrcoef(e[:-1, 0], e[1:, 0])[0, 1]             # 30 Hz reports, 2 s correlation: exp(-1/60)
    assert lag1 > 0.9


@pytest.mark.parametrize("rows, why", [
    ([[1.0, 0.0, 1.0]], "duration_s in"), ([[1.0, 2.0, 0.0]], "sd_m in"), ([[1.0, 2.0, 25.0]], "sd_m in"),
    ([[-1.0, 1.0, 1.0]], "t_s must be"), ([[1.0, 2.0, 1.0], [2.5, 1.0, 1.0]], "overlap"), ([[1.0, 2.0]], "rows")])
def test_that_bad_spells_are_refused_with_the_key_named(rows, why):
    with pytest.raises(ScenarioError, match="gps_degradations") as info:
        scenario_from_dict({"sim": {"gps_degradations": rows}})
    assert why in str(info.value)
    assert scenario_from_dict({}).sim.gps_degradations == ()
