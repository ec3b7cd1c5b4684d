"""``[sim] gps_outages``: the estimator dead-reckons through a GPS outage, as PX4's EKF2 does.

While an outage lasts the reported position drifts away from the truth at a seeded velocity, the
horizontal variance ODOMETRY reports grows, and GPS_RAW_INT shows no fix; when it ends the drift
is gone and ODOMETRY's ``reset_counter`` counts one more. Past PX4's own limit on dead
reckoning (``EKF2_NOAID_TOUT``) the position is invalid: PX4 fails safe to ALTCTL, refuses the
modes that need a position, and returns once the GPS is back. The ArduPilot personality, whose
failsafe is not modelled, refuses outages of 5 s or more.
"""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.lockstep import LockstepSimulator
from mavsim.scenario import ScenarioError, scenario_from_dict
from tests.support.mavsim_client import hover_record

START, LENGTH = 4.0, 4.0


def _hover(seed: int, seconds: float = 10.0, **sim) -> tuple[np.ndarray, list[tuple[float, object]]]:
    """The true hover point and (sim time s, message) of ODOMETRY and GPS_RAW_INT while hovering in AUTO.LOITER."""
    scenario = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
                "sim": {"position_noise_cov_m2": (0.0001 * np.eye(3)).tolist(),
                        "gps_outages": [[START, LENGTH]], "stream_rates_hz": {"GPS_RAW_INT": 5.0}, **sim}}
    truth, out, _ = hover_record(scenario, seed, seconds, ("ODOMETRY", "GPS_RAW_INT"))
    return truth, out


def test_that_an_outage_drifts_the_estimate_grows_the_reported_variance_and_ends_in_a_reset():
    truth, out = _hover(seed=1)
    odo = [(t, m) for t, m in out if m.get_type() == "ODOMETRY"]
    before = [m for t, m in odo if t < START]
    during = [(t, m) for t, m in odo if START + 0.5 <= t < START + LENGTH - 0.05]
    after = [m for t, m in odo if t > START + LENGTH + 0.1]
    err = lambda m: np.linalg.norm(np.array([m.x, m.y, m.z]) - truth)  # noqa: E731
    assert max(err(m) for m in before) < 0.1 and max(err(m) for m in after) < 0.1
    # a drift growing with time: linear in tau (a velocity), of the configured size
    late = during[-1]
    tau = late[0] - START
    assert err(late[1]) > 0.05 * tau and err(late[1]) == pytest.approx(err(during[0][1]) * tau / (during[0][0] - START), rel=0.2)
    # the reported horizontal deviation grows as 0.2 m/s by default; z unchanged
    sd_x = np.sqrt(late[1].pose_covariance[0] - 1e-4)
    assert sd_x == pytest.approx(0.2 * tau, rel=0.1) and late[1].pose_covariance[11] == pytest.approx(1e-4)
    assert before[-1].pose_covariance[0] == pytest.approx(1e-4) and after[0].pose_covariance[0] == pytest.approx(1e-4)
    assert {m.reset_counter for m in before} == {0} and {m.reset_counter for m in after} == {1}
    gps = [(t, m.fix_type) for t, m in out if m.get_type() == "GPS_RAW_INT"]
    assert {f for t, f in gps if START + 0.1 < t < START + LENGTH - 0.1} == {1}          # no fix
    assert {f for t, f in gps if t < START - 0.1 or t > START + LENGTH + 0.1} == {3}


def test_that_the_drift_is_seeded_and_moves_no_other_noise():
    _, a = _hover(seed=2)
    _, b = _hover(seed=2)
    _, c = _hover(seed=3)
    def pos(out, until_s=np.inf):
        return [(m.x, m.y, m.z) for t, m in out if m.get_type() == "ODOMETRY" and t < until_s]

    assert pos(a) == pos(b) and pos(a) != pos(c)
    _, later = _hover(seed=2, gps_outages=[[100.0, 1.0]])   # the drift has its own stream: nothing else moves
    assert len(pos(a, START)) > 100 and pos(later, START) == pos(a, START)
    assert pos(later, START + 2.0)[-1] != pos(a, START + 2.0)[-1]      # in the outage: drifting


