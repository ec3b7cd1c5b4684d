"""The planner: sequential convex programming on OSQP (docs/METHOD.md section 2.7; the paper's Algorithm 1).

Each SCP iteration linearises the collision rows around the current iterate
(:mod:`companion.core.planner.formulations`), writes them into the fixed QP pattern
(:mod:`companion.core.planner.qp_layout`), updates OSQP in place and solves: the hard QP
(safety slacks pinned), or, if its safety rows cannot all hold, the least-violation pair
of QPs (:func:`companion.core.planner.qp_step.least_violation`). It stops when the cost changes by less than
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

Every replan runs within ``replan_work_budget`` work units (ADMM iterations of all its
QPs plus a fixed charge per QP, :mod:`companion.core.planner.budget`); when they run
out, or the iteration cap ends the SCP on an unsafe solution that needed no slack, the plan
is the best safe iterate (the last QP's solution, else the cheapest earlier one, else the
SCP's start, whichever first passes the exact recheck) or ``failed``. The only clock is
``time.perf_counter()``, read for the ``solve_time_s`` diagnostic; it never influences
the plan (no time limit is handed to the solver).
"""

from __future__ import annotations

import logging
import time
import numpy as np

from collections.abc import Mapping
from types import MappingProxyType

from companion.core import jit, overlap
from companion.core.planner.budget import WorkBudget
from companion.core.planner.config import PlannerConfig
from companion.core.planner.formulations import Formulation, ObstacleRows, make_formulation, relax_out_of_range
from companion.core.planner.qp_backend import QpBackend
from companion.core.planner.qp_data import RequestData, RequestTemplate
from companion.core.planner.qp_layout import QpLayout
from companion.core.planner.qp_step import SLACK_TOL, QpStep, QpWorkspace, solve_qp
from companion.core.planner.request import Plan, PlanRequest
from companion.core.planner.vehicle_model import ResponseModel, model_from_config
from companion.errors import InputError

logger = logging.getLogger(__name__)

#: The same for the ``c_max`` slack. It stays free and penalised even in the hard QP (see
#: ``_qp_step``), so OSQP leaves it at its tolerance times the penalty's pull rather than
#: at zero: 5e-4 measured on a feasible ``c_max`` (contour 0.6019 against 0.6).
C_MAX_SLACK_TOL = 1e-3
#: Work "budget" of :meth:`Planner.qp_step` (a single QP for cross-checks): never binds.
UNBUDGETED_WORK = 10**15
#: The SCP has converged when no velocity moves by more than this between iterates, m/s.
STEP_TOL_MPS = 1e-4


#: Acceleration above ``accel_max`` that counts as emergency acceleration, m/s^2 (OSQP meets
#: the rows to its tolerance: 2e-3 over measured on a plan within ``accel_max``).
ACCEL_TOL_MPS2 = 1e-2

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


