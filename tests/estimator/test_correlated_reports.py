"""A track fed reports whose position errors are correlated in time (Gauss-Markov, tau = 60 s).

Fused as independent, ten reports a second make the covariance shrink while the error
stays: the NEES of the position estimate is far above its 3. With
``report_correlation_s`` set, the filter carries the error as states and its NEES is
consistent: inside the chi-square interval of the episodes' final NEES, pooled.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from estimator import ObstacleTracker, TrackerConfig
from estimator.errors import EstimatorConfigError

R = np.diag([0.4**2, 0.4**2, 0.25**2])  # reported (and true stationary) position covariance, m^2
TAU_S = 60.0
RATE_HZ = 10.0
EPISODE_S = 20.0
EPISODES = 150


def _final_nees(report_correlation_s: float, seed: int = 7) -> np.ndarray:
    """Per episode: NEES of the track's position at the end, against the truth."""
    rng = np.random.default_rng(seed)
    L = np.linalg.cholesky(R)
    dt = 1.0 / RATE_HZ
    phi = math.exp(-dt / TAU_S)
    out = []
    for _ in range(EPISODES):
        tracker = ObstacleTracker(TrackerConfig(report_correlation_s=report_correlation_s))
        v = rng.normal(0.0, 1.5, 3) * [1.0, 1.0, 0.1]
        p0 = rng.normal(0.0, 10.0, 3)
        e = L @ rng.normal(size=3)  # stationary from the start
        for k in range(int(EPISODE_S * RATE_HZ)):
            if k:
                e = phi * e + math.sqrt(1.0 - phi * phi) * (L @ rng.normal(size=3))
            p = p0 + v * k * dt
            assert tracker.update("ob", k * dt, p + e, None, R, None).accepted
        _, x, P = tracker.stacked(["ob"])
        d = x[0, :3] - p
        out.append(float(d @ np.linalg.solve(P[0, :3, :3], d)))
    return np.array(out)


def test_that_fusing_correlated_reports_as_independent_is_overconfident_and_the_shaped_filter_is_not():
    lo, hi = chi2.ppf([0.025, 0.975], 3 * EPISODES) / EPISODES  # mean of EPISODES chi2_3 draws, 95 %
    white = _final_nees(0.0)
    shaped = _final_nees(TAU_S)
    assert white.mean() > 2.0 * hi, white.mean()          # measured 10 at 40 s
    assert lo <= shaped.mean() <= hi, (shaped.mean(), lo, hi)


def test_that_the_published_state_is_position_and_velocity_only():
    tracker = ObstacleTracker(TrackerConfig(report_correlation_s=TAU_S))
    tracker.update("ob", 0.0, np.zeros(3), None, R, None)
    tracker.update("ob", 0.1, np.zeros(3), None, R, None)
    state = tracker.state("ob")
    assert state.mean.shape == (6,) and state.cov.shape == (6, 6)
    # the first report says where p + e is, not where p is: p's variance stays near R
    assert np.all(np.diag(state.cov)[:3] >= 0.9 * np.diag(R))
    means, covs = tracker.predict_many(["ob"], np.array([0.1, 1.1]))
    assert means.shape == (1, 2, 3) and covs.shape == (1, 2, 3, 3)


@pytest.mark.parametrize("bad", [-1.0, math.inf, math.nan])
def test_that_a_bad_correlation_time_is_refused_naming_the_field(bad):
    with pytest.raises(EstimatorConfigError, match="report_correlation_s"):
        TrackerConfig(report_correlation_s=bad)
