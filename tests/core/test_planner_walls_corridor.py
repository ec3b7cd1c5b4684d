"""Walls (exact Gaussian half-space chance constraint) and the c_max corridor bound."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from companion.core import overlap
from companion.core.planner import Planner, PlannerConfig, PlanRequest

N, TAU = 20, 0.5
START = np.array([0.0, 0.0, -5.0])
S_D = np.array([[0.02, 0.01, 0.0], [0.01, 0.04, 0.0], [0.0, 0.0, 0.02]])


def _config(**kw) -> PlannerConfig:
    base = dict(horizon_steps=N, step_s=TAU, c_min=0.9, velocity_max_mps=(3.0, 3.0, 1.0), accel_max_mps2=(2.0, 2.0, 1.0),
                drone_radius_m=0.3, sensing_range_m=10.0)
    base.update(kw)
    return PlannerConfig(**base)


@pytest.mark.parametrize("formulation", ["hyperplane", "paper", "bhattacharyya"])
def test_that_walls_hold_with_the_exact_chance_constraint(formulation):
    cfg = _config(formulation=formulation)
    # free space: y <= 1.5 and 0.6 x + 0.8 y... a tilted second wall the target lies beyond
    normals = np.array([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    offsets = np.array([1.5, 6.0])
    covs = np.stack([S_D * (1.0 + 0.1 * i) for i in range(N)])          # growing uncertainty
    req = PlanRequest(position=START, velocity=np.zeros(3), drone_covs=covs, target=np.array([9.0, 4.0, -5.0]),
                      walls_normal=normals, walls_offset=offsets)
    plan = Planner(cfg).solve(req)
    assert plan.status == "optimal", plan.notes
    r_min = overlap.touch_radius(cfg.c_min, 3)
    sigma = np.sqrt(np.einsum("wk,nkl,wl->wn", normals, covs, normals))
    mean_gap = offsets[:, None] - normals @ plan.positions.T - cfg.drone_radius_m     # b - a.p - R
    # a.p + r_min sqrt(a'Sa) + R <= b  at every step (solver tolerance aside)
    assert np.all(mean_gap - r_min * sigma >= -1e-5)
    # the probability that the drone's body crosses the wall is at most Phi(-r_min)
    p_cross = stats.norm.sf(mean_gap / sigma)
    assert p_cross.max() <= stats.norm.sf(r_min) * (1 + 1e-3)
    # the walls matter: the plan presses against one of them
    assert np.min(mean_gap - r_min * sigma) <= 1e-2
    np.testing.assert_allclose(plan.wall_margin, mean_gap - r_min * sigma, atol=1e-9)


def test_that_the_deterministic_baseline_keeps_only_the_body_off_the_wall():
    cfg = _config(formulation="deterministic")
    req = PlanRequest(position=START, velocity=np.zeros(3), drone_covs=np.broadcast_to(S_D, (N, 3, 3)),
                      target=np.array([6.0, 4.0, -5.0]), walls_normal=[[0.0, 1.0, 0.0]], walls_offset=[1.5])
    plan = Planner(cfg).solve(req)
    assert plan.status == "optimal"
    assert np.max(plan.positions[:, 1]) == pytest.approx(1.5 - 0.3, abs=5e-3)     # back-off 3 mm


def _escort(c_max: float | None, formulation: str) -> tuple[PlanRequest, object, PlannerConfig]:
    """An obstacle flying alongside and drifting away; the drone is asked to keep up (corridor case)."""
    cfg = _config(formulation=formulation, c_min=0.3, c_max=c_max, drone_radius_m=0.2, accel_max_mps2=(1.0, 1.0, 1.0))
    t = np.arange(1, N + 1)[:, None] * TAU
    s_o = np.array([[0.03, 0.02, 0.0], [0.02, 0.03, 0.0], [0.0, 0.0, 0.02]])
    means = (np.array([0.0, 0.85, -5.0]) + t * np.array([1.2, 0.1, 0.0]))[None]
    req = PlanRequest(position=START, velocity=np.array([1.2, 0.0, 0.0]), drone_covs=np.broadcast_to(S_D, (N, 3, 3)),
                      target=np.array([12.0, 0.3, -5.0]), obstacle_means=means,
                      obstacle_covs=np.broadcast_to(s_o, (1, N, 3, 3)), obstacle_radii=[0.2])
    return req, Planner(cfg).solve(req), cfg


@pytest.mark.parametrize("formulation", ["hyperplane", "paper"])
def test_that_with_c_max_the_contours_keep_touching(formulation):
    req, free, _ = _escort(None, formulation)
    assert free.status == "optimal"
    assert free.contour_of_touch.max() > 0.9          # left alone, the drone lets the obstacle drift off
    req, plan, cfg = _escort(0.6, formulation)
    assert plan.status == "optimal", plan.notes
    assert not any(n.startswith("c_max") for n in plan.notes)
    c = overlap.contour_of_touch(plan.positions[None], req.drone_covs[None], req.obstacle_means, req.obstacle_covs,
                                 req.obstacle_radii[:, None] + cfg.drone_radius_m)
    assert c.min() >= 0.3 - 1e-3
    assert c.max() <= 0.6 + 2e-3                     # the 60 % contours touch at every step


def test_that_an_infeasible_c_max_is_reported_in_the_notes():
    cfg = _config(c_min=0.3, c_max=0.6, drone_radius_m=0.2, accel_max_mps2=(0.2, 0.2, 0.2))
    t = np.arange(1, N + 1)[:, None] * TAU
    means = (np.array([0.0, 3.0, -5.0]) + t * np.array([0.0, 1.0, 0.0]))[None]    # runs away fast
    req = PlanRequest(position=START, velocity=np.zeros(3), drone_covs=np.broadcast_to(S_D, (N, 3, 3)),
                      target=np.array([3.0, 0.0, -5.0]), obstacle_means=means,
                      obstacle_covs=np.broadcast_to(S_D, (1, N, 3, 3)), obstacle_radii=[0.2])
    plan = Planner(cfg).solve(req)
    assert any(n.startswith("c_max_violated") for n in plan.notes)
    assert plan.status == "optimal"                   # c_max is not a safety bound: no safety slack used


def test_that_c_max_is_released_for_obstacles_outside_the_upper_bound_mask():
    req, bound, cfg = _escort(0.6, "hyperplane")
    free = Planner(cfg).solve(dataclasses.replace(req, upper_bound_mask=np.array([False])))
    assert free.status == "optimal"
    assert free.contour_of_touch.max() > 0.9     # as without c_max: the obstacle is let go
    assert bound.contour_of_touch.max() <= 0.6 + 2e-3


def test_that_a_malformed_upper_bound_mask_is_refused():
    req, _, _ = _escort(0.6, "hyperplane")
    with pytest.raises(ValueError, match="upper_bound_mask"):
        dataclasses.replace(req, upper_bound_mask=np.array([1, 0]))
