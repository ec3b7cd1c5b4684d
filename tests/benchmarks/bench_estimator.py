"""Estimator cost per control cycle: update 10 tracks and predict them over N = 40 steps.

Rows: the median (and 95th percentile) wall time of one cycle (the ten updates one by one,
as reports arrive, then one ``ObstacleTracker.predict_many`` of the ten, as the companion's
request builder asks), the cost of one filterpy track update, the closed-form horizon
prediction per track against a loop of filterpy ``predict`` calls for one track (peer), and
the drone filter's update plus horizon covariance.
"""

from __future__ import annotations

import copy
import time

import numpy as np

from estimator import DroneFilter, DroneFilterConfig, ObstacleTracker, TrackerConfig
from estimator.models import process_noise, transition_matrix

TRACKS = 10
HORIZON = 40
STEP_S = 0.3
CYCLES = 400
REPORT_DT_S = 0.1


def _cycle_times() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    tr = ObstacleTracker(TrackerConfig())
    keys = [(101 + i, 1) for i in range(TRACKS)]
    start = rng.uniform(-20, 20, (TRACKS, 3))
    vel = rng.uniform(-1, 1, (TRACKS, 3))
    R = 0.02 * np.eye(3)
    cycle, update_only, predict_only = [], [], []
    for c in range(CYCLES + 20):
        t = c * REPORT_DT_S
        z = start + vel * t + 0.14 * rng.standard_normal((TRACKS, 3))
        horizon = t + STEP_S * np.arange(1, HORIZON + 1)
        t0 = time.perf_counter()
        for i, key in enumerate(keys):
            tr.update(key, t, z[i], None, R, None)
        t1 = time.perf_counter()
        tr.predict_many(keys, horizon)   # as the companion's request builder predicts its tracks
        t2 = time.perf_counter()
        if c >= 20:  # warm-up
            cycle.append(t2 - t0)
            update_only.append((t1 - t0) / TRACKS)
            predict_only.append((t2 - t1) / TRACKS)
    return np.array(cycle), np.array(update_only), np.array(predict_only)


def _filterpy_loop_predict_s() -> float:
    """Median time of the same 40-step prediction as a loop of filterpy predict calls."""
    tr = ObstacleTracker(TrackerConfig())
    for k in range(10):
        tr.update("a", 0.1 * k, [0.1 * k, 0.0, -5.0], None, 0.02 * np.eye(3))
    kf0 = tr._tracks["a"].kf
    F, Q = transition_matrix(STEP_S), process_noise(STEP_S, tr.config.accel_noise_psd_m2ps3)
    times = []
    for _ in range(200):
        kf = copy.copy(kf0)
        t0 = time.perf_counter()
        covs = np.empty((HORIZON, 3, 3))
        for k in range(HORIZON):
            kf.predict(F=F, Q=Q)
            covs[k] = kf.P[:3, :3]
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _drone_cycle_s() -> float:
    rng = np.random.default_rng(1)
    f = DroneFilter(DroneFilterConfig())
    velocities = np.zeros((HORIZON, 3))
    times = []
    for k in range(CYCLES):
        t = k / 30.0
        t0 = time.perf_counter()
        f.update(t, rng.standard_normal(3), rng.standard_normal(3), [0.02] * 3, [0.01] * 3)
        f.predict_position_covariances(t, velocities, STEP_S)
        times.append(time.perf_counter() - t0)
    return float(np.median(times[20:]))


def run() -> list[dict]:
    cycle, update_only, predict_only = _cycle_times()
    loop_s = _filterpy_loop_predict_s()
    closed_s = float(np.median(predict_only))
    return [
        {
            "name": f"tracker cycle: update {TRACKS} tracks + predict all N={HORIZON} (median)",
            "value": float(np.median(cycle)) * 1e3, "unit": "ms", "target": "<= 0.4 ms",
            "note": f"{CYCLES} cycles; p95 {np.percentile(cycle, 95) * 1e3:.3f} ms; shared CPU, noisy",
        },
        {
            "name": "track update (filterpy predict + gate + Joseph update), per track",
            "value": float(np.median(update_only)) * 1e6, "unit": "us", "target": None, "note": "",
        },
        {
            "name": f"track horizon prediction N={HORIZON}, closed form, per track of {TRACKS} in one pass",
            "value": closed_s * 1e6, "unit": "us", "target": None,
            "peer": loop_s * 1e6, "ratio": loop_s / closed_s,
            "note": "peer: loop of filterpy KalmanFilter.predict calls (us)",
        },
        {
            "name": f"drone update + predict_position_covariances N={HORIZON} (median)",
            "value": _drone_cycle_s() * 1e6, "unit": "us", "target": None, "note": "position + velocity report",
        },
    ]
