"""The planner end to end: scenario 1 of the paper, bounds, sensing range, status, warm start.

Safety figures are recomputed here with the overlap module on the returned positions
(never taken from the plan or the linearisation).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core import overlap
from companion.errors import InputError
from companion.core.planner import Plan, Planner, PlannerConfig, PlanRequest
from companion.core.planner.formulations import _same_values

S = 0.02 * np.eye(3)
START = np.array([0.0, 0.0, -5.0])
GOAL = np.array([10.0, 0.0, -5.0])


def scenario_one(formulation: str = "hyperplane", **overrides) -> tuple[PlannerConfig, PlanRequest]:
    """docs/METHOD.md section 4, scenario 1 (as in configs/single_obstacle.toml): head-on, 0.5 m radii."""
    n = 20
    kwargs = dict(formulation=formulation, horizon_steps=n, step_s=1.0, c_min=0.6, velocity_max_mps=(3.0, 3.0, 1.0),
                  accel_max_mps2=(0.5, 0.5, 0.5), drone_radius_m=0.5, sensing_range_m=20.0)
    kwargs.update(overrides)
    cfg = PlannerConfig(**kwargs)
    t = np.arange(1, n + 1)[:, None]
    means = np.array([10.0, 0.0, -5.0]) + t * np.array([-0.5, 0.0, 0.0])
    req = PlanRequest(position=START, velocity=np.zeros(3), drone_covs=np.broadcast_to(S, (n, 3, 3)), target=GOAL,
                      obstacle_means=means[None], obstacle_covs=np.broadcast_to(S, (1, n, 3, 3)), obstacle_radii=[0.5])
    return cfg, req


def exact_contour(req: PlanRequest, plan: Plan, drone_radius: float) -> np.ndarray:
    return overlap.contour_of_touch(plan.positions[None], req.drone_covs[None], req.obstacle_means,
                                    req.obstacle_covs, req.obstacle_radii[:, None] + drone_radius)


@pytest.mark.parametrize("formulation", ["hyperplane", "paper"])
def test_that_scenario_one_reaches_the_goal_with_the_60_percent_contours_apart(formulation):
    cfg, req = scenario_one(formulation)
    plan = Planner(cfg).solve(req)
    assert plan.status == "optimal", plan.notes
    assert np.linalg.norm(plan.positions[-1] - GOAL) <= 0.1
    contour = exact_contour(req, plan, cfg.drone_radius_m)
    assert contour.min() >= 0.599
    np.testing.assert_allclose(plan.contour_of_touch, contour, atol=1e-9)
    # the constraint is active: the plan does not detour more than needed
    assert contour.min() <= 0.65
    assert plan.slack_max <= 1e-4


@pytest.mark.parametrize("formulation", ["deterministic", "bhattacharyya"])
def test_that_baselines_solve_scenario_one_under_their_own_constraint(formulation):
    cfg, req = scenario_one(formulation)
    plan = Planner(cfg).solve(req)
    assert plan.status == "optimal", plan.notes
    assert np.linalg.norm(plan.positions[-1] - GOAL) <= 0.1
    gap = np.linalg.norm(req.obstacle_means[0] - plan.positions, axis=1) - 1.0
    assert gap.min() >= -1e-3                      # bodies never touch
    if formulation == "deterministic":
        assert exact_contour(req, plan, 0.5).min() < 0.1   # means only: the contours interpenetrate


def test_that_without_obstacles_the_plan_goes_straight_to_the_goal_within_bounds():
    cfg = PlannerConfig(horizon_steps=20, step_s=0.5, c_min=0.9, velocity_max_mps=(2.0, 2.0, 1.0),
                        accel_max_mps2=(1.0, 1.0, 0.5))
    target = np.array([8.0, -4.0, -6.0])
    req = PlanRequest(position=START, velocity=np.array([0.5, 0.0, 0.0]), drone_covs=np.broadcast_to(S, (20, 3, 3)),
                      target=target)
    plan = Planner(cfg).solve(req)
    assert plan.status == "optimal"
    assert np.linalg.norm(plan.positions[-1] - target) <= 0.05
    tol = 1e-4
    assert np.all(np.abs(plan.velocities) <= cfg.velocity_max + tol)
    accel = np.diff(np.vstack([req.velocity, plan.velocities]), axis=0) / cfg.step_s
    assert np.all(np.abs(accel) <= cfg.accel_max + tol)
    # holonomic model: p_i = p_{i-1} + tau V_i
    np.testing.assert_allclose(plan.positions, START + cfg.step_s * np.cumsum(plan.velocities, axis=0), atol=1e-6)
    # straight: every position lies close to the segment start -> target (the initial
    # velocity bends the first steps a little)
    u = (target - START) / np.linalg.norm(target - START)
    rel = plan.positions - START
    off_line = np.linalg.norm(rel - np.outer(rel @ u, u), axis=1)
    assert off_line.max() <= 0.5
    assert plan.eta.shape == (0, 20) and plan.wall_margin.shape == (0, 20)


def _unavoidable_request(n: int = 20) -> PlanRequest:
    """An obstacle 0.3 m ahead of the drone that follows it: no plan keeps the contours apart."""
    means = np.broadcast_to(START + np.array([0.3, 0.0, 0.0]), (1, n, 3))
    return PlanRequest(position=START, velocity=np.zeros(3), drone_covs=np.broadcast_to(S, (n, 3, 3)), target=GOAL,
                       obstacle_means=means, obstacle_covs=np.broadcast_to(S, (1, n, 3, 3)), obstacle_radii=[0.5])


def test_that_an_unavoidable_obstacle_is_never_reported_optimal():
    # an obstacle sits on the drone and follows it: no plan keeps 60 % contours apart
    cfg, _ = scenario_one()
    req = _unavoidable_request()
    plan = Planner(dataclasses.replace(cfg, replan_work_budget=10**6)).solve(req)   # budget not binding
    assert plan.status in ("slack", "failed")
    assert plan.status == "slack" and plan.slack_max > 0.1
    assert plan.contour_of_touch[0, 0] < 0.6
    assert np.all(np.isfinite(plan.velocities))
    assert plan.work > 8000                        # this least-violation path needs more than 8000 units


def test_that_a_replan_out_of_budget_fails_without_a_safe_iterate_and_flies_a_completed_least_violation():
    cfg, _ = scenario_one()
    req = _unavoidable_request()
    for budget in (200, 1000):                          # not even the hard QP completes
        plan = Planner(dataclasses.replace(cfg, replan_work_budget=budget)).solve(req)
        assert plan.work <= budget
        assert plan.status == "failed"                  # no safe iterate exists here: the loop brakes
        assert any(n.startswith("work_budget") for n in plan.notes)
    plan = Planner(dataclasses.replace(cfg, replan_work_budget=8000)).solve(req)   # one least-violation iteration fits
    assert plan.work <= 8000
    assert any(n.startswith("work_budget") for n in plan.notes)
    assert plan.status == "slack" and plan.slack_max > 0.1


def test_that_a_tight_budget_still_returns_a_safe_plan_when_the_start_is_safe():
    cfg, req = scenario_one()
    planner = Planner(cfg)
    first = planner.solve(req)
    assert first.status == "optimal" and first.work <= cfg.replan_work_budget and first.admm_iterations > 0
    tight = Planner(dataclasses.replace(cfg, replan_work_budget=200))
    tight.solve(req)
    again = tight.solve(req, warm_start=first)          # 200 units: not even one QP fits
    assert again.work <= 200
    assert again.status == "optimal"                    # the shifted previous plan, rechecked exactly
    assert np.all(again.contour_of_touch[again.in_range] >= cfg.c_min - 1e-3)


def test_that_obstacles_beyond_sensing_range_are_ignored():
    cfg, req = scenario_one(sensing_range_m=5.0)          # obstacle starts 9.5 m away
    plan = Planner(cfg).solve(req)
    assert not plan.in_range[0]
    assert plan.status == "optimal"
    assert np.abs(plan.positions[:, 1]).max() < 0.1       # flies through as if it were not there
    assert plan.min_contour_of_touch == 1.0               # only in-range obstacles count


def test_that_an_obstacle_s_own_range_overrides_the_sensing_range():
    """Per obstacle: the request's range decides, both ways (a report from far out is planned
    around beyond the sensing range; a short range leaves it out within it)."""
    cfg, req = scenario_one(sensing_range_m=5.0)           # obstacle starts 9.5 m away
    far = Planner(cfg).solve(dataclasses.replace(req, obstacle_ranges_m=[20.0]))
    assert far.in_range[0] and far.status == "optimal"
    assert np.abs(far.positions[:, 1:]).max() > 0.3        # goes round it
    assert far.min_contour_of_touch >= cfg.c_min - 1e-3
    cfg, req = scenario_one()                              # sensing range 20 m
    near = Planner(cfg).solve(dataclasses.replace(req, obstacle_ranges_m=[np.float64(5.0)]))
    assert not near.in_range[0] and np.abs(near.positions[:, 1]).max() < 0.1


@pytest.mark.parametrize("ranges", [[0.0], [-1.0], [np.nan], [5.0, 6.0], "far"])
def test_that_bad_obstacle_ranges_are_rejected(ranges):
    _, req = scenario_one()
    with pytest.raises(InputError, match="obstacle_ranges_m"):
        dataclasses.replace(req, obstacle_ranges_m=ranges)


def test_that_a_warm_started_replan_reuses_the_solver_and_agrees():
    cfg, req = scenario_one()
    planner = Planner(cfg)
    first = planner.solve(req)
    qp = planner.solver((20, 1, 0))
    again = planner.solve(req, warm_start=first)
    assert qp is not None and planner.solver((20, 1, 0)) is qp   # set up once per shape, updated in place
    assert again.status == "optimal"
    assert np.linalg.norm(again.positions[-1] - GOAL) <= 0.1


def test_that_a_request_of_the_wrong_horizon_is_rejected():
    cfg, _ = scenario_one()
    req = PlanRequest(position=START, velocity=np.zeros(3), drone_covs=np.broadcast_to(S, (5, 3, 3)), target=GOAL)
    with pytest.raises(InputError, match="request has 5 steps, the planner is configured for horizon_steps = 20"):
        Planner(cfg).solve(req)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("position", [0.0, 0.0], r"position has shape \(2,\), expected \(3\)"),
        ("target", [0.0, np.nan, 0.0], "target contains NaN"),
        ("drone_covs", np.broadcast_to(-S, (4, 3, 3)), "drone_covs.* not positive definite"),
    ],
)
def test_that_bad_requests_get_clear_errors(field, value, match):
    kwargs = dict(position=START, velocity=np.zeros(3), drone_covs=np.broadcast_to(S, (4, 3, 3)), target=GOAL)
    kwargs[field] = value
    with pytest.raises(InputError, match=match):
        PlanRequest(**kwargs)


def test_that_the_plan_solve_time_is_a_diagnostic_only():
    cfg, req = scenario_one()
    a, b = Planner(cfg).solve(req), Planner(cfg).solve(req)
    np.testing.assert_array_equal(a.velocities, b.velocities)   # deterministic, whatever the clock says
    assert a.solve_time_s > 0.0


@pytest.mark.parametrize("formulation", ["hyperplane", "paper"])
def test_that_a_cold_plan_does_not_depend_on_what_the_planner_solved_before(formulation):
    """A plan without warm start is a function of its request: OSQP's duals restart at zero and
    its step size ``rho`` at ``solver_rho``, whatever the previous solves left behind."""
    cfg, req = scenario_one(formulation)
    fresh = Planner(cfg).solve(req)
    used = Planner(cfg)
    _, other = scenario_one(formulation)
    other = PlanRequest(position=START + np.array([0.0, 1.5, 0.5]), velocity=np.array([1.0, -0.5, 0.0]),
                        drone_covs=other.drone_covs, target=GOAL + np.array([0.0, -3.0, 0.0]),
                        obstacle_means=other.obstacle_means + np.array([0.0, 0.3, 0.0]),
                        obstacle_covs=other.obstacle_covs, obstacle_radii=other.obstacle_radii)
    previous = used.solve(other)
    used.solve(other, warm_start=previous)
    again = used.solve(req)
    np.testing.assert_array_equal(again.velocities, fresh.velocities)
    assert again.iterations == fresh.iterations


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_caches_compare_positions_as_array_equal_does(seed):
    """The separator and recheck caches' test of kept positions: np.array_equal's answer, for equal
    arrays, a change anywhere (the last entry or another), signed zeros, NaN and other shapes."""
    rng = np.random.default_rng(seed)
    kept = rng.normal(size=(int(rng.integers(1, 6)), 3))
    other = kept.copy()
    kind = int(rng.integers(6))
    if kind == 1:
        other[-1, -1] += 1.0
    elif kind == 2:
        other[int(rng.integers(len(other))), int(rng.integers(3))] = rng.normal()
    elif kind == 3:
        kept[-1, -1], other[-1, -1] = 0.0, -0.0          # equal values
    elif kind == 4:
        kept[0, 0] = other[0, 0] = np.nan                  # array_equal: NaN is unequal
    elif kind == 5:
        other = rng.normal(size=(len(kept) + 1, 3))
    assert _same_values(kept, other) == np.array_equal(kept, other)


def _rejecting_the_planners_iterates(monkeypatch, planner: Planner, which: str) -> list:
    """Make ``planner``'s exact recheck reject QP solutions (``which``: ``"last"``, the latest
    only, or ``"all"``); returns the list the SCP's QP steps are collected in."""
    from companion.core.planner import scp

    steps = []
    solve_qp = scp.solve_qp

    def collecting(*args, **kwargs):
        step = solve_qp(*args, **kwargs)
        steps.append(step)
        return step

    recheck = planner.formulation.recheck

    def rejecting(request, positions, in_range):
        figs, ok = recheck(request, positions, in_range)
        rejected = steps[-1:] if which == "last" else steps
        return figs, ok and not any(np.array_equal(positions, s.positions) for s in rejected)

    monkeypatch.setattr(scp, "solve_qp", collecting)
    monkeypatch.setattr(planner.formulation, "recheck", rejecting)
    return steps


