"""The planner: sequential convex programming on OSQP (SPEC section 3, paper Algorithm 1).

Each SCP iteration linearises the collision rows around the current iterate
(:mod:`companion.core.planner.formulations`), writes them into the fixed QP pattern
(:mod:`companion.core.planner.qp_layout`), updates OSQP in place and solves: the hard QP
(safety slacks pinned), or, if its safety rows cannot all hold, the least-violation pair
of QPs (:meth:`Planner._least_violation`). It stops when the cost changes by less than
``scp_tolerance`` (relative; ``scp_tolerance_warm`` for a replan warm-started from the
previous plan), or the iterate no longer moves, *and* the exact recheck on the new
iterate passes (or the same slack is needed again: the violation is forced); or at the
iteration cap.

Cost (``0.5 x'Px + q'x + const``)::

    w_t (p_N - g)' S_N^-1 (p_N - g)                          terminal Mahalanobis distance
  + w_j sum_{i=1}^{N-1} |(V_{i+1} - 2 V_i + V_{i-1}) / tau^2|^2   jerk, V_0 = current velocity
  + w_v sum_i |V_i|^2                                         small effort term
  + rho (sum s_lo + e_pos + e_neg + s_wall) + rho_c sum s_hi  L1 penalties on the slacks

Positions obey the paper's holonomic model ``p_i = p_{i-1} + tau V_i``, or with a velocity
lag ``p_i = p_{i-1} + b V_i + c V_{i-1}`` (:mod:`companion.core.planner.vehicle_model`).

The only clock is ``time.perf_counter()``, read for the ``solve_time_s`` diagnostic; it
never influences the plan (no time limit is handed to the solver).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from companion.core import overlap
from companion.errors import InputError
from companion.core.planner import formulations as F
from companion.core.planner.config import PlannerConfig
from companion.core.planner.osqp_qp import OsqpQp, QpSolution
from companion.core.planner.qp_data import RequestData
from companion.core.planner.qp_layout import QpLayout
from companion.core.planner.request import Plan, PlanRequest
from companion.core.planner.safety import (RECHECK_TOL_M, RECHECK_TOL_SIGMA, SafetyFigures, bhattacharyya_margin,
                                      exact_safety)
from companion.core.planner.vehicle_model import model_from_config

logger = logging.getLogger(__name__)

#: A slack above this (units of its row) means the constraint it relaxes is violated.
SLACK_TOL = 1e-4
#: The same for the ``c_max`` slack. It stays free and penalised even in the hard QP (see
#: ``_qp_step``), so OSQP leaves it at its tolerance times the penalty's pull rather than
#: at zero: 5e-4 measured on a feasible ``c_max`` (contour 0.6019 against 0.6).
C_MAX_SLACK_TOL = 1e-3
#: Proximal weight on the velocities (s^2/m^2) against the safety slack (1 per unit) in
#: the least-violation QP (:meth:`Planner._least_violation`).
LEAST_VIOLATION_PROX = 1e-3
#: Room left above the least slack of each violated row when the cost is then minimised
#: (units of the row). With 1e-4 the capped QP was so thin that OSQP hit its iteration
#: cap on the cvxpy cross-check case; 1e-2 solved it in 1450 iterations.
LEAST_VIOLATION_MARGIN = 1e-2
#: The SCP has converged when no velocity moves by more than this between iterates, m/s.
STEP_TOL_MPS = 1e-4


#: Lateral size of the cold-start guess's bulge to the right of the route, metres.
HEAD_ON_BIAS_M = 0.05


def _right_bulge_velocities(route: np.ndarray, n_steps: int, step_s: float) -> np.ndarray:
    """Velocities (N, 3) that add ``HEAD_ON_BIAS_M sin(pi i / N)`` to the right of ``route``.

    Right of the heading in NED is ``down x heading`` (east for a north-bound route); a
    vertical or zero route bulges east.
    """
    h = route[:2]
    right = np.array([-h[1], h[0], 0.0]) / np.linalg.norm(h) if np.linalg.norm(h) > 1e-9 else np.array([0.0, 1.0, 0.0])
    offset = HEAD_ON_BIAS_M * np.sin(np.pi * np.arange(n_steps + 1) / n_steps)
    return np.diff(offset)[:, None] / step_s * right


@dataclass(frozen=True)
class QpStep:
    """One QP of the SCP, solved at a given linearisation point (exposed for cross-checks).

    Attributes
    ----------
    velocities, positions : (N, 3) solution.
    lam : (P, N) overlap parameters (``paper``; else the iterate's minmax ``lam``).
    slack_obstacle, slack_upper, slack_wall : (P, N), (P, N), (W, N) slacks at the solution.
    objective : cost at the solution including constants and slack penalties (slacks clipped at 0).
    cost : ``objective`` without the slack penalties (terminal + jerk + effort).
    rows : the linearised obstacle rows used.
    velocity_lower, velocity_upper : (N, 3) velocity box (bounds ∩ trust region).
    lam_lower, lam_upper : (P, N) ``lam`` box (``paper``).
    wall_upper : (W, N) right-hand sides of the wall rows.
    v0 : (3,) the current velocity used by the acceleration and jerk terms.
    solution : the raw OSQP result.
    """

    velocities: np.ndarray
    positions: np.ndarray
    lam: np.ndarray
    slack_obstacle: np.ndarray
    slack_upper: np.ndarray
    slack_wall: np.ndarray
    objective: float
    cost: float
    rows: F.ObstacleRows
    velocity_lower: np.ndarray
    velocity_upper: np.ndarray
    lam_lower: np.ndarray
    lam_upper: np.ndarray
    wall_upper: np.ndarray
    v0: np.ndarray
    solution: QpSolution


class Planner:
    """Overlap-constrained MPC solved by SCP on OSQP.

    Parameters
    ----------
    config : PlannerConfig
        Frozen configuration; OSQP is set up lazily once per problem shape ``(N, P, W)``.

    Examples
    --------
    >>> planner = Planner(PlannerConfig(horizon_steps=20, step_s=1.0, c_min=0.6))  # doctest: +SKIP
    >>> plan = planner.solve(request, warm_start=previous_plan)                    # doctest: +SKIP
    """

    def __init__(self, config: PlannerConfig) -> None:
        if not isinstance(config, PlannerConfig):
            raise TypeError(f"config must be a PlannerConfig, got {type(config).__name__}")
        self.config = config
        self.r_min = float(overlap.touch_radius(config.c_min, 3))
        self.r_max = None if config.c_max is None else float(overlap.touch_radius(config.c_max, 3))
        self.lag = model_from_config(config.step_s, config.velocity_time_constant_s, config.vehicle_response)
        self._qps: dict[tuple[int, int, int], tuple[QpLayout, OsqpQp | None]] = {}
        self._last_y: dict[tuple[int, int, int], np.ndarray] = {}

    # ------------------------------------------------------------------ public API
    def solve(self, request: PlanRequest, warm_start: Plan | None = None) -> Plan:
        """Plan velocities for ``request``.

        Parameters
        ----------
        request : PlanRequest
            Current state, predictions, walls and target (horizon must equal ``horizon_steps``).
        warm_start : Plan or None
            The previous plan; its velocities shifted by one step (the last repeated)
            initialise the SCP. ``None`` starts from a constant velocity towards the target.

        Returns
        -------
        Plan
            Never raises on a solver failure: the status says ``'failed'``.
        """
        t0 = time.perf_counter()
        cfg = self.config
        self._check(request)
        layout = self._layout(request)
        data = RequestData(self.config, self.r_min, layout, request)
        last_y = self._last_y.get((layout.N, layout.P, layout.W))
        if warm_start is not None and last_y is not None:
            data.y_warm = last_y[layout.shift_rows]
        v_bar = self._initial_velocities(request, data.v0, warm_start)
        p_bar = self.lag.positions(request.position, data.v0, v_bar)
        lam_bar = self._initial_lam(request, p_bar) if cfg.formulation == "paper" else None
        notes: list[str] = []
        step: QpStep | None = None
        j_prev, slack_prev = np.inf, np.inf
        iterations = 0
        converged = False
        tolerance = cfg.scp_tolerance if warm_start is None else cfg.scp_tolerance_warm
        for iterations in range(1, cfg.scp_max_iterations + 1):
            new = self._qp_step(layout, data, request, v_bar, p_bar, lam_bar, first=iterations == 1)
            if not new.solution.usable:
                notes.append(f"solver: {new.solution.status} at iteration {iterations}")
                break
            if not new.solution.accurate:
                notes.append(f"solver: {new.solution.status} at iteration {iterations}")
            step = new
            moved = float(np.max(np.abs(step.velocities - v_bar)))
            v_bar, p_bar = step.velocities, step.positions
            lam_bar = step.lam if cfg.formulation == "paper" else None
            # convergence on the cost without penalties: slacks at OSQP's tolerance times the
            # large penalty would add noise of order eps * rho to J
            small = moved <= STEP_TOL_MPS or abs(step.cost - j_prev) <= tolerance * max(1.0, abs(step.cost))
            j_prev = step.cost
            # the exact recheck decides, unless the iterate needs safety slack and needed the
            # same last time: then the violation is forced (e.g. by the current state) and
            # further iterations only repeat it (they ran to the cap, measured in the corridor)
            slack = self._safety_slack(data, step)
            if small and (self._recheck(request, data, step.positions)[1]
                          or (slack > SLACK_TOL and abs(slack - slack_prev) <= SLACK_TOL)):
                converged = True
                break
            slack_prev = slack
        if step is not None:
            self._last_y[(layout.N, layout.P, layout.W)] = step.solution.y
        if not converged and step is not None and len(notes) == 0:
            notes.append("max_iterations")
        return self._finish(request, data, step, v_bar, iterations, notes, t0)

    def qp_step(self, request: PlanRequest, velocities: np.ndarray, lam: np.ndarray | None = None) -> QpStep:
        """Solve the single QP of the SCP linearised at ``velocities`` (N, 3) (and ``lam``).

        Exposed so that tests can compare one QP with an independent model of it.
        """
        self._check(request)
        layout = self._layout(request)
        data = RequestData(self.config, self.r_min, layout, request)
        v_bar = np.asarray(velocities, dtype=float)
        p_bar = self.lag.positions(request.position, data.v0, v_bar)
        if self.config.formulation == "paper" and lam is None:
            lam = self._initial_lam(request, p_bar)
        return self._qp_step(layout, data, request, v_bar, p_bar, lam, first=True)

    def linearise(self, request: PlanRequest, positions: np.ndarray, lam: np.ndarray | None = None,
                  in_range: np.ndarray | None = None) -> F.ObstacleRows:
        """Linearised obstacle rows of this planner's formulation around ``positions`` (N, 3)."""
        cfg = self.config
        radius_sum = request.obstacle_radii + cfg.drone_radius_m
        args = (positions, request.drone_covs, request.obstacle_means, request.obstacle_covs)
        if cfg.formulation == "hyperplane":
            rows, _ = F.hyperplane_rows(*args, radius_sum, self.r_min, self.r_max)
        elif cfg.formulation == "paper":
            rows = F.paper_rows(positions, lam, *args[1:], radius_sum, self.r_min, self.r_max)
        elif cfg.formulation == "deterministic":
            rows = F.deterministic_rows(positions, request.obstacle_means, radius_sum)
        else:
            rows = F.bhattacharyya_rows(*args, radius_sum, self.r_min)
        if in_range is not None:
            rows = F.relax_out_of_range(rows, in_range)
        return rows

    # ------------------------------------------------------------------ internals
    def _check(self, request: PlanRequest) -> None:
        if not isinstance(request, PlanRequest):
            raise TypeError(f"request must be a PlanRequest, got {type(request).__name__}")
        if request.horizon_steps != self.config.horizon_steps:
            raise InputError(f"request has {request.horizon_steps} steps, the planner is configured "
                             f"for horizon_steps = {self.config.horizon_steps}")

    def _layout(self, request: PlanRequest) -> QpLayout:
        key = (request.horizon_steps, request.num_obstacles, request.num_walls)
        if key not in self._qps:
            layout = QpLayout(*key, paper=self.config.formulation == "paper",
                              upper=self.r_max is not None and self.config.formulation in ("hyperplane", "paper"),
                              step_s=self.config.step_s, lag=self.lag)
            self._qps[key] = (layout, None)
            logger.debug("planner: new QP shape N=%d P=%d W=%d (n=%d, m=%d)", *key, layout.n, layout.m)
        return self._qps[key][0]

    def _initial_velocities(self, request: PlanRequest, v0: np.ndarray, warm_start: Plan | None) -> np.ndarray:
        cfg = self.config
        N, tau = cfg.horizon_steps, cfg.step_s
        if warm_start is not None and warm_start.velocities.shape == (N, 3):
            v = np.vstack([warm_start.velocities[1:], warm_start.velocities[-1:]])
        else:
            # straight line to the target at constant speed, with a small bulge to the right of
            # the route (HEAD_ON_BIAS_M): a head-on encounter on the line is symmetric and the
            # minmax normal along the line only says "stay behind"; the bulge decides the side
            # deterministically, as the rules of the air do (pass right).
            route = request.target - request.position
            v = np.broadcast_to(route / (N * tau), (N, 3)) + _right_bulge_velocities(route, N, tau)
        # project onto |V_i| <= v_max and |V_i - V_{i-1}| <= a_max tau (forward pass)
        vmax, da = cfg.velocity_max, cfg.accel_max * tau
        out = np.empty((N, 3))
        prev = v0
        for i in range(N):
            prev = np.clip(np.clip(v[i], prev - da, prev + da), -vmax, vmax)
            out[i] = prev
        return out

    def _initial_lam(self, request: PlanRequest, positions: np.ndarray) -> np.ndarray:
        if request.num_obstacles == 0:
            return np.zeros((0, request.horizon_steps))
        mu1 = F._nudge(positions, request.obstacle_means)
        res = overlap.minmax(mu1, np.broadcast_to(request.drone_covs[None], request.obstacle_covs.shape),
                             request.obstacle_means, request.obstacle_covs)
        return np.clip(res.lam, F.LAM_EPS, 1.0 - F.LAM_EPS)

    def _qp_step(self, layout: QpLayout, data: RequestData, request: PlanRequest, v_bar: np.ndarray,
                 p_bar: np.ndarray, lam_bar: np.ndarray | None, *, first: bool) -> QpStep:
        cfg = self.config
        N, P = layout.N, layout.P
        if lam_bar is not None:
            lam_bar = np.clip(lam_bar, F.LAM_EPS, 1.0 - F.LAM_EPS)     # OSQP meets the box only to tolerance
        rows = self.linearise(request, p_bar, lam_bar, data.in_range)
        a_slot = data.a_slot
        a_slot[layout.slot["obs_p"].slice] = rows.coef_p.ravel()
        l, u = data.l, data.u
        l[layout.row["obs"].slice], u[layout.row["obs"].slice] = rows.lower.ravel(), np.inf
        if layout.upper:
            a_slot[layout.slot["obs_hi_p"].slice] = rows.coef_p.ravel()
            upper = np.where(data.upper_active[:, None], rows.upper, np.inf)  # c_max released where masked
            l[layout.row["obs_hi"].slice], u[layout.row["obs_hi"].slice] = -np.inf, upper.ravel()
        # velocity box ∩ trust region around the iterate
        vmax, tr = cfg.velocity_max, cfg.trust_region_mps
        v_lo, v_hi = np.maximum(-vmax, v_bar - tr), np.minimum(vmax, v_bar + tr)
        l[layout.row["vbox"].slice], u[layout.row["vbox"].slice] = v_lo.ravel(), v_hi.ravel()
        lam_lo = lam_hi = np.zeros((P, 0))
        if layout.paper:
            a_slot[layout.slot["obs_lam"].slice] = rows.coef_lam.ravel()
            if layout.upper:
                a_slot[layout.slot["obs_hi_lam"].slice] = rows.coef_lam.ravel()
            a_slot[layout.slot["adm_p"].slice] = rows.adm_p.ravel()
            a_slot[layout.slot["adm_lam"].slice] = rows.adm_lam.ravel()
            l[layout.row["adm"].slice] = u[layout.row["adm"].slice] = rows.adm_rhs.ravel()
            lam_lo = np.maximum(F.LAM_EPS, lam_bar - cfg.trust_region_lam)
            lam_hi = np.minimum(1.0 - F.LAM_EPS, lam_bar + cfg.trust_region_lam)
            l[layout.row["lambox"].slice], u[layout.row["lambox"].slice] = lam_lo.ravel(), lam_hi.ravel()
        a_data = layout.a_csc_data(a_slot)
        key = (N, P, layout.W)
        qp = self._qps[key][1]
        # Hard first: safety slacks pinned to 0 (rows "0 <= s <= 0", no penalty in q). With
        # the L1 penalty in place every "s >= 0" row carries a dual equal to the penalty,
        # which OSQP needs hundreds to thousands of iterations to settle (measured); pinned,
        # they are equality rows it handles at once. Only if the hard QP is infeasible is it
        # solved again with the slacks free and penalised. The c_max slack stays free and
        # penalised in the hard QP too: c_max is a performance bound, and an unreachable
        # one (the leader still far ahead) must not make the safety rows soft. Pinned, it
        # did: the corridor run then traded wall and c_min slack against the terminal cost
        # and touched a wall (measured).
        slack_rows = layout.row["slack"].slice
        u[slack_rows] = np.inf
        u[layout.row["slack"].start + layout.safety_slacks] = 0.0
        if qp is None:
            qp = OsqpQp(layout, data.p_data, data.q_hard, a_data, l, u, eps=cfg.solver_eps, eps_rel=cfg.solver_eps_rel,
                        polish=cfg.solver_polish, rho=cfg.solver_rho)
            self._qps[key] = (layout, qp)
        else:
            qp.update(p_data=data.p_data if first else None, q=data.q_hard, a_data=a_data, l=l, u=u)
        # primal start at the linearisation point (slacks 0)
        x0 = np.zeros(layout.n)
        x0[layout.col["V"].slice] = v_bar.ravel()
        x0[layout.col["p"].slice] = p_bar.ravel()
        if layout.paper:
            x0[layout.col["lam"].slice] = lam_bar.ravel()
        if first:
            # duals of the previous replan shifted by one step like the primal; a cold start
            # starts them at zero, so that its plan does not depend on what was solved before
            qp.warm_start(x=x0, y=data.y_warm if data.y_warm is not None else np.zeros(layout.m))
        sol = qp.solve(max_iter=cfg.solver_max_iter)
        if not sol.accurate:
            hard_status = sol.status
            sol = self._least_violation(qp, layout, data, x0, l, u)
            logger.debug("hard QP %s; soft QP %s", hard_status, sol.status)
        x = sol.x
        # cost at the solution with slacks clipped at 0: OSQP meets "s >= 0" only to its
        # tolerance, and a slightly negative slack times the large penalty would bias J
        xc = x.copy()
        xc[layout.slack_cols] = np.maximum(xc[layout.slack_cols], 0.0)
        objective = 0.5 * float(xc @ (qp.p_full @ xc)) + float(data.q @ xc) + data.constant
        penalty = float(data.q[layout.slack_cols] @ xc[layout.slack_cols])
        col = layout.col
        vel = x[col["V"].slice].reshape(N, 3)
        pos = x[col["p"].slice].reshape(N, 3)
        lam = x[col["lam"].slice].reshape(P, N) if layout.paper else np.zeros((P, N))
        sig = layout.slack_scale
        s_hi = sig * x[col["s_hi"].slice].reshape(P, N) if layout.upper else np.zeros((P, N))
        return QpStep(
            velocities=vel, positions=pos, lam=lam,
            slack_obstacle=sig * x[col["s_lo"].slice].reshape(P, N), slack_upper=s_hi,
            slack_wall=sig * x[col["s_wall"].slice].reshape(layout.W, N),
            objective=objective, cost=objective - penalty, rows=rows,
            velocity_lower=v_lo, velocity_upper=v_hi, lam_lower=lam_lo, lam_upper=lam_hi,
            wall_upper=data.wall_upper, v0=data.v0, solution=sol,
        )

    def _least_violation(self, qp: OsqpQp, layout: QpLayout, data: RequestData, x0: np.ndarray,
                         l: np.ndarray, u: np.ndarray) -> QpSolution:
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
        """
        slack_rows = layout.row["slack"]
        safety = slack_rows.start + layout.safety_slacks
        u[slack_rows.slice] = np.inf
        v_bar = x0[layout.col["V"].slice]
        q_least = np.zeros(layout.n)
        q_least[layout.col["V"].slice] = -2.0 * LEAST_VIOLATION_PROX * v_bar
        q_least[layout.slack_cols[layout.safety_slacks]] = layout.slack_scale
        p_least = layout.p_data(0.0, 2.0 * LEAST_VIOLATION_PROX, np.zeros((3, 3)))
        qp.update(p_data=p_least, q=q_least, l=l, u=u)     # l and u together: OSQP 1.1 checks l <= u
        # The duals of an infeasible or unconverged hard solve are no start (they made OSQP
        # hit its iteration cap in closed loop with `paper`, measured): restart them at zero.
        qp.warm_start(x=x0, y=np.zeros(layout.m))
        least = qp.solve(max_iter=self.config.solver_max_iter)
        qp.update(p_data=data.p_data, q=data.q)
        if np.all(np.isfinite(least.x)):     # an unconverged (1) still bounds the slack it needs
            needed = np.maximum(least.x[layout.slack_cols[layout.safety_slacks]], 0.0)
            cap = np.where(needed > SLACK_TOL, needed + LEAST_VIOLATION_MARGIN, 0.0)   # unneeded: pinned
            u[safety] = cap / layout.slack_scale
            qp.update(l=l, u=u)
            qp.warm_start(x=least.x, y=np.zeros(layout.m))
            sol = qp.solve(max_iter=self.config.solver_max_iter)
            if sol.usable:
                return sol
            if least.usable:     # (1) is a plan too: least violation, cost not minimised
                return least
        u[slack_rows.slice] = np.inf
        qp.update(l=l, u=u)
        qp.warm_start(x=x0, y=np.zeros(layout.m))
        return qp.solve()                     # the plain soft QP: a plan, and its slack says so

    @staticmethod
    def _safety_slack(data: RequestData, step: QpStep) -> float:
        """Largest safety slack of a QP step (in-range obstacle rows and walls), row units."""
        slack = [step.slack_obstacle[data.in_range].ravel(), step.slack_wall.ravel()]
        return float(max((float(s.max()) for s in slack if s.size), default=0.0))

    def _recheck(self, request: PlanRequest, data: RequestData, positions: np.ndarray) -> tuple[SafetyFigures, bool]:
        """Exact figures and whether the formulation's own constraints hold on them."""
        cfg = self.config
        deterministic = cfg.formulation == "deterministic"
        figs = exact_safety(request, positions, cfg.drone_radius_m, 0.0 if deterministic else self.r_min)
        ok = bool(np.all(figs.wall_margin >= -RECHECK_TOL_M))
        m = data.in_range
        if deterministic:
            ok &= bool(np.all(figs.distance_margin[m] >= -RECHECK_TOL_M))
        elif cfg.formulation == "bhattacharyya":
            margin = bhattacharyya_margin(request, positions, cfg.drone_radius_m, 0.5 * self.r_min**2)
            ok &= bool(np.all(margin[m] >= -self.r_min * RECHECK_TOL_SIGMA))
        else:
            ok &= bool(np.all(figs.eta[m] >= self.r_min - RECHECK_TOL_SIGMA))
        return figs, ok

    def _finish(self, request: PlanRequest, data: RequestData, step: QpStep | None, v_bar: np.ndarray,
                iterations: int, notes: list[str], t0: float) -> Plan:
        cfg = self.config
        if step is None:
            velocities = v_bar
            positions = self.lag.positions(request.position, data.v0, velocities)
            slack_max, cost = np.inf, np.nan
        else:
            velocities, positions = step.velocities.copy(), step.positions.copy()
            slack_max = self._safety_slack(data, step)
            cost = step.objective
            upper = float(step.slack_upper[data.upper_active].max(initial=0.0))
            if upper > C_MAX_SLACK_TOL:
                notes.append(f"c_max_violated: slack {upper:.3g}")
        figs, ok = self._recheck(request, data, positions)
        # the status comes from the exact figures: slack that only ate into the back-off
        # (formulations.BACKOFF_SIGMA) leaves c_min and the walls holding
        if step is None:
            status = "failed"
        elif ok:
            status = "optimal"
            if slack_max > SLACK_TOL:
                notes.append(f"back-off used: slack {slack_max:.3g}")
        elif slack_max > SLACK_TOL:
            status = "slack"
        else:
            status = "failed"
            notes.append("exact recheck violated c_min without slack")
        # the cmd rows hold |u| <= v_max to OSQP's tolerance, which 1/(1 - alpha) amplifies
        # (1.5e-4 m/s over, measured): clip so that no setpoint ever exceeds the bound
        commands = np.clip(self.lag.commands(data.v0, velocities), -cfg.velocity_max, cfg.velocity_max)
        for a in (velocities, positions, commands):
            a.setflags(write=False)
        plan = Plan(
            velocities=velocities, commands=commands, initial_velocity=data.v0.copy(), positions=positions, eta=figs.eta, contour_of_touch=figs.contour_of_touch,
            overlap=figs.overlap, wall_margin=figs.wall_margin, in_range=data.in_range.copy(), status=status,
            iterations=iterations, solve_time_s=time.perf_counter() - t0, slack_max=slack_max, cost=cost,
            formulation=cfg.formulation, notes=tuple(notes),
        )
        if status != "optimal":
            logger.info("plan %s after %d iterations (slack %.3g; %s)", status, iterations, slack_max, "; ".join(notes))
        return plan
