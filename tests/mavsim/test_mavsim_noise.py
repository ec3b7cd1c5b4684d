"""The drone's reported position error: white by default, Gauss-Markov when asked, honest either way.

Honest: the covariance ODOMETRY reports is the error's covariance, so the NEES of the
reported position against the truth averages 3 (chi2_3), correlated or not.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.lockstep import LockstepSimulator
from mavsim.noise import GaussMarkovError
from mavsim.obstacles import noise_factor
from mavsim.scenario import ScenarioError, scenario_from_dict

P = np.array([[0.04, 0.01, 0.0], [0.01, 0.02, 0.005], [0.0, 0.005, 0.03]])  # m^2, correlated axes


def _lag1(e: np.ndarray) -> float:
    return float(np.mean([np.corrcoef(e[:-1, k], e[1:, k])[0, 1] for k in range(3)]))


def test_that_the_gauss_markov_error_keeps_its_covariance_and_correlates_as_exp_of_minus_dt_over_tau():
    rng = np.random.default_rng(7)
    dt_us, tau = 20_000, 0.5
    gm = GaussMarkovError(noise_factor(P), tau)
    e = np.array([gm.sample(k * dt_us, rng.standard_normal(3)).copy() for k in range(40_000)])  # 800 s
    assert np.cov(e.T) == pytest.approx(P, abs=0.2 * P.max())
    assert _lag1(e) == pytest.approx(math.exp(-0.02 / tau), abs=0.02)
    nees = np.einsum("ij,jk,ik->i", e, np.linalg.inv(P), e)
    assert nees.mean() == pytest.approx(3.0, abs=0.4)


def test_that_a_zero_correlation_time_is_the_white_noise_of_before():
    rng = np.random.default_rng(8)
    gm = GaussMarkovError(noise_factor(P), 0.0)
    for k in range(5):
        w = rng.standard_normal(3)
        assert np.array_equal(gm.sample(k * 10_000, w), noise_factor(P) @ w)
    with pytest.raises(ValueError, match="correlation time"):
        GaussMarkovError(noise_factor(P), -1.0)


def test_that_the_correlation_time_is_a_checked_sim_key():
    assert scenario_from_dict({}).sim.position_noise_correlation_s == 0.0
    assert scenario_from_dict({"sim": {"position_noise_correlation_s": 2.5}}).sim.position_noise_correlation_s == 2.5
    with pytest.raises(ScenarioError, match="position_noise_correlation_s"):
        scenario_from_dict({"sim": {"position_noise_correlation_s": -1.0}})


def test_that_odometry_reports_a_correlated_error_with_its_true_covariance():
    tau, seconds = 0.3, 60.0
    scenario = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
                "sim": {"position_noise_cov_m2": P.tolist(), "position_noise_correlation_s": tau}}
    parser = mavlink2.MAVLink(None)
    errors, nees = [], []
    with LockstepSimulator(scenario, seed=3) as sim:
        truth = sim.truth.drone_position_ned_m.copy()  # hovering in AUTO.LOITER: the truth stands still
        for _ in range(int(seconds / 0.1)):
            for _, packet in sim.advance(0.1):
                for msg in parser.parse_buffer(packet) or []:
                    if msg.get_type() != "ODOMETRY":
                        continue
                    e = np.array([msg.x, msg.y, msg.z]) - truth
                    ut = msg.pose_covariance
                    reported = np.array([[ut[0], ut[1], ut[2]], [ut[1], ut[6], ut[7]], [ut[2], ut[7], ut[11]]])
                    errors.append(e)
                    nees.append(float(e @ np.linalg.solve(reported, e)))
        assert np.allclose(sim.truth.drone_position_ned_m, truth, atol=1e-6)
    errors = np.array(errors)
    assert len(errors) > 1000
    assert np.mean(nees) == pytest.approx(3.0, abs=0.8)  # ~100 independent stretches of tau in 60 s
    assert _lag1(errors) > 0.5  # consecutive reports share most of the error (white: ~0)


def _obstacle_reports(correlation_s: float | None, seconds: float, seed: int) -> tuple[np.ndarray, list[float]]:
    """Errors of a standing obstacle's ODOMETRY reports (10 Hz) and their NEES against the covariance reported."""
    from mavsim.obstacles import ObstacleSystem

    table = {"name": "ob", "start_ned_m": [3.0, 1.0, -5.0], "velocity_ned_mps": [0.0, 0.0, 0.0],
             "measurement_cov_m2": P.tolist()}
    if correlation_s is not None:
        table["measurement_correlation_s"] = correlation_s
    ob = scenario_from_dict({"world": {"obstacles": [table]}}).obstacles[0]
    system = ObstacleSystem(ob, 101, 197, np.random.default_rng(seed), 0)
    errors, nees = [], []
    for k in range(int(seconds * 10)):
        for _, msg in system.due(1000 + k * 100_000):
            if msg.get_type() != "ODOMETRY":
                continue
            e = np.array([msg.x, msg.y, msg.z]) - ob.start_ned_m
            ut = msg.pose_covariance
            reported = np.array([[ut[0], ut[1], ut[2]], [ut[1], ut[6], ut[7]], [ut[2], ut[7], ut[11]]])
            errors.append(e)
            nees.append(float(e @ np.linalg.solve(reported, e)))
    return np.array(errors), nees