def test_that_an_unsafe_last_iterate_gives_way_to_the_cheapest_safe_earlier_one(monkeypatch):
    cfg, req = scenario_one(scp_max_iterations=6)
    planner = Planner(cfg)
    steps = _rejecting_the_planners_iterates(monkeypatch, planner, "last")
    plan = planner.solve(req)
    assert len(steps) == 6                                   # never converged: the last was always rejected
    earlier = [s for s in steps[:-1] if s.safety_slack <= 1e-4]
    best = min(earlier, key=lambda s: s.objective)
    assert plan.status == "optimal"                          # instead of failed (and the loop braking)
    np.testing.assert_array_equal(plan.velocities, best.velocities)
    k = next(i for i, s in enumerate(steps, 1) if s is best)
    assert f"returned iterate {k} of 6 (safe; the last was not)" in plan.notes
    assert np.all(exact_contour(req, plan, 0.5)[plan.in_range] >= cfg.c_min - 1e-6)


def test_that_without_a_safe_iterate_the_shifted_previous_plan_is_flown_if_safe_else_the_plan_fails(monkeypatch):
    cfg, req = scenario_one(scp_max_iterations=4)
    previous = Planner(cfg).solve(req)
    # one step later: the drone where the plan put it, the obstacle one step on
    later = np.vstack([req.obstacle_means[0, 1:], 2 * req.obstacle_means[0, -1] - req.obstacle_means[0, -2]])
    req = dataclasses.replace(req, position=previous.positions[0], velocity=previous.velocities[0],
                              obstacle_means=later[None])
    planner = Planner(cfg)
    _rejecting_the_planners_iterates(monkeypatch, planner, "all")
    plan = planner.solve(req, warm_start=previous)
    assert plan.status == "optimal"
    assert "returned the SCP's starting iterate (safe)" in plan.notes   # not the budget's: it did not run out
    np.testing.assert_allclose(plan.velocities[:-1], previous.velocities[1:], atol=1e-12)
    cold = planner.solve(req)                                # a cold start (a line through the obstacle) is not safe
    assert cold.status == "failed"
    assert "exact recheck violated c_min without slack" in cold.notes
