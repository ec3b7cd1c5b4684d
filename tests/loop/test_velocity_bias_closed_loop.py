"""Lockstep flights of the PX4 encounter against a velocity estimate that is off, as PX4's was on SIH.

mavsim's PX4 profile with ``[sim] velocity_bias_mps``: the vehicle flies the setpoint less a
slowly varying bias and reports its velocity plus it, while the reported position follows
the truth (``mavsim.noise.VelocityBias``). Without ``[companion] drift_window_s`` the pull
to the goal stalls against the bias (the hunt of docs/PX4.md); with it the plans run in the
estimate's position rate and the companion reaches the goal.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from companion.offline.harness import run_lockstep
from companion.offline.report import companion_report, truth_report

ROOT = Path(__file__).resolve().parents[2]


def _scenario(drift_window_s: float) -> dict:
    with open(ROOT / "configs" / "antipodal_px4.toml", "rb") as f:
        data = tomllib.load(f)
    data["sim"] = {"vehicle": "px4",
                   "position_noise_cov_m2": [[0.02, 0, 0], [0, 0.02, 0], [0, 0, 0.02]],
                   "position_noise_correlation_s": 5.0,
                   "velocity_noise_cov_m2ps2": [[0.0025, 0, 0], [0, 0.0025, 0], [0, 0, 0.0025]],
                   "velocity_bias_mps": [0.2, 0.4, 0.35], "velocity_bias_period_s": 20.0}
    data["companion"]["drift_window_s"] = drift_window_s
    return data


@pytest.mark.parametrize("seed", [0, 1])
def test_that_the_drift_window_reaches_the_goal_that_a_biased_velocity_estimate_stalls(seed):
    planned_in_rate = run_lockstep(_scenario(2.0), seed=seed)
    rate = companion_report(planned_in_rate.companion)
    truth = truth_report(planned_in_rate.truth)
    assert not truth["collided"] and truth["min_true_clearance_m"] > 0.3
    assert rate["min_realised_contour"] >= 0.9 and rate["replans_with_slack"] == 0
    assert rate["goal_reached_companion_t_s"] is not None and rate["goal_reached_companion_t_s"] < 20.0
    assert max(rate["drift_max_mps"]) > 0.2      # it saw the bias (as a drift of -b)
    # the same flight planned from the velocity estimate alone hunts around the goal
    stalled = companion_report(run_lockstep(_scenario(0.0), seed=seed).companion)
    assert stalled["goal_reached_companion_t_s"] is None or stalled["goal_reached_companion_t_s"] > 25.0
    assert stalled["drift_max_mps"] == [0.0, 0.0, 0.0]
    # and strays further from its plans
    assert max(stalled["tracking_error"]["rms_ned_m"]) > max(rate["tracking_error"]["rms_ned_m"])
