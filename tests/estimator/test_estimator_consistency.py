"""Monte Carlo consistency of the filters (Bar-Shalom, Li, Kirubarajan, ch. 5.4).

A target moves with white-noise acceleration exactly as the filter models it
(discrete samples ``w ~ N(0, Q(dt))`` are the exact integral of continuous white
acceleration). Over M runs of K steps, the normalised estimation error squared
``e' P^-1 e`` of position and of velocity (3 dof each) and the normalised innovation
squared ``y' S^-1 y`` must average to their dimension:

* the average over runs and steps lies inside the two-sided 95 % interval of an
  M-run average, ``[chi2.ppf(0.025, M n), chi2.ppf(0.975, M n)] / M``. Averaging over
  steps as well can only shrink the spread, so this interval is a lenient bound; the
* per-step test is the textbook one: at each step the M-run average lies inside the
  same interval for at least 90 % of the steps (95 % expected).

A negative control shows the test has teeth: a filter told a ten times smaller
process noise than the truth fails it.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from estimator import DroneFilter, DroneFilterConfig, ObstacleTracker, TrackerConfig
from estimator.models import process_noise, transition_matrix

RUNS = 50
STEPS = 200


def chi2_interval(dof: int, runs: int = RUNS) -> tuple[float, float]:
    """Two-sided 95 % interval of the average of ``runs`` chi-square(dof) samples."""
    return chi2.ppf(0.025, runs * dof) / runs, chi2.ppf(0.975, runs * dof) / runs


def simulate_truth(rng, dts, q, x0_std):
    """Truth of RUNS targets: (RUNS, STEPS, 6) with x0 ~ N(0, diag(x0_std^2))."""
    X = np.empty((RUNS, len(dts), 6))
    X[:, 0] = rng.standard_normal((RUNS, 6)) * x0_std
    for k in range(1, len(dts)):
        L = np.linalg.cholesky(process_noise(dts[k], q))
        X[:, k] = X[:, k - 1] @ transition_matrix(dts[k]).T + rng.standard_normal((RUNS, 6)) @ L.T
    return X


def nees(err, cov):
    """``e' P^-1 e`` for stacked errors (..., n) and covariances (..., n, n)."""
    return np.einsum("...i,...i->...", err, np.linalg.solve(cov, err[..., None])[..., 0])


def assert_consistent(values: np.ndarray, dof: int, what: str) -> None:
    """values: (RUNS, steps) normalised squares."""
    lo, hi = chi2_interval(dof)
    overall = values.mean()
    assert lo <= overall <= hi, f"{what}: average {overall:.3f} outside [{lo:.3f}, {hi:.3f}]"
    per_step = values.mean(axis=0)
    inside = np.mean((per_step >= lo) & (per_step <= hi))
    assert inside >= 0.90, f"{what}: only {inside:.0%} of per-step averages inside [{lo:.3f}, {hi:.3f}]"


def run_drone(seed: int, q_filter: float):
    rng = np.random.default_rng(seed)
    q_true, dt = 1.0, 1.0 / 30.0
    pos_var = np.array([0.02, 0.05, 0.01])
    vel_var = np.array([0.01, 0.02, 0.005])
    dts = np.full(STEPS, dt)
    # initial position error comes from the first measurement; truth velocity is arbitrary
    X = simulate_truth(rng, dts, q_true, x0_std=np.array([5, 5, 5, 2, 2, 2.0]))
    t = np.cumsum(dts) - dt
    zp = X[..., :3] + rng.standard_normal((RUNS, STEPS, 3)) * np.sqrt(pos_var)
    zv = X[..., 3:] + rng.standard_normal((RUNS, STEPS, 3)) * np.sqrt(vel_var)
    means = np.empty((RUNS, STEPS, 6))
    covs = np.empty((RUNS, STEPS, 6, 6))
    nis = np.full((RUNS, STEPS), np.nan)
    cfg = DroneFilterConfig(accel_noise_psd_m2ps3=q_filter)
    for r in range(RUNS):
        f = DroneFilter(cfg)
        for k in range(STEPS):
            res = f.update(t[k], zp[r, k], zv[r, k], pos_var, vel_var)
            assert res.accepted
            nis[r, k] = res.nis
            means[r, k], covs[r, k] = f.state.mean, f.state.cov
    return X, means, covs, nis


def run_tracker(seed: int, q_filter: float):
    rng = np.random.default_rng(seed)
    q_true, v0_std = 0.5, 3.0
    R = np.array([[0.02, 0.005, 0.0], [0.005, 0.03, 0.002], [0.0, 0.002, 0.01]])
    dts = rng.uniform(0.08, 0.12, STEPS)  # 10 Hz reports with jitter
    X = simulate_truth(rng, dts, q_true, x0_std=np.array([10, 10, 2, v0_std, v0_std, v0_std]))
    t = np.cumsum(dts)
    zp = X[..., :3] + rng.standard_normal((RUNS, STEPS, 3)) @ np.linalg.cholesky(R).T
    means = np.empty((RUNS, STEPS, 6))
    covs = np.empty((RUNS, STEPS, 6, 6))
    nis = np.full((RUNS, STEPS), np.nan)
    tr = ObstacleTracker(TrackerConfig(accel_noise_psd_m2ps3=q_filter, initial_velocity_std_mps=v0_std))
    for r in range(RUNS):
        key = (101 + r, 1)
        for k in range(STEPS):
            res = tr.update(key, t[k], zp[r, k], None, R, None)
            nis[r, k] = res.nis
            s = tr.state(key)
            means[r, k], covs[r, k] = s.mean, s.cov
    return X, means, covs, nis, tr.stats


@pytest.fixture(scope="module")
def drone_runs():
    return run_drone(seed=4, q_filter=1.0)


@pytest.fixture(scope="module")
def tracker_runs():
    return run_tracker(seed=5, q_filter=0.5)


def test_that_drone_filter_position_and_velocity_nees_are_consistent(drone_runs):
    X, means, covs, _ = drone_runs
    err = X - means
    assert_consistent(nees(err[..., :3], covs[..., :3, :3]), 3, "drone position NEES")
    assert_consistent(nees(err[..., 3:], covs[..., 3:, 3:]), 3, "drone velocity NEES")


def test_that_drone_filter_nis_is_consistent(drone_runs):
    *_, nis = drone_runs
    assert_consistent(nis[:, 1:], 6, "drone NIS")


def test_that_tracker_position_and_velocity_nees_are_consistent(tracker_runs):
    X, means, covs, _, _ = tracker_runs
    err = X - means
    assert_consistent(nees(err[..., :3], covs[..., :3, :3]), 3, "tracker position NEES")
    assert_consistent(nees(err[..., 3:], covs[..., 3:, 3:]), 3, "tracker velocity NEES")


def test_that_tracker_nis_is_consistent_and_the_gate_rarely_fires_on_model_data(tracker_runs):
    *_, nis, stats = tracker_runs
    assert stats.gated <= 0.001 * RUNS * STEPS  # gate probability 0.9999
    assert np.all(np.isfinite(nis[:, 1:]))  # gated reports carry their NIS too
    assert_consistent(nis[:, 1:], 3, "tracker NIS")


def test_that_an_overconfident_tracker_fails_the_nees_test():
    X, means, covs, _, _ = run_tracker(seed=5, q_filter=0.05)
    values = nees((X - means)[..., :3], covs[..., :3, :3])
    _, hi = chi2_interval(3)
    assert values.mean() > hi
