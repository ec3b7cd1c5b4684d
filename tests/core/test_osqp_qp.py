"""The planner's OSQP adapter: per-QP calls straight to osqp's extension give the wrapper's bits."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from companion.core.planner import Planner, osqp_qp
from tests.core.test_planner_scp import _unavoidable_request, scenario_one


def _fly(cfg, requests) -> list:
    """A cold plan of each request, then two warm-started replans of it, on one planner."""
    planner, plans = Planner(cfg), []
    for req in requests:
        warm = None
        for _ in range(3):
            warm = planner.solve(req, warm_start=warm)
            plans.append(warm)
    return plans


def test_that_the_installed_osqp_takes_the_direct_calls():
    """An osqp upgrade that moves its extension's solver fails here, instead of replanning slower unnoticed."""
    cfg, req = scenario_one()
    seen = []
    real = osqp_qp._extension_solver

    def spy(wrapper):
        seen.append(real(wrapper))
        return seen[-1]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(osqp_qp, "_extension_solver", spy)
        Planner(cfg).solve(req)
    assert seen and all(ext is not None for ext in seen)


@pytest.mark.parametrize("formulation", ["hyperplane", "paper"])
def test_that_plans_are_the_same_bits_through_the_extension_and_through_osqps_wrapper(formulation):
    """Hard QPs, warm starts, rho restored after adaptation, and the least-violation QPs (new ``P``,
    then the cost back) of an obstacle that cannot be avoided: every plan field the same bytes."""
    cfg, req = scenario_one(formulation)
    cfg = dataclasses.replace(cfg, replan_work_budget=10**6)
    requests = [req, _unavoidable_request()]
    direct = _fly(cfg, requests)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(osqp_qp, "_extension_solver", lambda wrapper: None)
        wrapped = _fly(cfg, requests)
    assert any(p.status == "slack" for p in direct)          # the least-violation QPs ran
    for a, b in zip(direct, wrapped, strict=True):
        assert (a.status, a.iterations, a.admm_iterations, a.notes) == (b.status, b.iterations, b.admm_iterations, b.notes)
        for field in ("velocities", "positions", "commands", "eta", "contour_of_touch", "slack_max"):
            assert np.asarray(getattr(a, field)).tobytes() == np.asarray(getattr(b, field)).tobytes(), field


@pytest.mark.parametrize("direct", [True, False])
def test_that_a_solution_is_the_callers_own(direct):
    """A solution's ``x`` and ``y`` are the caller's own: writing into them leaves the solver's next
    answer alone, and later solves leave them alone (the extension hands back new arrays)."""
    cfg, req = scenario_one()
    with pytest.MonkeyPatch.context() as mp:
        if not direct:
            mp.setattr(osqp_qp, "_extension_solver", lambda wrapper: None)
        planner = Planner(cfg)
        planner.solve(req)
        qp = planner.solver((req.horizon_steps, req.num_obstacles, req.num_walls))
        first = qp.solve()
        kept_x, kept_y = first.x.copy(), first.y.copy()
        first.x[:], first.y[:] = np.nan, np.nan            # the caller may write into them
        again = qp.solve()
        assert np.isfinite(again.x).all() and np.isfinite(again.y).all()
        first.x[:], first.y[:] = kept_x, kept_y
        qp.warm_start(x=np.zeros_like(kept_x), y=np.zeros_like(kept_y))
        qp.solve(max_iter=1)
        np.testing.assert_array_equal(first.x, kept_x)
        np.testing.assert_array_equal(first.y, kept_y)
        assert not np.shares_memory(first.x, again.x) and not np.shares_memory(first.y, again.y)


def test_that_the_compiled_p_product_gives_scipys_bits():
    """``OsqpQp.p_times`` (the objective's ``P x``, compiled) against scipy's CSR product, before and
    after new ``P`` data, on vectors with signed zeros and entries over twelve decades."""
    cfg, req = scenario_one()
    planner = Planner(cfg)
    planner.solve(req)
    qp = next(iter(planner.workspaces.values())).qp
    rng = np.random.default_rng(4)
    for update in range(2):
        for _ in range(200):
            x = rng.normal(size=qp.hessian.matrix.shape[0]) * 10.0 ** rng.uniform(-6.0, 6.0, qp.hessian.matrix.shape[0])
            x[rng.random(x.size) < 0.2] = rng.choice([0.0, -0.0])
            assert qp.p_times(x).tobytes() == (qp.hessian.matrix @ x).tobytes()
        before = qp.hessian.matrix.data.copy()
        layout = next(iter(planner.workspaces.values())).layout
        qp.update(p_data=layout.p_data(rng.uniform(1.0, 9.0), rng.uniform(0.1, 2.0), np.diag(rng.uniform(1.0, 5.0, 3))))
        assert not np.array_equal(qp.hessian.matrix.data, before)
