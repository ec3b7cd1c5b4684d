"""Obstacle tracker: creation, gating, drop, re-initialisation, counters, SPD property."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator import ObstacleTracker, TrackerConfig, UnknownTrackError
from estimator.errors import EstimatorConfigError, EstimatorInputError

KEY = (101, 1)
R = 0.02 * np.eye(3)


def tracked(cfg: TrackerConfig | None = None, steps: int = 10) -> ObstacleTracker:
    tr = ObstacleTracker(cfg or TrackerConfig())
    for k in range(steps):
        assert tr.update(KEY, 0.1 * k, [20.0 - 0.1 * k, 0.0, -5.0], None, R, None).accepted
    return tr


def test_that_a_track_is_created_on_its_first_report_with_a_wide_velocity_prior():
    tr = ObstacleTracker(TrackerConfig(initial_velocity_std_mps=4.0))
    result = tr.update(KEY, 3.0, [1.0, 2.0, -5.0], None, R, None)
    assert (result.accepted, result.reason) == (True, "initialised")
    assert tr.keys() == [KEY] and KEY in tr and len(tr) == 1
    s = tr.state(KEY)
    np.testing.assert_array_equal(s.position, [1.0, 2.0, -5.0])
    np.testing.assert_array_equal(s.velocity, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(s.velocity_cov, 16.0 * np.eye(3))
    assert tr.stats.tracks_created == 1


def test_that_tracks_are_independent_per_key():
    tr = ObstacleTracker(TrackerConfig())
    tr.update((101, 1), 0.0, [0.0, 0.0, 0.0])
    tr.update((102, 1), 0.0, [10.0, 0.0, 0.0])
    tr.update("adsb:abc123", 0.0, [0.0, 10.0, 0.0])
    assert tr.keys() == [(101, 1), (102, 1), "adsb:abc123"]
    assert tr.state((102, 1)).position[0] == 10.0


def test_that_report_covariance_is_used_and_all_nan_means_configured():
    tr = ObstacleTracker(TrackerConfig(position_noise_std_m=0.5))
    C = np.array([[0.04, 0.01, 0.0], [0.01, 0.09, 0.0], [0.0, 0.0, 0.01]])
    tr.update("a", 0.0, [0, 0, 0], None, C)
    tr.update("b", 0.0, [0, 0, 0], None, np.full((3, 3), np.nan))
    np.testing.assert_allclose(tr.state("a").position_cov, C)
    np.testing.assert_allclose(tr.state("b").position_cov, 0.25 * np.eye(3))


def innovation_at(tr: ObstacleTracker, t: float, sigmas: float, direction: np.ndarray) -> np.ndarray:
    """A report ``sigmas`` standard deviations away along ``direction``: NIS = sigmas^2."""
    mean, cov = tr.predict(KEY, [t])
    S = cov[0] + R  # S = H P H' + R
    u = direction / np.linalg.norm(direction)
    return mean[0] + sigmas * np.linalg.cholesky(S) @ u


def test_that_gating_rejects_a_ten_sigma_outlier_and_accepts_a_one_sigma_report():
    tr = tracked()
    u = np.array([1.0, -2.0, 0.5])
    outlier = tr.update(KEY, 1.0, innovation_at(tr, 1.0, 10.0, u), None, R)
    assert (outlier.accepted, outlier.reason) == (False, "gated")
    assert outlier.nis == pytest.approx(100.0) and outlier.dof == 3
    assert tr.stats.gated == 1
    inlier = tr.update(KEY, 1.0, innovation_at(tr, 1.0, 1.0, u), None, R)
    assert (inlier.accepted, inlier.reason) == (True, "updated")
    assert inlier.nis == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(lambda v: np.linalg.norm(v) > 1e-3),
    st.floats(0.01, 1.0),
)
def test_that_the_gate_separates_one_and_ten_sigma_in_any_direction_and_lag(direction, lag):
    tr = tracked()
    t = tr.state(KEY).t_s + lag
    assert tr.update(KEY, t, innovation_at(tr, t, 10.0, np.array(direction)), None, R).reason == "gated"
    assert tr.update(KEY, t, innovation_at(tr, t, 1.0, np.array(direction)), None, R).accepted


def test_that_gate_threshold_is_the_chi_square_quantile():
    tr = ObstacleTracker(TrackerConfig(gate_probability=0.99))
    assert tr.gate_thresholds[3] == pytest.approx(11.3448667)
    assert tr.gate_thresholds[6] == pytest.approx(16.8118938)


def test_that_a_gated_track_recovers_by_reinitialising_after_the_gap():
    tr = tracked(TrackerConfig(reinit_gap_s=0.5))
    jumped = [50.0, 0.0, -5.0]
    assert tr.update(KEY, 1.0, jumped).reason == "gated"
    assert tr.update(KEY, 1.3, jumped).reason == "gated"
    assert tr.update(KEY, 1.5, jumped).reason == "reinitialised"
    np.testing.assert_array_equal(tr.state(KEY).position, jumped)


def parked_then_flying(cfg: TrackerConfig) -> tuple[ObstacleTracker, list]:
    """A source parked 10 s (10 Hz reports with velocity, as ODOMETRY gives), then flying east at
    2 m/s from 10.0 s on: the tracker and the reasons of its reports from 10.1 s on."""
    tr = ObstacleTracker(cfg)
    for k in range(100):
        assert tr.update(KEY, 0.1 * k, [0.0, 0.0, -5.0], [0.0, 0.0, 0.0], R, 0.01 * np.eye(3)).accepted
    reasons = []
    for k in range(1, 16):
        reasons.append(tr.update(KEY, 10.0 + 0.1 * k, [0.0, 0.2 * k, -5.0], [0.0, 2.0, 0.0], R, 0.01 * np.eye(3)).reason)
    return tr, reasons


def test_that_a_source_that_starts_moving_is_followed_after_three_gated_reports():
    """Before ``reinit_after_gated`` the still track refused the flying source's reports for the
    whole ``reinit_gap_s`` (1.5 s, 3 m of flight unseen); now the third refusal re-initialises it."""
    tr, reasons = parked_then_flying(TrackerConfig(accel_noise_psd_m2ps3=0.01))
    assert reasons[:3] == ["gated", "gated", "reinitialised"]
    assert set(reasons[3:]) == {"updated"}
    np.testing.assert_allclose(tr.state(KEY).velocity, [0.0, 2.0, 0.0], atol=0.05)
    locked, reasons = parked_then_flying(TrackerConfig(accel_noise_psd_m2ps3=0.01, reinit_after_gated=100))
    assert reasons.index("reinitialised") >= 13   # locked out 1.4 s or more: until the gap


def test_that_lone_outliers_between_good_reports_never_reinitialise():
    tr = tracked(TrackerConfig(reinit_after_gated=2))
    t, u = 1.0, np.array([1.0, 0.0, 0.0])
    for _ in range(5):
        assert tr.update(KEY, t, innovation_at(tr, t, 10.0, u), None, R).reason == "gated"
        t += 0.1
        assert tr.update(KEY, t, innovation_at(tr, t, 0.5, u), None, R).reason == "updated"
        t += 0.1
    assert tr.stats.gated == 5 and tr.stats.reinitialised == 0


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "3"])
def test_that_reinit_after_gated_must_be_a_whole_number_of_reports(bad):
    with pytest.raises(EstimatorConfigError, match="reinit_after_gated"):
        TrackerConfig(reinit_after_gated=bad)


def test_that_silent_tracks_are_dropped_and_recreated_on_a_new_report():
    tr = tracked(TrackerConfig(drop_after_s=2.0))
    tr.update((102, 1), 2.5, [0.0, 0.0, -5.0])
    assert tr.prune(2.9) == []  # last (101, 1) report at 0.9 s: silent exactly 2.0 s
    assert tr.prune(3.0) == [KEY]
    assert tr.keys() == [(102, 1)]
    with pytest.raises(UnknownTrackError, match=r"no track \(101, 1\)"):
        tr.predict(KEY, [3.0])
    assert tr.update(KEY, 3.1, [1.0, 0.0, -5.0]).reason == "initialised"
    stats = tr.stats
    assert (stats.tracks_created, stats.tracks_dropped, stats.active_tracks) == (3, 1, 2)


@pytest.mark.parametrize(
    ("t", "pos", "pos_cov", "reason"),
    [
        (0.5, [1.0, 0.0, -5.0], None, "out_of_order"),
        (0.9, [1.0, 0.0, -5.0], None, "duplicate"),
        (1.0, [np.nan, 0.0, -5.0], None, "non_finite"),
        (float("inf"), [1.0, 0.0, -5.0], None, "non_finite"),
        (1.0, [1.0, 0.0, -5.0], np.diag([0.1, np.inf, 0.1]), "invalid_covariance"),
        (1.0, [1.0, 0.0, -5.0], np.diag([0.1, -0.1, 0.1]), "invalid_covariance"),
        (1.0, [1.0, 0.0, -5.0], np.array([[0.1, 0.05, 0], [0.0, 0.1, 0], [0, 0, 0.1]]), "invalid_covariance"),
        (1.0, [1.0, 0.0, -5.0], np.eye(4), "invalid_shape"),
    ],
)
def test_that_bad_reports_are_rejected_logged_and_counted(caplog, t, pos, pos_cov, reason):
    tr = tracked()
    before = tr.state(KEY)
    with caplog.at_level(logging.DEBUG, logger="estimator"):
        result = tr.update(KEY, t, pos, None, pos_cov)
    assert (result.accepted, result.reason) == (False, reason)
    assert reason in caplog.text
    assert getattr(tr.stats, reason) == 1 and tr.stats.rejected == 1
    np.testing.assert_array_equal(tr.state(KEY).cov, before.cov)


def test_that_predict_validates_times_and_keys():
    tr = tracked()
    with pytest.raises(EstimatorInputError, match="finite 1-D"):
        tr.predict(KEY, [[1.0, 2.0]])
    with pytest.raises(UnknownTrackError):
        tr.state("nobody")


def _five_tracks_heard_at_different_times() -> tuple[ObstacleTracker, list]:
    """A tracker with five tracks, each last updated at a different time, and their keys."""
    rng = np.random.default_rng(7)
    tr = ObstacleTracker(TrackerConfig())
    keys = [(101 + i, 1) for i in range(5)]
    for k in range(8):
        for i, key in enumerate(keys):
            if k < 3 + i:   # tracks last heard at different times
                tr.update(key, 0.1 * k + 0.01 * i, rng.normal(size=3) + [i, 0.1 * k, -5.0], None, R)
    return tr, keys


def test_that_predicting_many_tracks_at_once_gives_each_track_s_own_numbers():
    tr, keys = _five_tracks_heard_at_different_times()
    times = 1.0 + 0.3 * np.arange(12)
    means, covs = tr.predict_many(keys, times)
    assert means.shape == (5, 12, 3) and covs.shape == (5, 12, 3, 3)
    for k, key in enumerate(keys):
        m, c = tr.predict(key, times)
        assert np.array_equal(means[k], m) and np.array_equal(covs[k], c)   # bit for bit
    empty_m, empty_c = tr.predict_many([], times)
    assert empty_m.shape == (0, 12, 3) and empty_c.shape == (0, 12, 3, 3)
    with pytest.raises(UnknownTrackError):
        tr.predict_many([keys[0], "nobody"], times)
    with pytest.raises(EstimatorInputError, match="finite 1-D"):
        tr.predict_many(keys, [np.nan])


def test_that_the_stacked_estimates_are_each_track_s_state_and_copies():
    tr, keys = _five_tracks_heard_at_different_times()
    order = keys[::-1]     # any order of the keys asked for
    t, mean, cov = tr.stacked(order)
    assert t.shape == (5,) and mean.shape == (5, 6) and cov.shape == (5, 6, 6)
    assert len(set(t)) == 5     # each last heard at its own time
    for k, key in enumerate(order):
        state = tr.state(key)
        assert t[k] == state.t_s and np.array_equal(mean[k], state.mean) and np.array_equal(cov[k], state.cov)
    cov[0, 0, 0] = 1e9     # a copy: the track is untouched
    assert tr.state(order[0]).cov[0, 0] != 1e9
    t0, m0, c0 = tr.stacked([])
    assert t0.shape == (0,) and m0.shape == (0, 6) and c0.shape == (0, 6, 6)
    with pytest.raises(UnknownTrackError):
        tr.stacked([keys[0], "nobody"])


finite = st.floats(-1e4, 1e4, allow_nan=False)
vec3 = st.lists(finite, min_size=3, max_size=3)
spd = st.tuples(st.lists(st.floats(-1.0, 1.0), min_size=9, max_size=9), st.floats(1e-4, 10.0)).map(
    lambda a: (lambda A: A @ A.T + a[1] * np.eye(3))(np.array(a[0]).reshape(3, 3))
)
report = st.tuples(st.floats(1e-3, 3.0), vec3, st.one_of(st.none(), vec3), st.one_of(st.none(), spd), st.one_of(st.none(), spd))


@settings(max_examples=60, deadline=None)
@given(st.lists(report, min_size=1, max_size=25))
def test_that_track_covariance_stays_symmetric_positive_definite_for_any_valid_reports(reports):
    tr = ObstacleTracker(TrackerConfig())
    t = 0.0
    for dt, pos, vel, pcov, vcov in reports:
        t += dt
        tr.update(KEY, t, pos, vel, pcov, vcov)  # accepted or gated: either way the state stays SPD
        cov = tr.state(KEY).cov
        np.testing.assert_array_equal(cov, cov.T)
        np.linalg.cholesky(cov)
    _, covs = tr.predict(KEY, t + 0.3 * np.arange(1, 11))
    np.linalg.cholesky(covs)


def test_that_a_track_of_estimates_takes_the_senders_corrections_where_measurements_lag():
    """A fleet peer announces its own estimate, which its autopilot corrects now and then
    (here 0.5 m north at 1.5 s while it flies east at 1 m/s). Fused as measurements by a
    filter tuned for straight-flying traffic (PSD 0.01) the track takes the correction in
    slowly; adopted, the track is the announcement (mean and covariance) and only predicts
    between announcements."""
    cfg = TrackerConfig(accel_noise_psd_m2ps3=0.01)
    fused, adopted = ObstacleTracker(cfg), ObstacleTracker(cfg)
    cov_p, cov_v = 0.01 * np.eye(3), 0.004 * np.eye(3)
    v = np.array([0.0, 1.0, 0.0])
    for k in range(31):   # 3 s at 10 Hz
        t = 0.1 * k
        p = np.array([0.5 if t >= 1.5 else 0.0, t, -5.0])
        assert fused.update(KEY, t, p, v, cov_p, cov_v).accepted
        result = adopted.update(KEY, t, p, v, cov_p, cov_v, estimate=True)
        assert result.accepted and result.reason == ("initialised" if k == 0 else "adopted")
    lag = np.linalg.norm(fused.state(KEY).mean[:3] - p)
    assert lag > 0.1, lag                                       # 1.5 s on, a third of the correction is missing
    state = adopted.state(KEY)
    assert np.allclose(state.mean[:3], p) and np.allclose(state.mean[3:], v)
    assert np.allclose(state.cov[:3, :3], cov_p) and np.allclose(state.cov[3:, 3:], cov_v)
    assert adopted.stats.adopted == 30 and adopted.stats.updated == 0
    mean, _ = adopted.predict(KEY, np.array([3.5]))
    assert np.allclose(mean[0], p + 0.5 * v)                   # between announcements: constant velocity