@jit.lazy(lambda t: t.void(t.float64[:, ::1], jit.readonly(t, 1), jit.readonly(t, 1), jit.readonly(t, 1)))
def _project_forward(v, v0, vmax, da):
    """In place, the rows of ``v`` (N, 3), m/s, projected onto ``|V_i - V_{i-1}| <= da`` and ``|V_i| <= vmax``.

    A forward pass from ``V_0 = v0``: each row is clipped to within ``da`` (``a_max tau``)
    of the projected row before it, then to the speed box. A sequential recursion, so one
    compiled loop (or, without numba, this function in Python); ``lo if lo > x else x``
    and ``hi if hi < x else x`` are Python's ``max(x, lo)`` and ``min(x, hi)`` exactly
    (the values the list-based loop this replaces produced, signed zeros included).
    """
    for i in range(v.shape[0]):
        for k in range(3):
            prev = v0[k] if i == 0 else v[i - 1, k]
            lo, hi = prev - da[k], prev + da[k]
            x = v[i, k]
            x = lo if lo > x else x
            x = hi if hi < x else x
            x = -vmax[k] if -vmax[k] > x else x
            v[i, k] = vmax[k] if vmax[k] < x else x


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
        self.formulation: Formulation = make_formulation(config.formulation, self.r_min, self.r_max,
                                                         config.drone_radius_m)
        self.lag = model_from_config(config.step_s, config.velocity_time_constant_s, config.vehicle_response)
        self._workspaces: dict[tuple[int, int, int], QpWorkspace] = {}
        # the forward projection's bounds: speed (m/s) and speed change per step (a_max tau)
        self._projection_bounds = (np.ascontiguousarray(config.velocity_max, dtype=float),
                                   np.ascontiguousarray(config.accel_max * config.step_s, dtype=float))

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
        cfg, form = self.config, self.formulation
        ws = self._workspace(request)
        layout = ws.layout
        y_warm = ws.last_y[layout.shift_rows] if warm_start is not None and ws.last_y is not None else None
        data = RequestData.build(ws.template, form, request, y_warm)
        ws.start(data)
        v_bar = self.initial_velocities(request, data.v0, warm_start)
        p_bar = self.lag.positions(request.position, data.v0, v_bar, request.response_state)
        lam_bar = form.initial_lam(request, p_bar)
        v_start = v_bar
        budget = WorkBudget(cfg.replan_work_budget)
        notes: list[str] = []
        step: QpStep | None = None
        j_prev, slack_prev = np.inf, np.inf
        iterations = 0
        converged = False
        tolerance = cfg.scp_tolerance if warm_start is None else cfg.scp_tolerance_warm
        steps: list[QpStep] = []         # every iterate, for the best safe one (_finish)
        for iterations in range(1, cfg.scp_max_iterations + 1):
            new = solve_qp(cfg, form, ws, data, v_bar, p_bar, lam_bar, budget, first=iterations == 1,
                           try_hard=step is None or not step.least_violation,
                           emergency_first=step is not None and step.emergency)
            if new is None:              # the work budget ran out before this QP was solved
                iterations -= 1
                notes.append(f"work_budget: {budget.used} of {budget.total} units spent")
                break
            if not new.solution.usable:
                notes.append(f"solver: {new.solution.status} at iteration {iterations}")
                break
            if not new.solution.accurate:
                notes.append(f"solver: {new.solution.status} at iteration {iterations}")
            step = new
            steps.append(step)
            moved = step.moved
            v_bar, p_bar = step.velocities, step.positions
            lam_bar = step.lam if form.carries_lam else None
            # convergence on the cost without penalties: slacks at OSQP's tolerance times the
            # large penalty would add noise of order eps * rho to J
            small = moved <= STEP_TOL_MPS or abs(step.cost - j_prev) <= tolerance * max(1.0, abs(step.cost))
            j_prev = step.cost
            # the exact recheck decides, unless the iterate needs safety slack and needed the
            # same last time: then the violation is forced (e.g. by the current state) and
            # further iterations only repeat it (they ran to the cap, measured in the corridor)
            slack = step.safety_slack
            if small and (form.recheck(request, step.positions, data.in_range)[1]
                          or (slack > SLACK_TOL and abs(slack - slack_prev) <= SLACK_TOL)):
                converged = True
                break
            slack_prev = slack
        if step is not None:
            ws.last_y = step.solution.y
        if not converged and step is not None and len(notes) == 0:
            notes.append("max_iterations")
        return self._finish(request, data, step, v_bar, v_start, iterations, budget, notes, t0, steps[:-1])

    def qp_step(self, request: PlanRequest, velocities: np.ndarray, lam: np.ndarray | None = None) -> QpStep:
        """Solve the single QP of the SCP linearised at ``velocities`` (N, 3) (and ``lam``).

        Exposed so that tests can compare one QP with an independent model of it.
        """
        ws = self._workspace(request)
        data = RequestData.build(ws.template, self.formulation, request)
        ws.start(data)
        v_bar = np.asarray(velocities, dtype=float)
        p_bar = self.lag.positions(request.position, data.v0, v_bar, request.response_state)
        if self.formulation.carries_lam and lam is None:
            lam = self.formulation.initial_lam(request, p_bar)
        unbudgeted = WorkBudget(UNBUDGETED_WORK)     # one QP for a cross-check, not a replan
        return solve_qp(self.config, self.formulation, ws, data, v_bar, p_bar, lam, unbudgeted, first=True)

    def linearise(self, request: PlanRequest, positions: np.ndarray, lam: np.ndarray | None = None,
                  in_range: np.ndarray | None = None) -> ObstacleRows:
        """Linearised obstacle rows of this planner's formulation around ``positions`` (N, 3)."""
        rows = self.formulation.rows(request, positions, lam)
        if in_range is not None:
            rows = relax_out_of_range(rows, in_range)
        return rows

    @property
    def workspaces(self) -> Mapping[tuple[int, int, int], QpWorkspace]:
        """Read-only view of the per-shape workspaces, keyed by ``(N, P, W)`` (for inspection and tests)."""
        return MappingProxyType(self._workspaces)

    def layout(self, shape: tuple[int, int, int]) -> QpLayout:
        """The QP pattern of a shape ``(N, P, W)`` this planner has solved (KeyError otherwise)."""
        return self._workspaces[shape].layout

    def solver(self, shape: tuple[int, int, int]) -> QpBackend | None:
        """The QP backend of a shape ``(N, P, W)`` (None before its first QP; KeyError for an unseen shape)."""
        return self._workspaces[shape].qp

    def initial_velocities(self, request: PlanRequest, v0: np.ndarray, warm_start: Plan | None) -> np.ndarray:
        """The SCP's first iterate (N, 3), m/s: the shifted warm start, else a line to the target.

        Projected onto the speed and acceleration bounds (forward pass from ``v0``).
        """
        cfg = self.config
        N, tau = cfg.horizon_steps, cfg.step_s
        if warm_start is not None and warm_start.velocities.shape == (N, 3):
            v = np.empty((N, 3))
            v[:-1], v[-1] = warm_start.velocities[1:], warm_start.velocities[-1]
        else:
            # straight line to the target at constant speed, with a small bulge to the right of
            # the route (HEAD_ON_BIAS_M): a head-on encounter on the line is symmetric and the
            # minmax normal along the line only says "stay behind"; the bulge decides the side
            # deterministically, as the rules of the air do (pass right).
            route = request.target - request.position
            v = np.broadcast_to(route / (N * tau), (N, 3)) + _right_bulge_velocities(route, N, tau)
        out = np.ascontiguousarray(v, dtype=float)    # both branches made a new array: projected in place
        v0 = np.ascontiguousarray(v0, dtype=float)
        (_project_forward() if jit.available() else _project_forward.py_func)(out, v0, *self._projection_bounds)
        return out

    # ------------------------------------------------------------------ internals
    def _workspace(self, request: PlanRequest) -> QpWorkspace:
        if not isinstance(request, PlanRequest):
            raise TypeError(f"request must be a PlanRequest, got {type(request).__name__}")
        if request.horizon_steps != self.config.horizon_steps:
            raise InputError(f"request has {request.horizon_steps} steps, the planner is configured "
                             f"for horizon_steps = {self.config.horizon_steps}")
        if request.response_state is not None and not isinstance(self.lag, ResponseModel):
            raise InputError("response_state needs a response model ([planner] vehicle_response); "
                             "this planner models a velocity lag")
        key = (request.horizon_steps, request.num_obstacles, request.num_walls)
        if key not in self._workspaces:
            layout = QpLayout(*key, paper=self.formulation.carries_lam, upper=self.formulation.has_upper,
                              step_s=self.config.step_s, lag=self.lag)
            self._workspaces[key] = QpWorkspace(RequestTemplate(self.config, layout))
            logger.debug("planner: new QP shape N=%d P=%d W=%d (n=%d, m=%d)", *key, layout.n, layout.m)
        return self._workspaces[key]

    def _finish(self, request: PlanRequest, data: RequestData, step: QpStep | None, v_bar: np.ndarray,
                v_start: np.ndarray, iterations: int, budget: WorkBudget, notes: list[str], t0: float,
                earlier: list[QpStep] = ()) -> Plan:
        cfg = self.config
        if step is None:
            velocities = v_bar
            positions = self.lag.positions(request.position, data.v0, velocities, request.response_state)
            slack_max, cost = np.inf, np.nan
        else:
            velocities, positions = step.velocities.copy(), step.positions.copy()
            slack_max = step.safety_slack
            cost = step.objective
            if self.formulation.has_upper:      # else there is no c_max slack (zeros)
                upper = float(step.slack_upper[data.upper_active].max(initial=0.0))
                if upper > C_MAX_SLACK_TOL:
                    notes.append(f"c_max_violated: slack {upper:.3g}")
        if cfg.accel_emergency_mps2 is not None and step is not None and step.least_violation:
            dv = np.abs(np.diff(np.vstack([data.v0[None], velocities]), axis=0)) / cfg.step_s
            if np.any(dv > cfg.accel_max + ACCEL_TOL_MPS2):
                notes.append(f"accel_emergency: up to {float(dv.max()):.2f} m/s^2")
        figs, ok = self.formulation.recheck(request, positions, data.in_range)
        # An unsafe last solution: a least-violation solution (it carries the slack the
        # situation forced) is flown as a slack plan, as without a budget (braking instead
        # in the corridor with c_max: 6 of 8 seeds collided, measured). One that needed no
        # slack yet fails the exact recheck (out of budget, or stopped at the iteration cap
        # on the wrong side of a cycle) gives way to the best safe iterate: the earlier
        # iterates without safety slack, cheapest first, then the SCP's start (the previous
        # plan shifted, within the speed and acceleration bounds); else the plan fails.
        if not ok and step is not None and slack_max <= SLACK_TOL:
            for k, earlier_step in sorted(enumerate(earlier, 1), key=lambda e: e[1].objective):
                if earlier_step.safety_slack > SLACK_TOL:
                    continue
                figs_k, ok = self.formulation.recheck(request, earlier_step.positions, data.in_range)
                if ok:
                    velocities, positions, figs = earlier_step.velocities.copy(), earlier_step.positions.copy(), figs_k
                    slack_max, cost = earlier_step.safety_slack, earlier_step.objective
                    notes.append(f"returned iterate {k} of {iterations} (safe; the last was not)")
                    break
            if not ok:
                start = self.lag.positions(request.position, data.v0, v_start, request.response_state)
                figs_start, ok = self.formulation.recheck(request, start, data.in_range)
                if ok:
                    velocities, positions, figs = v_start.copy(), start, figs_start
                    slack_max, cost = 0.0, np.nan
                    notes.append(("work_budget: " if budget.exhausted else "") + "returned the SCP's starting iterate (safe)")
        # the status comes from the exact figures: slack that only ate into the back-off
        # (formulations.BACKOFF_SIGMA) leaves c_min and the walls holding
        if step is None and budget.exhausted and ok:
            status = "optimal"
            notes.append("work_budget: returned the SCP's starting iterate (safe)")
        elif step is None:
            status = "failed"
        elif ok:
            status = "optimal"
            if slack_max > SLACK_TOL:
                notes.append(f"back-off used: slack {slack_max:.3g}")
        elif slack_max > SLACK_TOL:
            status = "slack"
        else:
            status = "failed"
            notes.append("work_budget: no safe iterate" if budget.exhausted
                         else "exact recheck violated c_min without slack")
        # the cmd rows hold |u| <= v_max to OSQP's tolerance, which 1/(1 - alpha) amplifies
        # (1.5e-4 m/s over, measured): clip so that no setpoint ever exceeds the bound
        commands = self.lag.commands(data.v0, velocities, limit=cfg.velocity_max)
        for a in (velocities, positions, commands):
            a.setflags(write=False)
        plan = Plan(
            velocities=velocities, commands=commands, initial_velocity=data.v0.copy(), positions=positions, eta=figs.eta, contour_of_touch=figs.contour_of_touch,
            overlap=figs.overlap, wall_margin=figs.wall_margin, in_range=data.in_range.copy(), status=status,
            iterations=iterations, solve_time_s=time.perf_counter() - t0, slack_max=slack_max, cost=cost,
            formulation=cfg.formulation, notes=tuple(notes), work=budget.used, admm_iterations=budget.admm_iterations,
            initial_response_state=request.response_state,
        )
        if status != "optimal":
            logger.info("plan %s after %d iterations (slack %.3g; %s)", status, iterations, slack_max, "; ".join(notes))
        return plan
