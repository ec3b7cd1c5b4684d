"""Planning in the estimate's position rate (``[companion] drift_window_s``).

PX4's EKF moves its position estimate against its own velocity estimate when it corrects
with GPS and height. With the drift measured, the plan starts from the estimate's position
rate (``V_0`` = velocity estimate + drift) and the autopilot's velocity loop is sent the
plan's velocity less the drift, so that the estimate moves as planned.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from companion.errors import ConfigError
from companion.loop.config import load_scenario
from tests.loop.test_request_gating import SCENARIO
from tests.loop.test_tracking_margin import _companion
from tests.loop.test_tracking_margin import _fly as fly_north

EXTRA = np.array([0.0, 0.3, -0.2])   # the estimate's position drifts east and up against its velocity


def _fly(companion, service, seconds: float = 3.0) -> tuple[list, list]:
    """Poses whose velocity says 1 m/s north while the position also drifts by EXTRA (20 Hz); the
    jobs and, per tick, the streamed velocity with the executor's command and the drift then."""
    streamed: list = []
    return fly_north(companion, service, seconds, drift=EXTRA, streamed=streamed), streamed


def test_that_the_plans_start_from_the_position_rate_and_the_commands_take_the_drift_off():
    companion, service = _companion(drift_window_s=1.0, initial_velocity="estimate", plan_lead_max_s=0.0)
    jobs, streamed = _fly(companion, service)
    late = [j for j in jobs if j.t_link_s >= 1.0]   # the drift is known from half a window on
    assert len(late) >= 3
    for job in late:
        # no lead (plan_lead_max_s 0): V_0 is the estimate's velocity plus the drift, which the poses make EXTRA
        np.testing.assert_allclose(job.request.velocity, job.drone_velocity + EXTRA, atol=0.02)
    engaged = [(sent, cmd, d) for sent, cmd, d in streamed if np.any(d)]
    assert len(engaged) >= 20
    for sent, cmd, d in engaged:
        np.testing.assert_allclose(sent, cmd - d, rtol=0, atol=1e-12)
    np.testing.assert_allclose(engaged[-1][2], EXTRA, atol=1e-6)   # float32 positions
    assert companion.state.drift_max_mps == pytest.approx(np.abs(EXTRA).tolist(), abs=1e-6)


def test_that_without_a_window_nothing_changes():
    companion, service = _companion(initial_velocity="estimate", plan_lead_max_s=0.0)
    jobs, streamed = _fly(companion, service)
    assert companion.perception.drift is None and companion.state.drift_max_mps == [0.0, 0.0, 0.0]
    for job in jobs:
        np.testing.assert_array_equal(job.request.velocity, job.drone_velocity)
    for sent, cmd, d in streamed:
        np.testing.assert_array_equal(sent, cmd)


def test_that_the_window_is_checked_by_name():
    scenario = load_scenario(SCENARIO)
    for bad in (-1.0, 11.0, float("nan")):
        with pytest.raises(ConfigError, match="drift_window_s"):
            dataclasses.replace(scenario.companion, drift_window_s=bad)


def test_that_a_stale_estimate_brakes_without_the_drift():
    companion, service = _companion(drift_window_s=1.0, initial_velocity="estimate", plan_lead_max_s=0.0)
    _fly(companion, service)
    assert np.any(companion.perception.drift_mps())     # measured before the silence
    sent = []
    for k in range(1, 61):                                # 3 s with no pose: stale, then braked to rest
        t = round(3.0 + 0.05 * k, 2)
        for msg in companion.tick(t):
            if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                sent.append((companion.state.mode, np.array([msg.vx, msg.vy, msg.vz]), companion.executor.command.copy()))
    stale = [(v, cmd) for mode, v, cmd in sent if mode == "stale"]
    assert len(stale) >= 5
    for v, cmd in stale:
        np.testing.assert_array_equal(v, cmd)            # the brake alone, no drift taken off
    np.testing.assert_array_equal(stale[-1][0], np.zeros(3))
