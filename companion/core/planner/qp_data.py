"""Per-request constants of the planner's QP: cost, wall rows, kinematic and command bounds.

Everything here depends on the request, not on the SCP iterate, so it is computed once
per solve (:class:`companion.core.planner.scp.Planner`) and reused by every QP of the SCP.
Cost and row definitions are in :mod:`companion.core.planner.scp` and
:mod:`companion.core.planner.qp_layout`. NED metres, seconds.
"""

from __future__ import annotations

import numpy as np

from dataclasses import dataclass

from companion.core.planner.config import PlannerConfig
from companion.core.planner.formulations import Formulation
from companion.core.planner.qp_layout import QpLayout
from companion.core.planner.request import PlanRequest


@dataclass(frozen=True)
class RequestData:
    """Per-request constants of the QP (cost, walls, kinematic bounds), computed once per solve.

    Immutable (arrays read-only): the SCP copies what it changes per iteration into its
    workspace (:class:`companion.core.planner.qp_step.QpWorkspace`). Build with :meth:`build`.

    Attributes
    ----------
    request : the request these constants belong to.
    v0 : (3,) ``V_0`` clipped so that the first step's bounds can hold, m/s.
    p_data : ``P`` data in CSC order of the pattern (cost of the hard and soft QPs).
    q, q_hard : (n,) linear cost with the slacks penalised / with the safety slacks unpenalised.
    constant : cost constant, so that the objective includes the terminal and jerk constants.
    a_slot : ``A`` data in slot order with the constants and wall normals (obstacle rows zero).
    l, u : (m,) bounds that do not depend on the iterate (the rest are rewritten per QP).
    wall_upper : (W, N) right-hand sides of the wall rows, metres.
    in_range : (P,) obstacles within sensing range (constrained).
    upper_active : (P,) obstacles the ``c_max`` bound applies to.
    y_warm : (m,) duals of the previous replan shifted by one step, or None (cold start).
    """

    request: PlanRequest
    v0: np.ndarray
    p_data: np.ndarray
    q: np.ndarray
    q_hard: np.ndarray
    constant: float
    a_slot: np.ndarray
    l: np.ndarray
    u: np.ndarray
    wall_upper: np.ndarray
    in_range: np.ndarray
    upper_active: np.ndarray
    y_warm: np.ndarray | None

    def __post_init__(self) -> None:
        for value in vars(self).values():
            if isinstance(value, np.ndarray) and value.flags.writeable:
                value.setflags(write=False)

    @classmethod
    def build(cls, config: PlannerConfig, formulation: Formulation, layout: QpLayout, request: PlanRequest,
              y_warm: np.ndarray | None = None) -> RequestData:
        """Constants of ``request`` for ``layout`` (``y_warm``: shifted duals of the previous replan)."""
        cfg = config
        N, tau = layout.N, cfg.step_s
        vmax, amax = cfg.velocity_max, cfg.accel_max
        # V_0 clipped so that |V_1 - V_0| <= a tau and |V_1| <= v_max can hold together
        v0 = np.clip(request.velocity, -vmax - amax * tau, vmax + amax * tau)
        # terminal: w_t (p_N - g)' M (p_N - g), M = S_N^-1  ->  P += 2 w_t M, q += -2 w_t M g
        m = np.linalg.inv(request.drone_covs[-1])
        m = 0.5 * (m + m.T)
        wt, wj, wv = cfg.weight_terminal, cfg.weight_jerk, cfg.weight_velocity
        jerk_scale = 2.0 * wj / tau**4
        # progress: (w_p / N) sum_i (p_i - g)' M (p_i - g): without it the plan only has to be
        # at the target at step N, so each replan arrives "N steps from now" and the drone
        # closes in asymptotically
        wp = cfg.weight_progress / N
        p_data = layout.p_data(jerk_scale, 2.0 * wv, 2.0 * wt * m, 2.0 * wp * m)
        # jerk: |D2 V + c|^2 / tau^4 per axis with c_0 = V_0  ->  q += 2 w_j/tau^4 D2' c
        c = np.zeros((N - 1, 3))
        c[0] = v0
        q = np.zeros(layout.n)
        q[layout.col["V"].slice] = (jerk_scale * (layout.d2_t @ c)).ravel()
        pn = layout.col["p"].start + 3 * (N - 1)
        q[layout.col["p"].slice] = np.tile(-2.0 * wp * (m @ request.target), N)
        q[pn:pn + 3] += -2.0 * wt * (m @ request.target)
        for name in ("s_lo", "e_pos", "e_neg", "s_wall"):
            q[layout.col[name].slice] = cfg.slack_penalty * layout.slack_scale   # variable = slack / slack_scale
        q[layout.col["s_hi"].slice] = cfg.c_max_penalty * layout.slack_scale
        q_hard = q.copy()                               # q: soft, slacks penalised
        q_hard[layout.slack_cols[layout.safety_slacks]] = 0.0   # hard: safety slacks pinned to 0
        constant = (wt + wp * N) * request.target @ m @ request.target + wj / tau**4 * float(np.sum(c * c))
        # A: constants plus wall normals (fixed for this request)
        a_slot = layout.a_data0.copy()
        if layout.W:
            a_slot[layout.slot["wall_p"].slice] = np.broadcast_to(
                request.walls_normal[:, None, :], (layout.W, N, 3)).ravel()
        # bounds that do not depend on the iterate
        l = np.zeros(layout.m)
        u = np.zeros(layout.m)
        dyn = layout.lag.free_increments(v0, N)           # p_1 - b V_1 = p_0 + c V_0 for the lag
        dyn[0] += request.position
        l[layout.row["dyn"].slice] = u[layout.row["dyn"].slice] = dyn.ravel()
        acc = np.broadcast_to(amax * tau, (N, 3)).copy()
        lo_acc, hi_acc = -acc, acc.copy()
        lo_acc[0] += v0
        hi_acc[0] += v0
        if not layout.lag.bounds_command_steps:       # a response model: the autopilot limits acceleration
            lo_acc[:], hi_acc[:] = -np.inf, np.inf
        l[layout.row["accel"].slice], u[layout.row["accel"].slice] = lo_acc.ravel(), hi_acc.ravel()
        if layout.row["cmd"].size:          # commands within the speed bound: (1 - a) |u_i| <= (1 - a) v_max
            alpha = layout.lag.alpha
            cmd = np.broadcast_to((1.0 - alpha) * vmax, (N, 3)).copy()
            lo_cmd, hi_cmd = -cmd, cmd.copy()
            lo_cmd[0] += alpha * v0
            hi_cmd[0] += alpha * v0
            l[layout.row["cmd"].slice], u[layout.row["cmd"].slice] = lo_cmd.ravel(), hi_cmd.ravel()
        # walls: a.p_i - s <= b - r sqrt(a' S_i a) - R_drone
        wall_upper = formulation.wall_upper(request)
        l[layout.row["wall"].slice] = -np.inf
        u[layout.row["wall"].slice] = wall_upper.ravel()
        l[layout.row["slack"].slice], u[layout.row["slack"].slice] = 0.0, np.inf
        # sensing range: distance from the drone now to each obstacle's first predicted mean
        if request.num_obstacles:
            dist = np.linalg.norm(request.obstacle_means[:, 0, :] - request.position, axis=-1)
            in_range = dist <= cfg.sensing_range_m
        else:
            in_range = np.zeros(0, dtype=bool)
        upper_active = in_range & request.upper_bound_mask  # obstacles c_max applies to
        return cls(request=request, v0=v0, p_data=p_data, q=q, q_hard=q_hard, constant=constant, a_slot=a_slot,
                   l=l, u=u, wall_upper=wall_upper, in_range=in_range, upper_active=upper_active, y_warm=y_warm)
