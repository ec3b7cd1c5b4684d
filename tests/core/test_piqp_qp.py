"""The PIQP backend (``[planner] solver = "piqp"``): the same QPs as OSQP, its duals, its splits, its work."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from companion.core.planner import Planner, budget, piqp_qp, qp_record
from companion.core.planner.piqp_qp import PiqpQp
from companion.errors import InputError
from tests.core.test_planner_scp import GOAL, _unavoidable_request, exact_contour, scenario_one

ROOT = Path(__file__).resolve().parents[2]


def _shape(req) -> tuple[int, int, int]:
    return req.horizon_steps, req.num_obstacles, req.num_walls


def _qp_data(planner: Planner, req):
    """The hard QP of the planner's last solve of ``req``'s shape, as its OSQP solver holds it."""
    qp = planner.solver(_shape(req))
    return qp, planner.layout(_shape(req))


def test_that_scenario_one_flies_the_same_plan_with_piqp_as_with_osqp():
    """The head-on scenario: optimal, the goal reached, the 60 % contours apart, the cost within 1e-3 of
    OSQP's at the planner's tolerances, and (both solved tightly) the same plan within 5 cm."""
    cfg, req = scenario_one()
    osqp_plan = Planner(cfg).solve(req)
    planner = Planner(dataclasses.replace(cfg, solver="piqp"))
    plan = planner.solve(req)
    assert isinstance(planner.solver(_shape(req)), PiqpQp)
    assert plan.status == "optimal", plan.notes
    assert np.linalg.norm(plan.positions[-1] - GOAL) <= 0.1
    assert exact_contour(req, plan, cfg.drone_radius_m).min() >= cfg.c_min
    assert plan.cost == pytest.approx(osqp_plan.cost, rel=1e-3)
    warm = planner.solve(req, warm_start=plan)          # a warm start is taken (and ignored by PIQP)
    assert warm.status == "optimal" and warm.cost == pytest.approx(plan.cost, rel=1e-3)
    tight, _ = scenario_one(solver_eps=1e-7, solver_eps_rel=1e-7, scp_tolerance=1e-8, scp_max_iterations=40)
    a, b = Planner(tight).solve(req), Planner(dataclasses.replace(tight, solver="piqp")).solve(req)
    assert np.abs(a.positions - b.positions).max() < 0.05
    assert b.cost == pytest.approx(a.cost, rel=5e-4)


def test_that_a_piqp_solution_meets_the_kkt_conditions_in_osqps_sign_convention():
    """``P x + q + A'y = 0`` with ``y`` assembled from PIQP's equality and bound duals (``y > 0`` where the
    upper bound binds, as OSQP's), and ``l <= A x <= u`` to the tolerance."""
    cfg, req = scenario_one(solver_eps=1e-7, solver_eps_rel=1e-7)
    planner = Planner(dataclasses.replace(cfg, solver="piqp"))
    planner.solve(req)
    qp = planner.solver(_shape(req))
    layout = qp.layout
    sol = qp.solve()
    assert sol.accurate and sol.usable and sol.status == "solved"
    a = layout.a_matrix_csc(qp._a_data)
    residual = qp.p_times(sol.x) + qp._q + a.T @ sol.y
    assert np.abs(residual).max() < 1e-5
    ax = a @ sol.x
    assert np.all(ax >= qp._l - 1e-5) and np.all(ax <= qp._u + 1e-5)
    ineq = qp._l < qp._u
    pushing_up, pushing_down = ineq & (sol.y > 1e-4), ineq & (sol.y < -1e-4)
    assert pushing_up.any() or pushing_down.any()
    assert np.all(np.abs(ax - qp._u)[pushing_up] < 1e-4)       # a positive dual only on an upper bound
    assert np.all(np.abs(ax - qp._l)[pushing_down] < 1e-4)
    assert sol.objective == pytest.approx(0.5 * sol.x @ qp.p_times(sol.x) + qp._q @ sol.x)


def test_that_a_solution_is_the_callers_own():
    """PIQP overwrites its result at the next solve: the backend hands back copies."""
    cfg, req = scenario_one(solver="piqp")
    planner = Planner(cfg)
    planner.solve(req)
    qp = planner.solver(_shape(req))
    first = qp.solve()
    kept = first.x.copy()
    qp.update(q=np.zeros(qp.layout.n))
    qp.solve()
    np.testing.assert_array_equal(first.x, kept)


def test_that_an_unavoidable_obstacle_gives_a_slack_plan_through_the_least_violation_qps():
    """The hard QP is infeasible, PIQP says so, and the least-violation QPs (new equality rows: a new split)
    give the slack plan, never 'optimal'; each split is set up once and then updated in place."""
    cfg, _ = scenario_one(solver="piqp", replan_work_budget=10**6)
    req = _unavoidable_request()
    planner = Planner(cfg)
    plan = planner.solve(req)
    assert plan.status == "slack" and plan.slack_max > 0.1, plan.notes
    assert plan.contour_of_touch[0, 0] < 0.6 and np.all(np.isfinite(plan.velocities))
    qp = planner.solver(_shape(req))
    setups = qp.setups
    assert 2 <= setups <= piqp_qp.MAX_SPLITS           # the hard split and the least-violation ones
    again = planner.solve(req)
    assert qp.setups == setups                          # the same splits came back: updated, not set up
    assert again.velocities.tobytes() == plan.velocities.tobytes()


def test_that_splits_beyond_the_bound_evict_the_oldest():
    cfg, req = scenario_one(solver="piqp")
    planner = Planner(cfg)
    planner.solve(req)
    qp = planner.solver(_shape(req))
    l0, u0 = qp._l.copy(), qp._u.copy()
    ineq = np.flatnonzero(np.isfinite(l0) & np.isfinite(u0) & (l0 < u0))
    for k in range(piqp_qp.MAX_SPLITS + 3):             # pin one more row each time: a new split each
        l, u = l0.copy(), u0.copy()
        l[ineq[k]] = u[ineq[k]] = 0.5 * (l0[ineq[k]] + u0[ineq[k]])
        qp.update(l=l, u=u)
        qp.solve()
    assert len(qp._splits) == piqp_qp.MAX_SPLITS


def test_that_the_budget_charges_a_piqp_iteration_its_work_units():
    """``work`` is the QP charges plus PIQP's iterations at ``WORK_PER_ITERATION`` each, and a budget
    with room for two iterations gives PIQP two, then marks itself exhausted."""
    cfg, req = scenario_one(solver="piqp")
    plan = Planner(cfg).solve(req)
    unit = piqp_qp.WORK_PER_ITERATION
    qps = (plan.work - unit * plan.admm_iterations) / budget.QP_SOLVE_WORK
    assert qps == int(qps) and qps >= plan.iterations
    assert 0 < plan.admm_iterations < 200                # interior-point iterations, not ADMM's
    planner = Planner(cfg)
    planner.solve(req)
    work = budget.WorkBudget(budget.QP_SOLVE_WORK + budget.MIN_QP_ITERATIONS)   # room for 2 iterations
    sol = work.solve(planner.solver(_shape(req)), cfg.solver_max_iter)
    assert sol.iterations == budget.MIN_QP_ITERATIONS // unit and not sol.accurate
    assert work.exhausted and work.used == budget.QP_SOLVE_WORK + unit * sol.iterations
    assert work.solve(planner.solver(_shape(req)), cfg.solver_max_iter) is None


def test_that_the_qp_recorder_refuses_a_piqp_planner():
    cfg, req = scenario_one(solver="piqp")
    with qp_record.recording(qp_record.QpRecorder()):
        with pytest.raises(InputError, match="records OSQP's solves; \\[planner\\] solver is 'piqp'"):
            Planner(cfg).solve(req)


def test_that_a_lockstep_corridor_flight_with_piqp_reaches_the_goal_without_a_collision(monkeypatch):
    """configs/corridor.toml (``c_max``, walls, the least-violation path) with ``[planner] solver = "piqp"``,
    twice: the goal, no collision, no replan cut short by the budget, and the same commands both times."""
    from companion.core.planner import scp
    from companion.offline.harness import run_lockstep

    notes, solve = [], scp.Planner.solve

    def noting(self, request, warm_start=None):
        plan = solve(self, request, warm_start)
        notes.extend(plan.notes)
        return plan

    monkeypatch.setattr(scp.Planner, "solve", noting)
    runs = [run_lockstep(ROOT / "configs" / "corridor.toml", seed=0, solver="piqp") for _ in range(2)]
    summary = runs[0].summary()
    assert summary["goal_reached"] and not summary["collisions"], summary
    assert summary["replans"] > 50 and summary["failed_plans"] == 0
    assert not [n for n in notes if n.startswith("work_budget")]
    commands = [[r.command.tobytes() for r in run.companion.records] for run in runs]
    assert commands[0] == commands[1]
