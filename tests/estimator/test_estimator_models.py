"""The constant-velocity model and horizon prediction against independent computations."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from filterpy.common import Q_continuous_white_noise
from scipy.linalg import expm

from estimator import DroneFilter, DroneFilterConfig, ObstacleTracker, TrackerConfig
from estimator.errors import EstimatorInputError, NotInitialisedError
from estimator.models import process_noise, propagate, propagate_position, transition_matrix


def random_spd(rng, n=6):
    A = rng.standard_normal((n, n))
    return A @ A.T + 0.1 * np.eye(n)


def test_that_process_noise_is_the_van_loan_integral_of_white_acceleration():
    dt, q = 0.37, 1.7
    # continuous model x' = A x + G w, E[w w'] = q I; Van Loan: expm([[-A, G q G'], [0, A']] dt)
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    G = np.vstack([np.zeros((3, 3)), np.eye(3)])
    M = np.block([[-A, G @ (q * np.eye(3)) @ G.T], [np.zeros((6, 6)), A.T]]) * dt
    E = expm(M)
    F = E[6:, 6:].T
    Q = F @ E[:6, 6:]
    np.testing.assert_allclose(transition_matrix(dt), F, atol=1e-14)
    np.testing.assert_allclose(process_noise(dt, q), Q, rtol=1e-12, atol=1e-15)


def _block_form(dt, q):
    """``F(dt)`` and ``Q(dt)`` written by blocks, scalar times identity (as the models were first written)."""
    i3 = np.eye(3)
    F = np.eye(6)
    F[:3, 3:] = dt * i3
    Q = np.empty((6, 6))
    Q[:3, :3] = q * dt**3 / 3.0 * i3
    Q[:3, 3:] = q * dt**2 / 2.0 * i3
    Q[3:, :3] = Q[:3, 3:]
    Q[3:, 3:] = q * dt * i3
    return F, Q


def test_that_the_models_every_report_builds_are_the_block_forms_bit_for_bit():
    """F and Q are built for every report (about 1 us each from a template, against 3 to 10 us by
    blocks): the same bytes, signed zeros included, for any interval and noise level."""
    rng = np.random.default_rng(7)
    dts = [0.1, 0.09999999999999987, 0.3, 5e-324, 1e-300, 1e100, -0.1, 0.0, -0.0, np.inf, -np.inf, np.nan,
           np.float64(0.05), 2, *rng.uniform(0.0, 2.0, 300), *(1e3 * rng.standard_normal(50))]
    for dt in dts:
        for q in (0.01, 0.5, 1e-300, 0.0, -0.0, 3.0, -1.0):
            with np.errstate(all="ignore"):
                F, Q = _block_form(dt, q)
                assert transition_matrix(dt).tobytes() == F.tobytes(), dt
                assert process_noise(dt, q).tobytes() == Q.tobytes(), (dt, q)


def test_that_process_noise_matches_filterpy_continuous_white_noise():
    dt, q = 0.1, 2.0
    Q1 = Q_continuous_white_noise(dim=2, dt=dt, spectral_density=q, block_size=3, order_by_dim=False)
    np.testing.assert_allclose(process_noise(dt, q), Q1, rtol=1e-14)


def explicit_horizon(P0, step, q, n):
    """F^k P0 F^k' + sum_{j<k} F^j Q F^j' for k = 1..n, by the textbook sum."""
    F, Q = transition_matrix(step), process_noise(step, q)
    out = []
    for k in range(1, n + 1):
        Fk = np.linalg.matrix_power(F, k)
        P = Fk @ P0 @ Fk.T + sum(
            np.linalg.matrix_power(F, j) @ Q @ np.linalg.matrix_power(F, j).T for j in range(k)
        )
        out.append(P)
    return np.array(out)


def test_that_closed_form_propagation_equals_the_sum_over_steps():
    rng = np.random.default_rng(0)
    P0, x0 = random_spd(rng), rng.standard_normal(6)
    step, q, n = 0.3, 0.8, 40
    expected = explicit_horizon(P0, step, q, n)
    means, covs = propagate(x0, P0, step * np.arange(1, n + 1), q)
    np.testing.assert_allclose(covs, expected, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(means[-1], np.linalg.matrix_power(transition_matrix(step), n) @ x0, rtol=1e-12)
    pm, pc = propagate_position(x0, P0, step * np.arange(1, n + 1), q)
    np.testing.assert_allclose(pc, covs[:, :3, :3], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(pm, means[:, :3], rtol=1e-12, atol=1e-12)


def fitted_drone(seed=1):
    rng = np.random.default_rng(seed)
    f = DroneFilter(DroneFilterConfig(accel_noise_psd_m2ps3=1.3))
    for k in range(20):
        f.update(0.05 * k, rng.standard_normal(3), rng.standard_normal(3), [0.02, 0.03, 0.01], [0.01, 0.01, 0.02])
    return f


def test_that_drone_horizon_covariance_equals_closed_form_from_the_estimate():
    f = fitted_drone()
    s = f.state
    step, n = 0.3, 28
    velocities = np.tile([1.0, -0.5, 0.2], (n, 1))
    covs = f.predict_position_covariances(s.t_s, velocities, step)
    expected = explicit_horizon(s.cov, step, 1.3, n)[:, :3, :3]
    assert covs.shape == (n, 3, 3)
    np.testing.assert_allclose(covs, expected, rtol=1e-11, atol=1e-12)


def test_that_drone_horizon_starting_later_first_predicts_the_estimate_to_t0():
    f = fitted_drone()
    s = f.state
    lag, step, n = 0.12, 0.3, 10
    P0 = transition_matrix(lag) @ s.cov @ transition_matrix(lag).T + process_noise(lag, 1.3)
    covs = f.predict_position_covariances(s.t_s + lag, np.zeros((n, 3)), step)
    np.testing.assert_allclose(covs, explicit_horizon(P0, step, 1.3, n)[:, :3, :3], rtol=1e-11, atol=1e-12)


def test_that_planned_velocities_do_not_change_the_predicted_covariance():
    f = fitted_drone()
    t0 = f.state.t_s
    a = f.predict_position_covariances(t0, np.zeros((5, 3)), 0.2)
    b = f.predict_position_covariances(t0, np.full((5, 3), 3.0), 0.2)
    np.testing.assert_array_equal(a, b)


def test_that_drone_horizon_rejects_bad_arguments_and_an_empty_filter():
    with pytest.raises(NotInitialisedError, match="no estimate"):
        DroneFilter(DroneFilterConfig()).predict_position_covariances(0.0, np.zeros((3, 3)), 0.1)
    f = fitted_drone()
    with pytest.raises(EstimatorInputError, match=r"shape \(N, 3\)"):
        f.predict_position_covariances(1.0, np.zeros((3, 2)), 0.1)
    with pytest.raises(EstimatorInputError, match="step_s"):
        f.predict_position_covariances(1.0, np.zeros((3, 3)), 0.0)
    with pytest.raises(EstimatorInputError, match="finite"):
        f.predict_position_covariances(1.0, np.full((3, 3), np.nan), 0.1)


def test_that_tracker_prediction_agrees_with_repeated_filterpy_predict_calls():
    rng = np.random.default_rng(2)
    tr = ObstacleTracker(TrackerConfig(accel_noise_psd_m2ps3=0.7))
    for k in range(15):
        tr.update("obs", 0.1 * k, [5.0 - 0.1 * k, 1.0, -5.0] + 0.1 * rng.standard_normal(3), None, 0.02 * np.eye(3))
    kf = copy.deepcopy(tr._tracks["obs"].kf)  # the filterpy KalmanFilter behind the track
    t_track = tr.state("obs").t_s
    times = t_track + np.cumsum(rng.uniform(0.05, 0.4, 40))
    means, covs = tr.predict("obs", times)
    prev = t_track
    for i, t in enumerate(times):
        kf.predict(F=transition_matrix(t - prev), Q=process_noise(t - prev, 0.7))
        prev = t
        np.testing.assert_allclose(means[i], kf.x[:3], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(covs[i], kf.P[:3, :3], rtol=1e-10, atol=1e-12)


def test_that_tracker_uncertainty_grows_with_look_ahead():
    tr = ObstacleTracker(TrackerConfig())
    for k in range(10):
        tr.update((101, 1), 0.1 * k, [1.0 * 0.1 * k, 0.0, -5.0], None, None)
    t0 = tr.state((101, 1)).t_s
    means, covs = tr.predict((101, 1), t0 + 0.3 * np.arange(1, 41))
    assert means.shape == (40, 3) and covs.shape == (40, 3, 3)
    traces = np.trace(covs, axis1=1, axis2=2)
    assert np.all(np.diff(traces) > 0)
    assert np.all(np.linalg.eigvalsh(covs[1:] - covs[:-1]) > 0)  # grows in every direction
    assert means[-1, 0] > means[0, 0]  # moving north at about 1 m/s
