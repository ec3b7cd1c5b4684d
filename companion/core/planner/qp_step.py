"""One QP of the SCP: assemble it from the iterate into the SCP's workspace and solve it.

The hard QP pins the safety slacks; if its safety rows cannot all hold, the
least-violation pair of QPs replaces it (:func:`least_violation`). Everything that
changes per iteration lives in a :class:`QpWorkspace` (one per QP shape, owned by the
planner); the per-request constants are the immutable
:class:`companion.core.planner.qp_data.RequestData`. NED metres, seconds.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from companion.core.planner import qp_record
from companion.core.planner.budget import WorkBudget
from companion.core.planner.config import PlannerConfig
from companion.core.planner.formulations import LAM_EPS, Formulation, ObstacleRows, relax_out_of_range
from companion.core.planner.osqp_qp import MAX_ITER, OsqpQp, QpSolution
from companion.core.planner.piqp_qp import PiqpQp
from companion.core.planner.qp_backend import QpBackend
from companion.core.planner.qp_data import RequestData, RequestTemplate
from companion.core.planner.qp_vectors import read_solution, write_rows
from companion.errors import InputError

logger = logging.getLogger(__name__)

#: The QP backend of each ``[planner] solver``.
BACKENDS = {"osqp": OsqpQp, "piqp": PiqpQp}

#: A slack above this (units of its row) means the constraint it relaxes is violated.
SLACK_TOL = 1e-4
#: Proximal weight on the velocities (s^2/m^2) against the safety slack (1 per unit) in
#: the least-violation QP (:func:`least_violation`).
LEAST_VIOLATION_PROX = 1e-3
#: Room left above the least slack of each violated row when the cost is then minimised
#: (units of the row). With 1e-4 the capped QP was so thin that OSQP hit its iteration
#: cap on the cvxpy cross-check case; 1e-2 solved it in 1450 iterations.
LEAST_VIOLATION_MARGIN = 1e-2


@dataclass(frozen=True)
class QpStep:
    """One QP of the SCP, solved at a given linearisation point (exposed for cross-checks).

    Attributes
    ----------
    velocities, positions : (N, 3) solution.
    lam : (P, N) overlap parameters (``paper``; else the iterate's minmax ``lam``).
    slack_obstacle, slack_upper, slack_wall : (P, N), (P, N), (W, N) slacks at the solution.
    moved : the largest change of a velocity from the linearisation point, m/s.
    safety_slack : the largest safety slack (in-range obstacle rows and walls, units of
        the row; 0 without such rows).
    objective : cost at the solution including constants and slack penalties (slacks clipped at 0).
    cost : ``objective`` without the slack penalties (terminal + jerk + effort).
    rows : the linearised obstacle rows, as the formulation gave them (in the QP the rows of
        obstacles out of sensing range are inactive: :func:`relax_out_of_range` of these).
    velocity_lower, velocity_upper : (N, 3) velocity box (bounds ∩ trust region).
    lam_lower, lam_upper : (P, N) ``lam`` box (``paper``).
    wall_upper : (W, N) right-hand sides of the wall rows.
    v0 : (3,) the current velocity used by the acceleration and jerk terms.
    solution : the raw OSQP result (of the QP whose solution this is).
    admm_iterations : ADMM iterations of every QP solved for this step (hard, and the
        least-violation QPs when the hard one failed).
    least_violation : whether the solution came from the least-violation QPs.
    emergency : whether those QPs needed ``[planner] accel_emergency_mps2`` (see :func:`least_violation`).
    """

    velocities: np.ndarray
    positions: np.ndarray
    lam: np.ndarray
    slack_obstacle: np.ndarray
    slack_upper: np.ndarray
    slack_wall: np.ndarray
    safety_slack: float
    moved: float
    objective: float
    cost: float
    rows: ObstacleRows
    velocity_lower: np.ndarray
    velocity_upper: np.ndarray
    lam_lower: np.ndarray
    lam_upper: np.ndarray
    wall_upper: np.ndarray
    v0: np.ndarray
    solution: QpSolution
    admm_iterations: int = 0
    least_violation: bool = False
    emergency: bool = False


class QpWorkspace:
    """What the SCP keeps per QP shape ``(N, P, W)``: the pattern, the solver, the per-iteration vectors.

    Attributes
    ----------
    layout : the fixed QP pattern.
    template : the request-independent part of every request's constants (this shape and configuration).
    qp : the QP solver (``[planner] solver``: OSQP or PIQP; set up at the first solve of this shape), or None.
    a_slot, l, u : ``A`` data in slot order and the bounds, rewritten per QP.
    x0 : the primal start of the QP (the linearisation point, slacks 0).
    last_y : duals of the last QP solved for this shape (the next replan's warm start).
    recorder : the QP recorder active when the workspace was made (None: none, the default;
        :mod:`companion.core.planner.qp_record`).
    """

    def __init__(self, template: RequestTemplate) -> None:
        layout = template.layout
        self.layout, self.template = layout, template
        self.qp: QpBackend | None = None
        self.a_slot = np.empty_like(layout.a_data0)
        self.l = np.empty(layout.m)
        self.u = np.empty(layout.m)
        self.x0 = np.zeros(layout.n)
        self.last_y: np.ndarray | None = None
        self.recorder = qp_record.ACTIVE

    def start(self, data: RequestData) -> None:
        """Reset the per-iteration vectors to the request's constants (start of a solve)."""
        np.copyto(self.a_slot, data.a_slot)
        np.copyto(self.l, data.l)
        np.copyto(self.u, data.u)


def _primal_start(ws: QpWorkspace, v_bar: np.ndarray, p_bar: np.ndarray, lam_bar: np.ndarray | None) -> np.ndarray:
    """``ws.x0`` set to the linearisation point, slacks 0: a QP's primal start."""
    layout, x0 = ws.layout, ws.x0
    x0[:] = 0.0
    x0[layout.col["V"].slice] = v_bar.ravel()
    x0[layout.col["p"].slice] = p_bar.ravel()
    if layout.paper:
        x0[layout.col["lam"].slice] = lam_bar.ravel()
    return x0


def solve_qp(cfg: PlannerConfig, formulation: Formulation, ws: QpWorkspace, data: RequestData, v_bar: np.ndarray,
             p_bar: np.ndarray, lam_bar: np.ndarray | None, budget: WorkBudget, *, first: bool,
             try_hard: bool = True, emergency_first: bool = False) -> QpStep | None:
    """Linearise at ``(v_bar, p_bar, lam_bar)``, write the QP into ``ws``, solve it (hard, else least violation).

    ``try_hard=False`` goes straight to the least-violation QPs (the SCP does so once the
    hard QP of this replan proved infeasible: an infeasible hard QP runs to its iteration
    cap, and the least-violation pair finds the hard solution anyway when one exists).
    ``emergency_first`` likewise starts the least-violation QPs at the emergency acceleration
    bound (the SCP does so once a step of this replan needed it).
    Returns None when ``budget`` ran out before a solution (``budget.exhausted`` is then set).
    """
    layout = ws.layout
    N, P = layout.N, layout.P
    if lam_bar is not None:
        lam_bar = np.clip(lam_bar, LAM_EPS, 1.0 - LAM_EPS)     # OSQP meets the box only to tolerance
    rows = formulation.rows(data.request, p_bar, lam_bar)
    a_slot, l, u = ws.a_slot, ws.l, ws.u
    # obstacle rows (out of range: inactive; c_max released where masked), the velocity box
    # (bounds ∩ trust region around the iterate) and the hard QP's slack bounds (why: below)
    v_lo, v_hi = write_rows(layout, rows, data.in_range, data.upper_active, v_bar, cfg.trust_region_mps,
                            ws.template.velocity_low, ws.template.velocity_high, a_slot, l, u)
    lam_lo = lam_hi = np.zeros((P, 0))
    if layout.paper:
        relaxed = relax_out_of_range(rows, data.in_range)
        a_slot[layout.slot["obs_lam"].slice] = relaxed.coef_lam.ravel()
        if layout.upper:
            a_slot[layout.slot["obs_hi_lam"].slice] = relaxed.coef_lam.ravel()
        a_slot[layout.slot["adm_p"].slice] = relaxed.adm_p.ravel()
        a_slot[layout.slot["adm_lam"].slice] = relaxed.adm_lam.ravel()
        l[layout.row["adm"].slice] = u[layout.row["adm"].slice] = relaxed.adm_rhs.ravel()
        lam_lo = np.maximum(LAM_EPS, lam_bar - cfg.trust_region_lam)
        lam_hi = np.minimum(1.0 - LAM_EPS, lam_bar + cfg.trust_region_lam)
        l[layout.row["lambox"].slice], u[layout.row["lambox"].slice] = lam_lo.ravel(), lam_hi.ravel()
    a_data = layout.a_csc_data(a_slot)
    # Hard first: safety slacks pinned to 0 (rows "0 <= s <= 0", no penalty in q). With
    # the L1 penalty in place every "s >= 0" row carries a dual equal to the penalty,
    # which OSQP needs hundreds to thousands of iterations to settle (measured); pinned,
    # they are equality rows it handles at once. Only if the hard QP is infeasible is it
    # solved again with the slacks free and penalised. The c_max slack stays free and
    # penalised in the hard QP too: c_max is a performance bound, and an unreachable
    # one (the leader still far ahead) must not make the safety rows soft. Pinned, it
    # did: the corridor run then traded wall and c_min slack against the terminal cost
    # and touched a wall (measured).
    qp = ws.qp
    if ws.recorder is not None:          # off by default (qp_record): tags the QPs recorded
        ws.recorder.scp_step(first)
    if qp is None:
        if ws.recorder is not None and cfg.solver != "osqp":
            raise InputError(f"the QP recorder records OSQP's solves; [planner] solver is {cfg.solver!r}")
        make = ws.recorder.solver if ws.recorder is not None else BACKENDS[cfg.solver]
        qp = ws.qp = make(layout, data.p_data, data.q_hard, a_data, l, u, eps=cfg.solver_eps,
                      eps_rel=cfg.solver_eps_rel, polish=cfg.solver_polish, rho=cfg.solver_rho)
    else:
        qp.update(p_data=data.p_data if first else None, q=data.q_hard, a_data=a_data, l=l, u=u)
    if first:
        # duals of the previous replan shifted by one step like the primal; a cold start
        # starts them at zero, so that its plan does not depend on what was solved before
        qp.warm_start(x=_primal_start(ws, v_bar, p_bar, lam_bar),
                      y=data.y_warm if data.y_warm is not None else np.zeros(layout.m))
    admm_before = budget.admm_iterations
    sol, emergency = None, False
    if try_hard:
        sol = budget.solve(qp, cfg.solver_max_iter)
        if sol is None or budget.exhausted:
            return None
    least = sol is None or not sol.accurate
    if least:
        hard_status = "skipped" if sol is None else sol.status
        sol, emergency = least_violation(cfg, ws, data, _primal_start(ws, v_bar, p_bar, lam_bar), budget,
                                         emergency_first=emergency_first)
        if sol is None:
            return None
        logger.debug("hard QP %s; soft QP %s", hard_status, sol.status)
    admm = budget.admm_iterations - admm_before
    x = sol.x
    # cost at the solution with slacks clipped at 0: OSQP meets "s >= 0" only to its
    # tolerance, and a slightly negative slack times the large penalty would bias J
    xc, xs, s_lo, s_hi, s_wall, safety_slack, moved = read_solution(layout, x, data.in_range, v_bar)
    objective = 0.5 * float(xc @ qp.p_times(xc)) + float(data.q @ xc) + data.constant
    penalty = float(ws.template.q_slack @ xs)
    col = layout.col
    vel = x[col["V"].slice].reshape(N, 3)
    pos = x[col["p"].slice].reshape(N, 3)
    lam = x[col["lam"].slice].reshape(P, N) if layout.paper else np.zeros((P, N))
    return QpStep(
        velocities=vel, positions=pos, lam=lam,
        slack_obstacle=s_lo, slack_upper=s_hi, slack_wall=s_wall,
        safety_slack=safety_slack, moved=moved,
        objective=objective, cost=objective - penalty, rows=rows,
        velocity_lower=v_lo, velocity_upper=v_hi, lam_lower=lam_lo, lam_upper=lam_hi,
        wall_upper=data.wall_upper, v0=data.v0, solution=sol, admm_iterations=admm, least_violation=least,
        emergency=emergency,
    )


def _needs_slack(layout, x: np.ndarray) -> bool:
    """Whether the solution ``x`` uses safety slack (a slack variable above :data:`SLACK_TOL`, as
    :func:`least_violation` caps them)."""
    return bool(np.any(x[layout.slack_cols[layout.safety_slacks]] > SLACK_TOL))


def _accel_rows(layout, x: np.ndarray) -> np.ndarray:
    """The acceleration rows' values at ``x`` (3N,): ``V_1``, then ``V_i - V_{i-1}``, m/s (row order)."""
    velocities = x[layout.col["V"].slice].reshape(-1, 3)
    return np.diff(np.vstack([np.zeros((1, 3)), velocities]), axis=0).ravel()


def least_violation(cfg: PlannerConfig, ws: QpWorkspace, data: RequestData, x0: np.ndarray,
                    budget: WorkBudget, *, emergency_first: bool = False) -> tuple[QpSolution | None, bool]:
    """The QP when its safety rows cannot all hold: violate them as little as possible.

    An L1 penalty is exact only above the constraint's multiplier, and here the
    multiplier is the cost's pull (the terminal Mahalanobis term several metres from
    the goal is worth more per metre than ``slack_penalty``): one soft QP gave up far
    more safety than the situation forced (measured: 4x the least total slack in the
    cvxpy cross-check, and planned contours of 0.07 against c_min = 0.30 in the
    corridor). So, lexicographically: (1) the least total safety slack, with a small
    proximal term ``LEAST_VIOLATION_PROX |V - V_bar|^2`` in place of the cost so that
    the QP is strongly convex in the velocities; (2) the real cost with each safety
    slack capped at what (1) needed.

    With ``[planner] accel_emergency_mps2``, when (1) within ``accel_max`` still needs
    safety slack, (1) is solved again with the acceleration rows widened to that bound
    (safety outranks the comfort bound), and (2) then widens each acceleration row only as
    far as that (1) needed, like the slack: the cost alone never buys emergency
    acceleration (with the whole emergency bound in (2) the corridor's drone chased its
    leader with it and needed more emergencies, measured). With ``emergency_first`` (an
    earlier step of the replan needed the bound) (1) is solved widened at once: within
    ``accel_max`` it ran to its iteration cap at every later step of such a replan, and the
    budget ran out before the replan had a safe plan (corridor, measured). The acceleration
    rows of ``ws`` are as they were when it returns.

    Every QP is solved within ``budget``. Returns the solution (None when the budget ran
    out first) and whether the acceleration rows were widened for it.
    """
    acc = ws.layout.row["accel"].slice
    l_acc, u_acc = ws.l[acc].copy(), ws.u[acc].copy()
    try:
        return _least_violation(cfg, ws, data, x0, budget, emergency_first, l_acc, u_acc)
    finally:
        ws.l[acc], ws.u[acc] = l_acc, u_acc


def _least_violation(cfg: PlannerConfig, ws: QpWorkspace, data: RequestData, x0: np.ndarray, budget: WorkBudget,
                     emergency_first: bool, l_acc: np.ndarray, u_acc: np.ndarray) -> tuple[QpSolution | None, bool]:
    """:func:`least_violation` with the acceleration rows' nominal bounds ``l_acc``, ``u_acc``
    (it may widen ``ws``'s rows; the caller restores them)."""
    layout, qp, l, u = ws.layout, ws.qp, ws.l, ws.u
    slack_rows = layout.row["slack"]
    safety = slack_rows.start + layout.safety_slacks
    u[slack_rows.slice] = np.inf
    widening, acc = ws.template.accel_widening, layout.row["accel"].slice
    widened = widening is not None and emergency_first
    if widened:
        l[acc], u[acc] = l_acc - widening, u_acc + widening
    v_bar = x0[layout.col["V"].slice]
    q_least = np.zeros(layout.n)
    q_least[layout.col["V"].slice] = -2.0 * LEAST_VIOLATION_PROX * v_bar
    q_least[layout.slack_cols[layout.safety_slacks]] = layout.slack_scale
    p_least = layout.p_data(0.0, 2.0 * LEAST_VIOLATION_PROX, np.zeros((3, 3)))
    qp.update(p_data=p_least, q=q_least, l=l, u=u)     # l and u together: OSQP 1.1 checks l <= u
    # The duals of an infeasible or unconverged hard solve are no start (they made OSQP
    # hit its iteration cap in closed loop with `paper`, measured): restart them at zero.
    qp.warm_start(x=x0, y=np.zeros(layout.m))
    least = budget.solve(qp, cfg.solver_max_iter)
    if least is None or budget.exhausted:
        qp.update(p_data=data.p_data, q=data.q)
        return None, widened
    if widening is not None and not widened and np.isfinite(least.x).all() and _needs_slack(layout, least.x):
        l[acc], u[acc] = l_acc - widening, u_acc + widening      # (1) again, up to the emergency bound
        qp.update(l=l, u=u)
        qp.warm_start(x=least.x, y=np.zeros(layout.m))
        emergency = budget.solve(qp, cfg.solver_max_iter)
        if emergency is None or budget.exhausted:
            qp.update(p_data=data.p_data, q=data.q)
            return None, True
        if emergency.usable or not least.usable:
            least, widened = emergency, True
        else:
            l[acc], u[acc] = l_acc, u_acc
    if widened and np.isfinite(least.x).all():
        rows = _accel_rows(layout, least.x)       # each row widened only as far as (1) needed
        below, above = np.maximum(l_acc - rows, 0.0), np.maximum(rows - u_acc, 0.0)
        l[acc] = np.maximum(l_acc - np.where(below > SLACK_TOL, below + LEAST_VIOLATION_MARGIN, 0.0), l_acc - widening)
        u[acc] = np.minimum(u_acc + np.where(above > SLACK_TOL, above + LEAST_VIOLATION_MARGIN, 0.0), u_acc + widening)
    qp.update(p_data=data.p_data, q=data.q)
    if np.isfinite(least.x).all():     # an unconverged (1) still bounds the slack it needs
        needed = np.maximum(least.x[layout.slack_cols[layout.safety_slacks]], 0.0)
        cap = np.where(needed > SLACK_TOL, needed + LEAST_VIOLATION_MARGIN, 0.0)   # unneeded: pinned
        u[safety] = cap / layout.slack_scale
        qp.update(l=l, u=u)
        qp.warm_start(x=least.x, y=np.zeros(layout.m))
        sol = budget.solve(qp, cfg.solver_max_iter)
        if sol is None or budget.exhausted:
            return None, widened
        if sol.usable:
            return sol, widened
        if least.usable:     # (1) is a plan too: least violation, cost not minimised
            return least, widened
    u[slack_rows.slice] = np.inf
    qp.update(l=l, u=u)
    qp.warm_start(x=x0, y=np.zeros(layout.m))
    sol = budget.solve(qp, MAX_ITER)     # the plain soft QP: a plan, and its slack says so
    return (None if sol is None or budget.exhausted else sol), widened
