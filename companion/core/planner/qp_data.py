"""Per-request constants of the planner's QP: cost, wall rows, kinematic and command bounds.

Everything here depends on the request, not on the SCP iterate, so it is computed once
per solve (:class:`companion.core.planner.scp.Planner`) and reused by every QP of the SCP.
Cost and row definitions are in :mod:`companion.core.planner.scp` and
:mod:`companion.core.planner.qp_layout`. NED metres, seconds.
"""

from __future__ import annotations

import numpy as np

from companion.core.planner import formulations as F
from companion.core.planner.config import PlannerConfig
from companion.core.planner.qp_layout import QpLayout
from companion.core.planner.request import PlanRequest


class RequestData:
    """Per-request constants of the QP (cost, walls, kinematic bounds), computed once per solve.

    Parameters
    ----------
    config : PlannerConfig
    r_min : float
        Touch radius of ``c_min`` (the wall rows use it).
    layout : QpLayout
        The pattern of this request's shape.
    request : PlanRequest
    """

    def __init__(self, config: PlannerConfig, r_min: float, layout: QpLayout, request: PlanRequest) -> None:
        cfg = config
        N, tau = layout.N, cfg.step_s
        vmax, amax = cfg.velocity_max, cfg.accel_max
        # V_0 clipped so that |V_1 - V_0| <= a tau and |V_1| <= v_max can hold together
        self.v0 = np.clip(request.velocity, -vmax - amax * tau, vmax + amax * tau)
        # terminal: w_t (p_N - g)' M (p_N - g), M = S_N^-1  ->  P += 2 w_t M, q += -2 w_t M g
        m = np.linalg.inv(request.drone_covs[-1])
        m = 0.5 * (m + m.T)
        wt, wj, wv = cfg.weight_terminal, cfg.weight_jerk, cfg.weight_velocity
        jerk_scale = 2.0 * wj / tau**4
        # progress: (w_p / N) sum_i (p_i - g)' M (p_i - g): without it the plan only has to be
        # at the target at step N, so each replan arrives "N steps from now" and the drone
        # closes in asymptotically
        wp = cfg.weight_progress / N
        self.p_data = layout.p_data(jerk_scale, 2.0 * wv, 2.0 * wt * m, 2.0 * wp * m)
        # jerk: |D2 V + c|^2 / tau^4 per axis with c_0 = V_0  ->  q += 2 w_j/tau^4 D2' c
        c = np.zeros((N - 1, 3))
        c[0] = self.v0
        q = np.zeros(layout.n)
        q[layout.col["V"].slice] = (jerk_scale * (layout.d2.T @ c)).ravel()
        pn = layout.col["p"].start + 3 * (N - 1)
        q[layout.col["p"].slice] = np.tile(-2.0 * wp * (m @ request.target), N)
        q[pn:pn + 3] += -2.0 * wt * (m @ request.target)
        for name in ("s_lo", "e_pos", "e_neg", "s_wall"):
            q[layout.col[name].slice] = cfg.slack_penalty * layout.slack_scale   # variable = slack / slack_scale
        q[layout.col["s_hi"].slice] = cfg.c_max_penalty * layout.slack_scale
        self.q = q                                       # soft: slacks penalised
        self.q_hard = q.copy()
        self.q_hard[layout.slack_cols[layout.safety_slacks]] = 0.0   # hard: safety slacks pinned to 0
        self.constant = (wt + wp * N) * request.target @ m @ request.target + wj / tau**4 * float(np.sum(c * c))
        # A: constants plus wall normals (fixed for this request)
        self.a_slot = layout.a_data0.copy()
        if layout.W:
            self.a_slot[layout.slot["wall_p"].slice] = np.broadcast_to(
                request.walls_normal[:, None, :], (layout.W, N, 3)).ravel()
        # bounds that do not depend on the iterate
        self.l = np.zeros(layout.m)
        self.u = np.zeros(layout.m)
        dyn = layout.lag.free_increments(self.v0, N)           # p_1 - b V_1 = p_0 + c V_0 for the lag
        dyn[0] += request.position
        self.l[layout.row["dyn"].slice] = self.u[layout.row["dyn"].slice] = dyn.ravel()
        acc = np.broadcast_to(amax * tau, (N, 3)).copy()
        lo_acc, hi_acc = -acc, acc.copy()
        lo_acc[0] += self.v0
        hi_acc[0] += self.v0
        if not layout.lag.bounds_command_steps:       # a response model: the autopilot limits acceleration
            lo_acc[:], hi_acc[:] = -np.inf, np.inf
        self.l[layout.row["accel"].slice], self.u[layout.row["accel"].slice] = lo_acc.ravel(), hi_acc.ravel()
        if layout.row["cmd"].size:          # commands within the speed bound: (1 - a) |u_i| <= (1 - a) v_max
            alpha = layout.lag.alpha
            cmd = np.broadcast_to((1.0 - alpha) * vmax, (N, 3)).copy()
            lo_cmd, hi_cmd = -cmd, cmd.copy()
            lo_cmd[0] += alpha * self.v0
            hi_cmd[0] += alpha * self.v0
            self.l[layout.row["cmd"].slice], self.u[layout.row["cmd"].slice] = lo_cmd.ravel(), hi_cmd.ravel()
        # walls: a.p_i - s <= b - r sqrt(a' S_i a) - R_drone
        r_wall = 0.0 if cfg.formulation == "deterministic" else r_min + F.BACKOFF_SIGMA
        spread = np.sqrt(np.einsum("wk,nkl,wl->wn", request.walls_normal, request.drone_covs, request.walls_normal))
        self.wall_upper = request.walls_offset[:, None] - r_wall * spread - cfg.drone_radius_m
        if cfg.formulation == "deterministic":
            self.wall_upper = self.wall_upper - F.BACKOFF_M
        self.l[layout.row["wall"].slice] = -np.inf
        self.u[layout.row["wall"].slice] = self.wall_upper.ravel()
        self.l[layout.row["slack"].slice], self.u[layout.row["slack"].slice] = 0.0, np.inf
        # sensing range: distance from the drone now to each obstacle's first predicted mean
        if request.num_obstacles:
            dist = np.linalg.norm(request.obstacle_means[:, 0, :] - request.position, axis=-1)
            self.in_range = dist <= cfg.sensing_range_m
        else:
            self.in_range = np.zeros(0, dtype=bool)
        self.upper_active = self.in_range & request.upper_bound_mask  # obstacles c_max applies to
        self.y_warm: np.ndarray | None = None
