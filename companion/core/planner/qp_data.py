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


class RequestTemplate:
    """What :meth:`RequestData.build` writes that depends on the configuration and the QP shape only.

    Built once per planner and shape (the planner's workspace holds it), so that a request
    pays only for its own parts. :meth:`RequestData.build` fills those in with the
    operations that built the whole vectors before, so every value is the same to the bit.

    Attributes
    ----------
    config, layout : the planner's configuration and the QP pattern.
    v0_low, v0_high : (3,) the clip of ``V_0`` (``v_max + a_max tau`` each way), m/s.
    velocity_low, velocity_high : (3,) the speed bound ``-v_max``, ``v_max``, m/s.
    weight_progress : the progress weight per step, ``w_p / N``.
    jerk_scale : ``2 w_j / tau^4``, the jerk term's factor in ``P`` and ``q``.
    q, q_hard : (n,) the linear cost with the slack penalties (``q_hard``: the safety
        slacks unpenalised) and zero on ``V`` and ``p``.
    l, u : (m,) the bounds with the request's rows (``dyn``, walls' upper side) zero and
        the first acceleration and command rows without ``V_0``.
    q_slack : ``q`` at the slack columns (``layout.slack_cols``): the slack penalties, the
        same in every request's ``q``.
    """

    def __init__(self, config: PlannerConfig, layout: QpLayout) -> None:
        cfg = config
        N, tau = layout.N, cfg.step_s
        vmax, amax = cfg.velocity_max, cfg.accel_max
        self.config, self.layout = cfg, layout
        self.v0_low, self.v0_high = -vmax - amax * tau, vmax + amax * tau
        self.velocity_low, self.velocity_high = -vmax, vmax
        self.weight_progress = cfg.weight_progress / N
        self.jerk_scale = 2.0 * cfg.weight_jerk / tau**4
        self._p_data = layout.p_data(self.jerk_scale, 2.0 * cfg.weight_velocity, np.zeros((3, 3)))
        # D2' c with c = (V_0, 0, ..., 0) touches only D2's first column
        self._jerk_column = layout.d2_t[:, [0]].toarray()
        q = np.zeros(layout.n)
        for name in ("s_lo", "e_pos", "e_neg", "s_wall"):
            q[layout.col[name].slice] = cfg.slack_penalty * layout.slack_scale   # variable = slack / slack_scale
        q[layout.col["s_hi"].slice] = cfg.c_max_penalty * layout.slack_scale
        q_hard = q.copy()                               # q: soft, slacks penalised
        q_hard[layout.slack_cols[layout.safety_slacks]] = 0.0   # hard: safety slacks pinned to 0
        l, u = np.zeros(layout.m), np.zeros(layout.m)
        acc = np.broadcast_to(amax * tau, (N, 3)).copy()
        lo_acc, hi_acc = -acc, acc.copy()
        if not layout.lag.bounds_command_steps:       # a response model: the autopilot limits acceleration
            lo_acc[:], hi_acc[:] = -np.inf, np.inf
        l[layout.row["accel"].slice], u[layout.row["accel"].slice] = lo_acc.ravel(), hi_acc.ravel()
        if layout.row["cmd"].size:          # commands within the speed bound: (1 - a) |u_i| <= (1 - a) v_max
            cmd = np.broadcast_to((1.0 - layout.lag.alpha) * vmax, (N, 3)).copy()
            l[layout.row["cmd"].slice], u[layout.row["cmd"].slice] = -cmd.ravel(), cmd.ravel()
        l[layout.row["wall"].slice] = -np.inf
        l[layout.row["slack"].slice], u[layout.row["slack"].slice] = 0.0, np.inf
        self.q, self.q_hard, self.l, self.u = q, q_hard, l, u
        self.q_slack = q[layout.slack_cols]       # every request's q there (build writes V and p only)
        for value in (self.v0_low, self.v0_high, self.velocity_low, self.velocity_high, self._p_data,
                      self._jerk_column, q, q_hard, l, u, self.q_slack):
            value.setflags(write=False)

    def p_data(self, terminal: np.ndarray, stage: np.ndarray) -> np.ndarray:
        """``P`` data (CSC order) with the Hessian blocks ``stage`` (3, 3) on every ``p_i`` and
        ``stage + terminal`` on ``p_N``: :meth:`QpLayout.p_data` of this template's velocity block."""
        data = self._p_data.copy()
        self.layout.write_p_blocks(data, terminal, stage)
        return data

    def jerk_q(self, v0: np.ndarray) -> np.ndarray:
        """``D2' c`` (N, 3) for ``c = (V_0, 0, ..., 0)``, as scipy's sparse product sums it (from +0)."""
        return 0.0 + self._jerk_column * v0


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
        for value in (self.v0, self.p_data, self.q, self.q_hard, self.a_slot, self.l, self.u, self.wall_upper,
                      self.in_range, self.upper_active, self.y_warm):
            if value is not None and value.flags.writeable:
                value.setflags(write=False)

    @classmethod
    def build(cls, template: RequestTemplate, formulation: Formulation, request: PlanRequest,
              y_warm: np.ndarray | None = None) -> RequestData:
        """Constants of ``request`` on ``template`` (its configuration and layout; ``y_warm``: shifted duals)."""
        cfg, layout = template.config, template.layout
        N, tau = layout.N, cfg.step_s
        # V_0 clipped so that |V_1 - V_0| <= a tau and |V_1| <= v_max can hold together
        v0 = np.clip(request.velocity, template.v0_low, template.v0_high)
        # terminal: w_t (p_N - g)' M (p_N - g), M = S_N^-1  ->  P += 2 w_t M, q += -2 w_t M g
        m = np.linalg.inv(request.drone_covs[-1])
        m = 0.5 * (m + m.T)
        wt, wj, wp = cfg.weight_terminal, cfg.weight_jerk, template.weight_progress
        # progress: (w_p / N) sum_i (p_i - g)' M (p_i - g): without it the plan only has to be
        # at the target at step N, so each replan arrives "N steps from now" and the drone
        # closes in asymptotically
        p_data = template.p_data(2.0 * wt * m, 2.0 * wp * m)
        q, q_hard = template.q.copy(), template.q_hard.copy()
        # jerk: |D2 V + c|^2 / tau^4 per axis with c_0 = V_0, the rest 0  ->  q += 2 w_j/tau^4 D2' c
        q_v = template.jerk_scale * template.jerk_q(v0)
        goal = m @ request.target
        q_p = np.empty((N, 3))
        q_p[:] = -2.0 * wp * goal
        q_p[-1] += -2.0 * wt * goal
        for vec in (q, q_hard):        # the two differ in the slack penalties only (in the template)
            vec[layout.col["V"].slice] = q_v.ravel()
            vec[layout.col["p"].slice] = q_p.ravel()
        # |c|^2 = |V_0|^2, summed as numpy sums c * c
        v0_sq = float(v0[0] * v0[0] + v0[1] * v0[1]) + float(v0[2] * v0[2])
        constant = (wt + wp * N) * request.target @ m @ request.target + wj / tau**4 * v0_sq
        # A: constants plus wall normals (fixed for this request)
        a_slot = layout.a_data0.copy()
        if layout.W:
            a_slot[layout.slot["wall_p"].slice].reshape(layout.W, N, 3)[:] = request.walls_normal[:, None, :]
        # bounds: the template's, with V_0, p_0 and the walls of this request
        l, u = template.l.copy(), template.u.copy()
        dyn = layout.lag.free_increments(v0, N)           # p_1 - b V_1 = p_0 + c V_0 for the lag
        dyn[0] += request.position
        l[layout.row["dyn"].slice] = u[layout.row["dyn"].slice] = dyn.ravel()
        if layout.lag.bounds_command_steps:       # else a response model: the autopilot limits acceleration
            first = slice(layout.row["accel"].start, layout.row["accel"].start + 3)
            l[first] += v0
            u[first] += v0
        if layout.row["cmd"].size:          # commands within the speed bound: (1 - a) |u_i| <= (1 - a) v_max
            first = slice(layout.row["cmd"].start, layout.row["cmd"].start + 3)
            l[first] += layout.lag.alpha * v0
            u[first] += layout.lag.alpha * v0
        # walls: a.p_i - s <= b - r sqrt(a' S_i a) - R_drone
        wall_upper = formulation.wall_upper(request)
        u[layout.row["wall"].slice] = wall_upper.ravel()
        # sensing range: distance from the drone now to each obstacle's first predicted mean
        if request.num_obstacles:
            d = request.obstacle_means[:, 0, :] - request.position
            dist = np.sqrt(np.add.reduce(d * d, axis=-1))     # numpy's norm over the last axis, without its checks
            in_range = dist <= cfg.sensing_range_m
        else:
            in_range = np.zeros(0, dtype=bool)
        upper_active = in_range & request.upper_bound_mask  # obstacles c_max applies to
        return cls(request=request, v0=v0, p_data=p_data, q=q, q_hard=q_hard, constant=constant, a_slot=a_slot,
                   l=l, u=u, wall_upper=wall_upper, in_range=in_range, upper_active=upper_active, y_warm=y_warm)
