"""The planner's first-order velocity-lag model against a fine-step simulation of the lag.

The simulation integrates ``dv/dt = (u - v) / T`` with the command held over each step,
as mavsim's vehicle does; the model's closed forms must give the same step-end
velocities and positions, and the planner's plans must obey them.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.errors import ConfigError
from companion.core.planner import Planner, PlannerConfig, PlanRequest
from companion.core.planner.vehicle_model import LagModel


def _simulate(p0, v0, commands, step_s, time_constant_s, substeps=2000):
    """Step-end positions and velocities of a first-order lag driven by held commands."""
    dt = step_s / substeps
    decay = np.exp(-dt / time_constant_s)
    p, v = np.array(p0, dtype=float), np.array(v0, dtype=float)
    positions, velocities = [], []
    for u in commands:
        for _ in range(substeps):       # exact over dt for v; trapezoid for p
            v_next = u + (v - u) * decay
            p = p + 0.5 * dt * (v + v_next)
            v = v_next
        positions.append(p.copy())
        velocities.append(v.copy())
    return np.array(positions), np.array(velocities)


def test_that_without_lag_the_model_is_the_papers():
    lag = LagModel.from_time_constant(0.3, 0.0)
    assert (lag.alpha, lag.b, lag.c) == (0.0, 0.3, 0.0)
    v = np.array([[1.0, 0.0, 0.0], [2.0, 1.0, 0.0]])
    np.testing.assert_allclose(lag.commands(np.zeros(3), v), v)
    np.testing.assert_allclose(lag.positions(np.zeros(3), np.zeros(3), v), [[0.3, 0.0, 0.0], [0.9, 0.3, 0.0]])


@settings(max_examples=25, deadline=None)
@given(step_s=st.floats(0.05, 1.0), time_constant_s=st.floats(0.05, 1.0), seed=st.integers(0, 2**31 - 1))
def test_that_the_commands_make_a_lagging_vehicle_fly_the_planned_velocities_and_positions(step_s, time_constant_s, seed):
    rng = np.random.default_rng(seed)
    lag = LagModel.from_time_constant(step_s, time_constant_s)
    assert lag.b + lag.c == pytest.approx(step_s)
    p0, v0 = rng.normal(size=3), rng.normal(size=3)
    velocities = np.cumsum(rng.normal(scale=0.3, size=(6, 3)), axis=0)
    commands = lag.commands(v0, velocities)
    positions, flown = _simulate(p0, v0, commands, step_s, time_constant_s)
    np.testing.assert_allclose(flown, velocities, atol=1e-9)
    np.testing.assert_allclose(lag.positions(p0, v0, velocities), positions, atol=1e-6)


def test_that_a_plan_with_lag_obeys_the_model_and_its_commands_lead_the_velocities():
    n, tau, t_lag = 20, 0.3, 0.3
    cfg = PlannerConfig(horizon_steps=n, step_s=tau, velocity_time_constant_s=t_lag, accel_max_mps2=(1.0, 1.0, 1.0))
    req = PlanRequest(position=np.zeros(3), velocity=np.array([0.5, 0.0, 0.0]),
                      drone_covs=np.broadcast_to(0.02 * np.eye(3), (n, 3, 3)), target=np.array([8.0, 2.0, -1.0]))
    plan = Planner(cfg).solve(req)
    assert plan.status == "optimal"
    lag = LagModel.from_time_constant(tau, t_lag)
    np.testing.assert_allclose(plan.positions, lag.positions(req.position, req.velocity, plan.velocities), atol=1e-3)
    np.testing.assert_allclose(plan.commands, lag.commands(req.velocity, plan.velocities), atol=1e-3)
    flown_positions, flown_velocities = _simulate(req.position, req.velocity, plan.commands, tau, t_lag, substeps=300)
    np.testing.assert_allclose(flown_positions, plan.positions, atol=2e-3)
    # accelerating north at first: the command is ahead of the velocity it produces
    assert plan.commands[0, 0] > plan.velocities[0, 0] > req.velocity[0]


def test_that_a_negative_time_constant_is_rejected():
    with pytest.raises(ConfigError, match=r"velocity_time_constant_s = -0.1 must be >= 0"):
        PlannerConfig(velocity_time_constant_s=-0.1)


def test_that_with_lag_the_commands_stay_within_the_speed_bound():
    """Accelerating to the speed bound, the commands lead the velocity but never exceed v_max."""
    n, tau = 20, 0.3
    cfg = PlannerConfig(horizon_steps=n, step_s=tau, velocity_time_constant_s=0.3, velocity_max_mps=(2.0, 2.0, 1.0),
                        accel_max_mps2=(1.0, 1.0, 1.0), weight_progress=1.0)
    req = PlanRequest(position=np.zeros(3), velocity=np.array([1.8, 0.0, 0.0]),
                      drone_covs=np.broadcast_to(0.02 * np.eye(3), (n, 3, 3)), target=np.array([60.0, 0.0, 0.0]))
    plan = Planner(cfg).solve(req)
    assert plan.status == "optimal"
    assert plan.velocities[:, 0].max() > 1.99                        # it reaches the bound...
    assert np.all(np.abs(plan.commands) <= cfg.velocity_max)           # ...without commanding past it
    lag = LagModel.from_time_constant(tau, 0.3)                        # (clipped by at most the tolerance)
    np.testing.assert_allclose(plan.commands, lag.commands(req.velocity, plan.velocities), atol=1e-3)
