"""Drone filter: rejection counters, re-initialisation, noise selection, SPD property."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator import DroneFilter, DroneFilterConfig, Reason


def started(**cfg) -> DroneFilter:
    f = DroneFilter(DroneFilterConfig(**cfg))
    assert f.update(1.0, [0.0, 0.0, -5.0], [1.0, 0.0, 0.0], None, None).reason == Reason.INITIALISED
    return f


def test_that_the_first_report_initialises_with_reported_variances():
    f = DroneFilter(DroneFilterConfig())
    assert f.state is None
    f.update(0.5, [1.0, 2.0, -3.0], [0.1, 0.2, 0.3], [0.04, 0.05, 0.06], [0.01, 0.02, 0.03])
    s = f.state
    assert s.t_s == 0.5
    np.testing.assert_array_equal(s.mean, [1, 2, -3, 0.1, 0.2, 0.3])
    np.testing.assert_array_equal(np.diag(s.cov), [0.04, 0.05, 0.06, 0.01, 0.02, 0.03])


def test_that_nan_variances_fall_back_to_configured_noise_per_axis():
    f = DroneFilter(DroneFilterConfig(position_noise_std_m=0.5, velocity_noise_std_mps=0.3))
    f.update(0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.04, np.nan, 0.06], None)
    np.testing.assert_allclose(np.diag(f.state.cov), [0.04, 0.25, 0.06, 0.09, 0.09, 0.09])


def test_that_position_only_reports_use_the_velocity_prior():
    f = DroneFilter(DroneFilterConfig(initial_velocity_std_mps=2.0, position_noise_std_m=0.1))
    result = f.update(0.0, [1.0, 1.0, 1.0])  # LOCAL_POSITION_NED without velocity
    assert result.accepted
    np.testing.assert_allclose(np.diag(f.state.cov), [0.01] * 3 + [4.0] * 3)
    assert f.update(0.1, [1.1, 1.0, 1.0]).dof == 3


def test_that_out_of_order_and_duplicate_timestamps_are_ignored_and_counted():
    f = started()
    before = f.state
    r1 = f.update(0.9, [5.0, 5.0, 5.0], None, None, None)
    r2 = f.update(1.0, [5.0, 5.0, 5.0], None, None, None)
    assert (r1.accepted, r1.reason) == (False, "out_of_order")
    assert (r2.accepted, r2.reason) == (False, "duplicate")
    np.testing.assert_array_equal(f.state.mean, before.mean)
    np.testing.assert_array_equal(f.state.cov, before.cov)
    assert (f.stats.out_of_order, f.stats.duplicate, f.stats.rejected) == (1, 1, 2)


@pytest.mark.parametrize(
    ("args", "reason", "counter"),
    [
        ((np.nan, [0, 0, 0], None, None, None), "non_finite", "non_finite"),
        ((2.0, [0, np.nan, 0], None, None, None), "non_finite", "non_finite"),
        ((2.0, [0, 0, 0], [np.inf, 0, 0], None, None), "non_finite", "non_finite"),
        ((2.0, [0, 0, 0], None, [0.1, -0.1, 0.1], None), "invalid_covariance", "invalid_covariance"),
        ((2.0, [0, 0, 0], None, [0.1, np.inf, 0.1], None), "invalid_covariance", "invalid_covariance"),
        ((2.0, [0, 0, 0], [1, 0, 0], None, [0.1, 0.0, 0.1]), "invalid_covariance", "invalid_covariance"),
        ((2.0, [0, 0, 0], None, np.ones((3, 3)), None), "invalid_covariance", "invalid_covariance"),
        ((2.0, [0, 0], None, None, None), "invalid_shape", "invalid_shape"),
    ],
)
def test_that_bad_reports_are_rejected_logged_and_counted_never_raised(caplog, args, reason, counter):
    f = started()
    mean_before = f.state.mean.copy()
    with caplog.at_level(logging.WARNING, logger="estimator.drone"):
        result = f.update(*args)
    assert not result.accepted and result.reason == reason and result.detail
    assert reason in caplog.text
    assert getattr(f.stats, counter) == 1
    np.testing.assert_array_equal(f.state.mean, mean_before)
    assert f.update(1.1, [0.1, 0, -5], [1, 0, 0], None, None).accepted  # still works afterwards


def test_that_a_long_gap_reinitialises_from_the_measurement():
    f = started(reinit_gap_s=0.5, position_noise_std_m=0.2)
    f.update(1.1, [0.1, 0.0, -5.0], [1.0, 0.0, 0.0], None, None)
    result = f.update(2.0, [50.0, 0.0, -5.0], None, None, None)
    assert (result.accepted, result.reason) == (True, "reinitialised")
    np.testing.assert_array_equal(f.state.position, [50.0, 0.0, -5.0])
    np.testing.assert_allclose(f.state.position_cov, 0.04 * np.eye(3))
    assert f.stats.reinitialised == 1 and f.stats.accepted == 3


def test_that_reported_variances_weigh_the_update():
    confident, doubtful = started(), started()
    confident.update(1.1, [1.0, 0.0, -5.0], None, [1e-4] * 3, None)
    doubtful.update(1.1, [1.0, 0.0, -5.0], None, [1e2] * 3, None)
    assert abs(confident.state.position[0] - 1.0) < abs(doubtful.state.position[0] - 1.0)


def assert_spd(cov):
    np.testing.assert_array_equal(cov, cov.T)
    np.linalg.cholesky(cov)
    assert np.min(np.linalg.eigvalsh(cov)) > 0


finite = st.floats(-1e4, 1e4, allow_nan=False)
variance = st.floats(1e-6, 1e2)
vec3 = st.lists(finite, min_size=3, max_size=3)
var3 = st.one_of(st.none(), st.lists(st.one_of(variance, st.just(float("nan"))), min_size=3, max_size=3))
report = st.tuples(st.floats(1e-3, 2.0), vec3, st.one_of(st.none(), vec3), var3, var3)


@settings(max_examples=60, deadline=None)
@given(st.lists(report, min_size=1, max_size=25))
def test_that_covariance_stays_symmetric_positive_definite_for_any_valid_reports(reports):
    f = DroneFilter(DroneFilterConfig())
    t = 0.0
    for dt, pos, vel, pvar, vvar in reports:
        t += dt
        assert f.update(t, pos, vel, pvar, vvar).accepted
        assert_spd(f.state.cov)
    for cov in f.predict_position_covariances(t, np.zeros((10, 3)), 0.3):
        np.linalg.cholesky(cov)


def test_that_an_autopilot_estimate_is_adopted_report_by_report_not_filtered_again():
    # reports = "estimate": each in-order report is the state (mean and covariance); the
    # default re-filters it, and a position report that jumps against its velocity (an EKF
    # correction) moves the filtered mean only part of the way
    jump = ([0.5, -0.3, 0.2], [1.0, 0.0, 0.0], [0.04, 0.04, 0.09], [0.01, 0.01, 0.01])
    adopted, filtered = started(reports="estimate"), started()
    for f in (adopted, filtered):
        f.update(1.1, *jump)
    np.testing.assert_array_equal(adopted.state.mean, [0.5, -0.3, 0.2, 1.0, 0.0, 0.0])
    np.testing.assert_array_equal(np.diag(adopted.state.cov), [0.04, 0.04, 0.09, 0.01, 0.01, 0.01])
    assert adopted.stats.adopted == 1 and adopted.stats.updated == 0 and adopted.stats.accepted == 2
    assert np.abs(filtered.state.position - [0.5, -0.3, 0.2]).max() > 0.1 and filtered.stats.updated == 1
    # time order still holds: an older or repeated report is rejected, the state kept
    assert adopted.update(1.05, [9.0, 9.0, 9.0], [0.0, 0.0, 0.0], None, None).reason == Reason.OUT_OF_ORDER
    assert adopted.update(1.1, [9.0, 9.0, 9.0], [0.0, 0.0, 0.0], None, None).reason == Reason.DUPLICATE
    np.testing.assert_array_equal(adopted.state.position, [0.5, -0.3, 0.2])
    # and it predicts between reports like the filter (the covariance grows with the lag)
    covs = adopted.predict_position_covariances(1.4, np.zeros((2, 3)), 0.3)
    assert covs[1][0, 0] > covs[0][0, 0] > 0.04


@pytest.mark.parametrize("value", ["filter", "", 1])
def test_that_an_unknown_kind_of_drone_report_is_refused_naming_the_field(value):
    from estimator import EstimatorConfigError

    with pytest.raises(EstimatorConfigError, match="reports must be one of"):
        DroneFilterConfig(reports=value)