def _offboard_hover(sim: LockstepSimulator, seconds: float, parser) -> list:
    """Stream zero-velocity OFFBOARD setpoints at 20 Hz for ``seconds``; the HEARTBEATs and STATUSTEXTs seen."""
    out = []
    for _ in range(round(seconds / 0.05)):
        sim.write(mavlink2.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, 0b0000_1111_1100_0111, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(parser))
        for _, packet in sim.advance(0.05):
            for msg in parser.parse_buffer(packet) or []:
                if msg.get_type() in ("HEARTBEAT", "STATUSTEXT"):
                    out.append((sim.time_s, msg))
    return out


def test_that_dead_reckoning_past_px4s_limit_fails_safe_to_altitude_then_returns_when_the_gps_is_back():
    scenario = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
                "sim": {"start_mode": "OFFBOARD", "gps_outages": [[2.0, 8.0]], "params": {"EKF2_NOAID_TOUT": 6000000}}}
    parser = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    with LockstepSimulator(scenario, seed=0) as sim:
        seen = _offboard_hover(sim, 8.5, parser)          # 6 s into the outage at 8 s: ALTCTL
        z_at = {"failsafe": sim.truth.drone_position_ned_m[2]}
        sim.write(mavlink2.MAVLink_command_long_message(1, 1, mavlink2.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0).pack(parser))
        seen += _offboard_hover(sim, 3.0, parser)          # asks for OFFBOARD back in ALTCTL; GPS back at 10 s
        changes = [(round(t, 2), m) for t, m in sim.simulator.commander.mode_changes]
    texts = [(t, m.text) for t, m in seen if m.get_type() == "STATUSTEXT"]
    assert changes == [(0.0, "OFFBOARD"), (8.0, "ALTCTL"), (10.0, "AUTO.RTL")], changes   # EKF2_NOAID_TOUT 6 s from 2 s
    assert [text for t, text in texts if 7.9 <= t <= 8.1] == ["Failsafe: blind land", "Failsafe activated"]
    assert any("Switching to Offboard is currently not available" in text for t, text in texts if 8.5 <= t < 8.6), texts
    beats = {round(t): (m.custom_mode >> 16 & 0xFF, m.system_status) for t, m in seen if m.get_type() == "HEARTBEAT"}
    assert beats[9] == (2, 5) and beats[7] == (6, 4)      # ALTCTL (main mode 2), MAV_STATE_CRITICAL
    # 0.5 s of the blind land at MPC_LAND_SPEED (0.7 m/s) through the vehicle's 0.3 s velocity lag by 8.5 s
    assert z_at["failsafe"] == pytest.approx(-5.0 + 0.7 * (0.5 - 0.3 * (1 - np.exp(-0.5 / 0.3))), abs=0.03)


def test_that_the_ardupilot_personality_refuses_an_outage_its_failsafe_would_end():
    from mavsim.core import SimulationError, Simulator

    scenario = scenario_from_dict({"sim": {"gps_outages": [[1.0, 5.0]]}})
    with pytest.raises(SimulationError, match=r"gps_outages: an outage of 5 s; the ardupilot personality models outages shorter than 5 s"):
        Simulator(scenario, links=("gcs",), personality="ardupilot")
    assert Simulator(scenario, links=("gcs",), personality="px4").scenario.sim.gps_outages == ((1.0, 5.0),)


@pytest.mark.parametrize("rows, why", [
    ([[1.0, 600.5]], "duration_s in"), ([[1.0, 0.0]], "duration_s in"), ([[-1.0, 1.0]], "t_s must be"),
    ([[1.0, 2.0], [2.5, 1.0]], "overlap"), ([[1.0]], "rows"), ("soon", "rows")])
def test_that_bad_outages_are_refused_with_the_key_named(rows, why):
    with pytest.raises(ScenarioError, match="gps_outages") as info:
        scenario_from_dict({"sim": {"gps_outages": rows}})
    assert why in str(info.value)
    assert scenario_from_dict({}).sim.gps_outages == ()
