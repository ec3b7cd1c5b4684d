"""One QP of the SCP against an independent cvxpy model of the same QP.

The cvxpy model is written from the problem statement (velocities as the only motion
variables, positions as cumulative sums, cost written out term by term) and solved by
Clarabel, an interior-point solver; the planner's QP uses positions as variables, a
hand-built sparse pattern and OSQP. For ``hyperplane`` the linearised rows are also
rebuilt here from :func:`companion.core.overlap.minmax`.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest

from companion.core import overlap
from companion.core.planner import Planner, PlannerConfig, PlanRequest
from companion.core.planner.formulations import BACKOFF_SIGMA, LAM_EPS
from companion.core.planner.qp_step import LEAST_VIOLATION_MARGIN

N = 12
TAU = 0.5


def _case(formulation: str, trust_region_mps: float = 1.5) -> tuple[PlannerConfig, PlanRequest, np.ndarray]:
    cfg = PlannerConfig(formulation=formulation, horizon_steps=N, step_s=TAU, c_min=0.9, c_max=0.99,
                        velocity_max_mps=(2.0, 2.0, 1.0), accel_max_mps2=(1.0, 1.0, 0.5), drone_radius_m=0.3,
                        sensing_range_m=15.0, weight_jerk=0.2, weight_velocity=0.05, weight_progress=0.4,
                        trust_region_mps=trust_region_mps,
                        solver_eps=1e-7, solver_eps_rel=1e-7,    # compare models, not tolerances
                        solver_max_iter=10000)
    t = np.arange(1, N + 1)[:, None] * TAU
    s_d = np.array([[0.03, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.02]])
    drone_covs = np.stack([s_d * (1.0 + 0.05 * i) for i in range(N)])
    means = np.stack([np.array([6.0, 0.4, -5.0]) + t * np.array([-1.0, 0.0, 0.0]),
                      np.array([3.0, -3.0, -5.2]) + t * np.array([0.0, 1.0, 0.0]),
                      np.array([40.0, 0.0, -5.0]) + 0.0 * t])          # out of sensing range
    s_o = np.array([[0.04, 0.0, 0.0], [0.0, 0.03, 0.01], [0.0, 0.01, 0.02]])
    covs = np.broadcast_to(s_o, (3, N, 3, 3))
    req = PlanRequest(position=np.array([0.0, 0.0, -5.0]), velocity=np.array([0.8, 0.1, 0.0]), drone_covs=drone_covs,
                      target=np.array([8.0, 0.5, -5.0]), obstacle_means=means, obstacle_covs=covs,
                      obstacle_radii=[0.4, 0.3, 0.5], walls_normal=[[0.0, 1.0, 0.0]], walls_offset=[1.2])
    # linearisation point: a constant velocity a little off the straight line
    v_bar = np.tile([0.7, 0.05, 0.0], (N, 1))
    return cfg, req, v_bar


def _cvxpy_qp(cfg: PlannerConfig, req: PlanRequest, v_bar: np.ndarray, rows, lam_bar=None, safety="hard"):
    """The QP written plainly: returns (objective, V, total safety slack).

    ``safety = "hard"``: the safety slacks are held at zero (the QP the planner solves
    first; only the ``c_max`` slack is free). ``"least"``: lexicographically, the least
    total safety slack, then the least cost with no more slack than that.
    """
    P = req.num_obstacles
    r_min = overlap.touch_radius(cfg.c_min, 3)
    in_range = np.linalg.norm(req.obstacle_means[:, 0] - req.position, axis=1) <= cfg.sensing_range_m
    V = cp.Variable((N, 3))
    s = cp.Variable((P, N), nonneg=True)
    s_hi = cp.Variable((P, N), nonneg=True)
    s_w = cp.Variable((req.num_walls, N), nonneg=True)
    p = [req.position + TAU * cp.sum(V[: i + 1], axis=0) for i in range(N)]
    vmax, amax = cfg.velocity_max, cfg.accel_max
    cons = [V <= np.minimum(vmax, v_bar + cfg.trust_region_mps), V >= np.maximum(-vmax, v_bar - cfg.trust_region_mps)]
    prev = req.velocity
    for i in range(N):
        cons += [cp.abs(V[i] - prev) <= amax * TAU]
        prev = V[i]
    lam = cp.Variable((P, N)) if lam_bar is not None else None
    e = cp.Variable((P, N)) if lam_bar is not None else None
    for j in range(P):
        if not in_range[j]:
            continue
        for i in range(N):
            expr = rows.coef_p[j, i] @ p[i] + s[j, i] - s_hi[j, i]
            if lam is not None:
                expr = expr + rows.coef_lam[j, i] * lam[j, i]
                cons += [rows.adm_p[j, i] @ p[i] + rows.adm_lam[j, i] * lam[j, i] + e[j, i] == rows.adm_rhs[j, i]]
            cons += [expr >= rows.lower[j, i], expr <= rows.upper[j, i]]
    if lam is not None:
        cons += [lam >= np.maximum(LAM_EPS, lam_bar - cfg.trust_region_lam),
                 lam <= np.minimum(1 - LAM_EPS, lam_bar + cfg.trust_region_lam)]
    for w in range(req.num_walls):
        a, b = req.walls_normal[w], req.walls_offset[w]
        for i in range(N):
            spread = np.sqrt(a @ req.drone_covs[i] @ a)
            cons += [a @ p[i] - s_w[w, i] <= b - (r_min + BACKOFF_SIGMA) * spread - cfg.drone_radius_m]
    m = np.linalg.inv(req.drone_covs[-1])
    vs = [req.velocity] + [V[i] for i in range(N)]
    jerk = sum(cp.sum_squares(vs[i + 1] - 2 * vs[i] + vs[i - 1]) for i in range(1, N)) / TAU**4
    progress = sum(cp.quad_form(p[i] - req.target, 0.5 * (m + m.T)) for i in range(N)) / N
    cost = (cfg.weight_terminal * cp.quad_form(p[-1] - req.target, 0.5 * (m + m.T)) + cfg.weight_jerk * jerk
            + cfg.weight_progress * progress
            + cfg.weight_velocity * cp.sum_squares(V)
            + cfg.slack_penalty * (cp.sum(s[in_range]) + cp.sum(s_w)) + cfg.c_max_penalty * cp.sum(s_hi[in_range]))
    if e is not None:
        cost = cost + cfg.slack_penalty * cp.sum(cp.abs(e[in_range]))
    total = cp.sum(s[in_range]) + cp.sum(s_w) + (cp.sum(cp.abs(e[in_range])) if e is not None else 0.0)
    if safety == "hard":
        cons += [total <= 0.0]
    elif safety == "least":
        least = cp.Problem(cp.Minimize(total), cons)
        least.solve(solver=cp.CLARABEL)
        assert least.status == "optimal" and least.value > 1e-3
        cons += [total <= least.value + 1e-7]
    prob = cp.Problem(cp.Minimize(cost), cons)
    prob.solve(solver=cp.CLARABEL)
    assert prob.status == "optimal"
    return prob.value, V.value, float(total.value)


def test_that_the_hyperplane_rows_are_the_minmax_support_rows():
    cfg, req, v_bar = _case("hyperplane")
    planner = Planner(cfg)
    p_bar = req.position + TAU * np.cumsum(v_bar, axis=0)
    rows = planner.linearise(req, p_bar)
    res = overlap.minmax(p_bar[None], req.drone_covs[None], req.obstacle_means, req.obstacle_covs)
    n = res.normal
    r_min, r_max = overlap.touch_radius(0.9, 3), overlap.touch_radius(0.99, 3)
    radius = req.obstacle_radii[:, None] + cfg.drone_radius_m
    n_o = np.sum(n * req.obstacle_means, axis=-1)
    # n.(o - p) >= r_min (s1 + s2) + R   <=>   -n.p >= r_min (s1 + s2) + R - n.o
    np.testing.assert_allclose(rows.coef_p, -n, atol=1e-12)
    np.testing.assert_allclose(rows.lower, (r_min + BACKOFF_SIGMA) * (res.s1 + res.s2) + radius - n_o, atol=1e-9)
    np.testing.assert_allclose(rows.upper, r_max * (res.s1 + res.s2) + radius - n_o, atol=1e-9)


def _paper_lam(req: PlanRequest, v_bar: np.ndarray) -> np.ndarray:
    p_bar = req.position + TAU * np.cumsum(v_bar, axis=0)
    res = overlap.minmax(p_bar[None], req.drone_covs[None], req.obstacle_means, req.obstacle_covs)
    return np.clip(res.lam, LAM_EPS, 1 - LAM_EPS)


def _safety_slack_total(planner: Planner, step) -> float:
    """Total safety slack of a QP step (in-range obstacle rows, walls, admissibility)."""
    layout = planner.layout((N, 3, 1))
    total = step.slack_obstacle[:2].sum() + step.slack_wall.sum()
    if layout.paper:
        total += np.abs(step.solution.x[layout.col["e_pos"].slice]).sum()
        total += np.abs(step.solution.x[layout.col["e_neg"].slice]).sum()
    return float(total)


@pytest.mark.parametrize("formulation", ["hyperplane", "paper", "bhattacharyya"])
def test_that_one_qp_matches_an_independent_cvxpy_model(formulation):
    cfg, req, v_bar = _case(formulation)
    planner = Planner(cfg)
    step = planner.qp_step(req, v_bar)
    assert step.solution.accurate
    assert _safety_slack_total(planner, step) < 1e-6       # the safety rows hold in this linearisation...
    if formulation != "bhattacharyya":                      # (a baseline without c_max)
        assert step.slack_upper.max() > 0.1                # ...and c_max (0.99) cannot, it is soft
    p_bar = req.position + TAU * np.cumsum(v_bar, axis=0)
    lam_bar = _paper_lam(req, v_bar) if formulation == "paper" else None
    rows = planner.linearise(req, p_bar, lam_bar)
    value, v_ref, _ = _cvxpy_qp(cfg, req, v_bar, rows, lam_bar)
    assert step.objective == pytest.approx(value, rel=2e-4, abs=2e-4)
    np.testing.assert_allclose(step.velocities, v_ref, atol=5e-3)
    # the cost the planner reports is the cost written out
    np.testing.assert_allclose(step.positions, req.position + TAU * np.cumsum(step.velocities, axis=0), atol=1e-6)


def test_that_a_qp_whose_safety_rows_cannot_hold_gives_up_the_least_slack():
    """``paper`` with a tight velocity trust region: the linearised rows cannot all hold.

    The planner's QP must use (within its margin) the least total safety slack cvxpy
    finds, not the 4x more a single L1-penalised QP trades for cost.
    """
    cfg, req, v_bar = _case("paper", trust_region_mps=0.8)
    planner = Planner(cfg)
    step = planner.qp_step(req, v_bar)
    assert step.solution.usable
    lam_bar = _paper_lam(req, v_bar)
    rows = planner.linearise(req, req.position + TAU * np.cumsum(v_bar, axis=0), lam_bar)
    _, _, least = _cvxpy_qp(cfg, req, v_bar, rows, lam_bar, safety="least")
    _, _, penalised = _cvxpy_qp(cfg, req, v_bar, rows, lam_bar, safety="soft")
    used = _safety_slack_total(planner, step)
    violated = int(np.sum(step.slack_obstacle[:2] > 1e-4))
    assert least - 1e-3 <= used <= least + LEAST_VIOLATION_MARGIN * violated + 1e-3, (used, least, violated)
    assert penalised > 2.0 * least                         # what the penalty alone would have given up
