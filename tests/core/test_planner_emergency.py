"""``[planner] accel_emergency_mps2``: the least-violation QPs may brake harder than ``accel_max``.

A drone closing on a slower leader faster than ``accel_max`` can stop needs safety slack
without the emergency bound; with it the replan brakes harder and keeps ``c_min``, using
the extra acceleration only where the least-violation QP needed it. Nothing changes where
no QP of the replan needs slack within ``accel_max``. Safety figures are recomputed with the
overlap module.
"""

from __future__ import annotations

import numpy as np
import pytest

from companion.core import overlap
from companion.core.planner import Planner, PlannerConfig, PlanRequest
from companion.errors import ConfigError

S = 0.02 * np.eye(3)
N, TAU = 20, 0.3
START = np.array([0.0, 0.0, -5.0])
NOMINAL = (0.5, 0.5, 0.5)
EMERGENCY = (2.0, 2.0, 1.0)


def _config(**overrides) -> PlannerConfig:
    kwargs = dict(horizon_steps=N, step_s=TAU, c_min=0.3, velocity_max_mps=(3.0, 3.0, 1.0), accel_max_mps2=NOMINAL,
                  velocity_time_constant_s=0.3, drone_radius_m=0.5, sensing_range_m=20.0)
    kwargs.update(overrides)
    return PlannerConfig(**kwargs)


def _closing_request(gap_m: float, drone_speed: float = 2.0, leader_speed: float = 0.5) -> PlanRequest:
    """The drone at ``drone_speed`` north, a leader ``gap_m`` ahead at ``leader_speed`` north, goal beyond it."""
    t = TAU * np.arange(1, N + 1)[:, None]
    leader = START + np.array([gap_m, 0.0, 0.0]) + t * np.array([leader_speed, 0.0, 0.0])
    return PlanRequest(position=START, velocity=np.array([drone_speed, 0.0, 0.0]), drone_covs=np.broadcast_to(S, (N, 3, 3)),
                       target=START + np.array([30.0, 0.0, 0.0]), obstacle_means=leader[None],
                       obstacle_covs=np.broadcast_to(S, (1, N, 3, 3)), obstacle_radii=[0.5])


def _exact_contour(req: PlanRequest, positions: np.ndarray) -> np.ndarray:
    return overlap.contour_of_touch(positions[None], req.drone_covs[None], req.obstacle_means, req.obstacle_covs,
                                    req.obstacle_radii[:, None] + 0.5)


def _accelerations(plan) -> np.ndarray:
    """|V_i - V_{i-1}| / tau per step and axis (N, 3), V_0 the plan's initial velocity, m/s^2."""
    return np.abs(np.diff(np.vstack([plan.initial_velocity[None], plan.velocities]), axis=0)) / TAU


def test_that_a_drone_too_fast_for_accel_max_brakes_harder_and_keeps_c_min():
    req = _closing_request(gap_m=2.6)
    nominal = Planner(_config()).solve(req)
    assert nominal.status == "slack" and nominal.slack_max > 0.05          # accel_max cannot stop it in time
    plan = Planner(_config(accel_emergency_mps2=EMERGENCY)).solve(req)
    assert plan.status == "optimal", plan.notes
    assert np.all(_exact_contour(req, plan.positions) >= 0.3 - 1e-6)
    acc = _accelerations(plan)
    assert acc.max() > NOMINAL[0] + 0.1                                   # it did brake harder ...
    assert np.all(acc <= np.array(EMERGENCY) + 1e-3)                      # ... within the emergency bound
    assert any(n.startswith("accel_emergency") for n in plan.notes), plan.notes


def test_that_emergency_acceleration_is_used_only_where_the_least_violation_needed_it():
    req = _closing_request(gap_m=2.6)
    plan = Planner(_config(accel_emergency_mps2=EMERGENCY)).solve(req)
    over = _accelerations(plan) > np.array(NOMINAL) + 1e-3
    # the braking comes first; the rest of the horizon (the catch-up towards the goal
    # behind the leader) is at most accel_max: the cost alone never buys emergency acceleration
    assert over.any()
    assert not over[N // 2:].any(), np.argwhere(over)


@pytest.mark.parametrize("gap_m", [15.0, 20.0])   # 15 m: it rides the c_min contour behind the leader
def test_that_a_replan_that_never_needs_slack_is_the_same_with_or_without_an_emergency_bound(gap_m):
    # (a cold replan whose first linearisation, the straight line through the leader, needs
    # slack within accel_max may use the bound in that iteration and end a little elsewhere)
    req = _closing_request(gap_m=gap_m)
    plain = Planner(_config()).solve(req)
    assert plain.status == "optimal"
    with_bound = Planner(_config(accel_emergency_mps2=EMERGENCY)).solve(req)
    np.testing.assert_array_equal(with_bound.velocities, plain.velocities)
    np.testing.assert_array_equal(with_bound.commands, plain.commands)
    assert with_bound.notes == plain.notes


def test_that_an_emergency_bound_below_accel_max_is_refused_naming_the_key():
    with pytest.raises(ConfigError, match="accel_emergency_mps2"):
        _config(accel_emergency_mps2=(0.4, 2.0, 1.0))
    with pytest.raises(ConfigError, match="accel_emergency_mps2"):
        PlannerConfig.from_toml_table({"accel_emergency_mps2": [2.0, -1.0, 1.0]}, "x.toml [planner]")
    assert PlannerConfig.from_toml_table({"accel_emergency_mps2": 2.0}).accel_emergency_mps2 == (2.0, 2.0, 2.0)


def test_that_a_response_model_has_no_acceleration_rows_to_widen():
    response = {"horizontal": {"p_gain_per_s": 1.8, "i_gain_per_s2": 0.4, "drag_per_s": 0.1, "accel_lag_s": 0.1},
                "vertical": {"p_gain_per_s": 4.0, "i_gain_per_s2": 2.0, "drag_per_s": 0.1, "accel_lag_s": 0.1}}
    req = _closing_request(gap_m=2.6)
    plain = Planner(_config(vehicle_response=response)).solve(req)
    with_bound = Planner(_config(vehicle_response=response, accel_emergency_mps2=EMERGENCY)).solve(req)
    np.testing.assert_array_equal(with_bound.velocities, plain.velocities)
    assert plain.status == with_bound.status


def test_that_once_a_replan_needed_the_bound_its_later_steps_start_there(monkeypatch):
    from companion.core.planner import scp

    solve_qp, calls = scp.solve_qp, []

    def recording(*args, emergency_first=False, **kwargs):
        step = solve_qp(*args, emergency_first=emergency_first, **kwargs)
        calls.append((emergency_first, step is not None and step.emergency))
        return step

    monkeypatch.setattr(scp, "solve_qp", recording)
    cfg = _config(accel_emergency_mps2=EMERGENCY)
    req = _closing_request(gap_m=2.6)
    plan = Planner(cfg).solve(req)
    assert calls[0] == (False, True)                                      # the first step needed the bound ...
    assert all(first for first, _ in calls[1:]) and len(calls) >= 2      # ... so the later ones start there
    assert plan.status == "optimal" and plan.work < cfg.replan_work_budget
    # starting every step within accel_max instead, the least-slack QP runs to its cap each
    # time and the replan runs out of budget
    monkeypatch.setattr(scp, "solve_qp", lambda *a, emergency_first=False, **k: solve_qp(*a, emergency_first=False, **k))
    again = Planner(cfg).solve(req)
    assert again.work == cfg.replan_work_budget