def test_that_an_obstacle_reports_a_correlated_error_with_its_true_covariance():
    tau = 0.5
    errors, nees = _obstacle_reports(tau, 200.0, seed=4)
    assert len(errors) == 2000
    assert np.mean(nees) == pytest.approx(3.0, abs=0.5)  # ~400 independent stretches of tau in 200 s
    assert _lag1(errors) == pytest.approx(math.exp(-0.1 / tau), abs=0.06)  # reports 0.1 s apart
    white, white_nees = _obstacle_reports(None, 200.0, seed=4)
    assert abs(_lag1(white)) < 0.1 and np.mean(white_nees) == pytest.approx(3.0, abs=0.3)
    assert np.array_equal(white, _obstacle_reports(0.0, 200.0, seed=4)[0])  # 0 is the white noise of before


def test_that_the_obstacle_correlation_time_is_a_checked_obstacle_key():
    base = {"name": "ob", "start_ned_m": [3.0, 1.0, -5.0], "velocity_ned_mps": [0.0, 0.0, 0.0]}
    assert scenario_from_dict({"world": {"obstacles": [base]}}).obstacles[0].measurement_correlation_s == 0.0
    with pytest.raises(ScenarioError, match="measurement_correlation_s"):
        scenario_from_dict({"world": {"obstacles": [dict(base, measurement_correlation_s=-2.0)]}})


def test_that_the_velocity_bias_is_a_bounded_checked_function_of_time():
    from mavsim.noise import VelocityBias

    vb = VelocityBias(np.array([0.3, 0.4, 0.5]), 20.0)
    t = np.linspace(0.0, 40.0, 4001)
    b = np.array([vb.bias(x) for x in t])
    np.testing.assert_allclose(np.abs(b).max(axis=0), [0.3, 0.4, 0.5], rtol=1e-4)
    np.testing.assert_allclose(b[0], [0.0, 0.4, 0.0], atol=1e-12)      # the axes a quarter period apart
    np.testing.assert_array_equal(vb.bias(7.3), vb.bias(7.3))          # no state, no draws
    np.testing.assert_allclose(vb.bias(7.3), vb.bias(27.3), atol=1e-12)
    assert np.all(scenario_from_dict({}).sim.velocity_bias_mps == 0.0)
    sim = scenario_from_dict({"sim": {"velocity_bias_mps": [0.0, 0.3, -0.2], "velocity_bias_period_s": 12.0}}).sim
    assert sim.velocity_bias_mps.tolist() == [0.0, 0.3, -0.2] and sim.velocity_bias_period_s == 12.0
    for bad in ({"velocity_bias_mps": [0.0, 6.0, 0.0]}, {"velocity_bias_mps": [0.0, 0.1]},
                {"velocity_bias_period_s": 0.0}):
        with pytest.raises(ScenarioError, match=next(iter(bad))):
            scenario_from_dict({"sim": bad})


def test_that_the_vehicle_flies_on_the_biased_velocity_and_reports_it():
    # hovering in AUTO.LOITER with a steady east bias: the reported velocity is the true one plus
    # the bias, and the vehicle truly flies the hold's setpoint less the bias
    from mavsim.noise import VelocityBias

    period = 400.0                        # east starts at its full 0.3 m/s and stays near it for seconds
    scenario = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
                "sim": {"velocity_bias_mps": [0.0, 0.3, 0.0], "velocity_bias_period_s": period,
                        "velocity_noise_cov_m2ps2": (1e-12 * np.eye(3)).tolist()}}
    parser, gaps = mavlink2.MAVLink(None), []
    with LockstepSimulator(scenario, seed=1) as sim:
        for _ in range(30):
            for _, packet in sim.advance(0.1):
                for msg in parser.parse_buffer(packet) or []:
                    if msg.get_type() == "ODOMETRY":
                        reported_east = msg.vy
            gaps.append(reported_east - sim.truth.drone_velocity_ned_mps[1])
    bias_east = VelocityBias(np.array([0.0, 0.3, 0.0]), period).bias(1.5)[1]
    assert bias_east == pytest.approx(0.3, abs=1e-4)
    # reported minus true east velocity is the bias (the truth sampled at the end of each 0.1 s)
    assert np.median(gaps) == pytest.approx(bias_east, abs=0.05)
