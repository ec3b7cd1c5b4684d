"""Per-request constants of the planner's QP: cost, wall rows, kinematic and command bounds.

Everything here depends on the request, not on the SCP iterate, so it is computed once
per solve (:class:`companion.core.planner.scp.Planner`) and reused by every QP of the SCP.
Cost and row definitions are in :mod:`companion.core.planner.scp` and
:mod:`companion.core.planner.qp_layout`. NED metres, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.core import jit
from companion.core.planner.config import PlannerConfig
from companion.core.planner.formulations import Formulation
from companion.core.planner.qp_layout import QpLayout
from companion.core.planner.request import PlanRequest
from companion.core.planner.vehicle_model import LagModel
from estimator.linalg import inverse


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
        # D2' c with c = (V_0, 0, ..., 0) touches only D2's first column, (N,)
        self.jerk_column = np.ascontiguousarray(layout.d2_t[:, [0]].toarray()[:, 0])
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
        #: how far the least-violation QPs widen each acceleration row, m/s (None: not at all)
        self.accel_widening = None
        if cfg.accel_emergency_mps2 is not None and layout.lag.bounds_command_steps:
            widen = (np.asarray(cfg.accel_emergency_mps2, dtype=float) - amax) * tau
            self.accel_widening = np.ascontiguousarray(np.broadcast_to(widen, (N, 3)).ravel())
        if layout.row["cmd"].size:          # commands within the speed bound: (1 - a) |u_i| <= (1 - a) v_max
            cmd = np.broadcast_to((1.0 - layout.lag.alpha) * vmax, (N, 3)).copy()
            l[layout.row["cmd"].slice], u[layout.row["cmd"].slice] = -cmd.ravel(), cmd.ravel()
        l[layout.row["wall"].slice] = -np.inf
        l[layout.row["slack"].slice], u[layout.row["slack"].slice] = 0.0, np.inf
        self.q, self.q_hard, self.l, self.u = q, q_hard, l, u
        self.q_slack = q[layout.slack_cols]       # every request's q there (build writes V and p only)
        # for RequestData's compiled pass: where P's position blocks go (the layout's indices as intp)
        self.p_block_entries = tuple(np.array(a, dtype=np.intp) for a in (*layout.p_term_idx, layout.p_block_slots))
        for value in (self.v0_low, self.v0_high, self.velocity_low, self.velocity_high, self._p_data,
                      self.jerk_column, q, q_hard, l, u, self.q_slack, *self.p_block_entries):
            value.setflags(write=False)

    def p_data(self, terminal: np.ndarray, stage: np.ndarray) -> np.ndarray:
        """``P`` data (CSC order) with the Hessian blocks ``stage`` (3, 3) on every ``p_i`` and
        ``stage + terminal`` on ``p_N``: :meth:`QpLayout.p_data` of this template's velocity block."""
        data = self._p_data.copy()
        self.layout.write_p_blocks(data, terminal, stage)
        return data

    def jerk_q(self, v0: np.ndarray) -> np.ndarray:
        """``D2' c`` (N, 3) for ``c = (V_0, 0, ..., 0)``, as scipy's sparse product sums it (from +0)."""
        return 0.0 + self.jerk_column[:, None] * v0


def _fill_signature(t):
    """The request's numbers and the template's vectors and indices in; the request's vectors out."""
    r1, r2, r3 = jit.readonly(t, 1), jit.readonly(t, 2), jit.readonly(t, 3)
    i1, i2 = t.Array(t.intp, 1, "C", readonly=True), t.Array(t.intp, 2, "C", readonly=True)
    b1, w1, wb = t.Array(t.boolean, 1, "C", readonly=True), t.float64[::1], t.boolean[::1]
    f, n, yes = t.float64, t.intp, t.boolean
    return t.void(r1, r1, r1, r2, r1, f, f, f, f,                  # velocity, clip, m, goal, weights
                  r1, i1, i1, i2,                                  # P: template data, block entries and slots
                  f, r1, r1, r1, n, n,                             # q: jerk scale and column, templates, V and p
                  r1, r2, n, n,                                    # A: constants, wall normals, wall slot, N
                  r1, r1, f, r1, n, yes, n, yes, f, n,             # l, u: templates, dyn, accel, cmd rows
                  r3, r1, b1,                                      # means, ranges, c_max mask
                  w1, w1, w1, w1, w1, w1, w1, wb, wb)              # out: v0, P, q, q_hard, A, l, u, masks


@jit.lazy(_fill_signature)
def _fill(velocity, v0_low, v0_high, m, goal, stage_scale, terminal_scale, progress_q, terminal_q,
          p_data0, term_r, term_c, block_slots,
          jerk_scale, jerk_column, q0, q_hard0, v_col, p_col,
          a_data0, walls_normal, wall_slot, n_steps,
          l0, u0, lag_c, position, dyn_row, accel, accel_row, cmd, alpha, cmd_row,
          means, ranges, upper_mask,
          v0, p_data, q, q_hard, a_slot, l, u, in_range, upper_active):
    """:meth:`RequestData.build`'s elementwise work for a :class:`LagModel`, in one pass.

    The operations of the numpy form there, in its order: ``np.clip`` of ``V_0``; ``P``'s
    position blocks ``stage`` on every step and ``stage + terminal`` on the last
    (``scale * m``); the jerk term ``jerk_scale (0 + D2[:, 0] V_0)``; ``q_p = (-2 w_p) g``
    with ``(-2 w_t) g`` added on the last step; the wall normals in ``A``; the dynamics rows
    ``c V_0 + p_0`` (then zeros), ``V_0`` added to the first acceleration rows and
    ``alpha V_0`` to the first command rows; each obstacle's range ``sqrt((dx^2 + dy^2) + dz^2) <= range``.
    """
    for k in range(3):
        x = velocity[k]
        if x == x:                       # np.clip: NaN kept, else the bound when beyond it
            x = x if x > v0_low[k] else v0_low[k]
            x = x if x < v0_high[k] else v0_high[k]
        v0[k] = x
    for e in range(p_data0.shape[0]):
        p_data[e] = p_data0[e]
    last = block_slots.shape[0] - 1
    for b in range(block_slots.shape[0]):
        for e in range(term_r.shape[0]):
            value = stage_scale * m[term_r[e], term_c[e]]
            if b == last:
                value = value + terminal_scale * m[term_r[e], term_c[e]]
            p_data[block_slots[b, e]] = value
    for e in range(q0.shape[0]):
        q[e], q_hard[e] = q0[e], q_hard0[e]
    for i in range(n_steps):
        for k in range(3):
            value = jerk_scale * (0.0 + jerk_column[i] * v0[k])
            q[v_col + 3 * i + k] = q_hard[v_col + 3 * i + k] = value
            value = progress_q * goal[k]
            if i == n_steps - 1:
                value = value + terminal_q * goal[k]
            q[p_col + 3 * i + k] = q_hard[p_col + 3 * i + k] = value
    for e in range(a_data0.shape[0]):
        a_slot[e] = a_data0[e]
    for w in range(walls_normal.shape[0]):
        for i in range(n_steps):
            for k in range(3):
                a_slot[wall_slot + 3 * (w * n_steps + i) + k] = walls_normal[w, k]
    for e in range(l0.shape[0]):
        l[e], u[e] = l0[e], u0[e]
    for i in range(n_steps):
        for k in range(3):
            value = lag_c * v0[k] + position[k] if i == 0 else 0.0
            l[dyn_row + 3 * i + k] = u[dyn_row + 3 * i + k] = value
    for k in range(3):
        if accel:
            l[accel_row + k] = l[accel_row + k] + v0[k]
            u[accel_row + k] = u[accel_row + k] + v0[k]
        if cmd:
            shift = alpha * v0[k]
            l[cmd_row + k] = l[cmd_row + k] + shift
            u[cmd_row + k] = u[cmd_row + k] + shift
    for j in range(means.shape[0]):
        dx, dy, dz = means[j, 0, 0] - position[0], means[j, 0, 1] - position[1], means[j, 0, 2] - position[2]
        in_range[j] = math.sqrt((dx * dx + dy * dy) + dz * dz) <= ranges[j]
        upper_active[j] = in_range[j] and upper_mask[j]


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
        """Constants of ``request`` on ``template`` (its configuration and layout; ``y_warm``: shifted duals).

        The inverse (numpy's LAPACK call, through :func:`estimator.linalg.inverse`), the matrix
        products and the walls' spread are numpy's (LAPACK, BLAS and ``einsum`` fix their
        bits); the elementwise rest is one compiled pass for a lag model
        (:func:`_elementwise_compiled`) and numpy's operations otherwise
        (:func:`_elementwise_numpy`), the same bits.
        """
        cfg, layout = template.config, template.layout
        N, tau = layout.N, cfg.step_s
        # terminal: w_t (p_N - g)' M (p_N - g), M = S_N^-1  ->  P += 2 w_t M, q += -2 w_t M g
        m = inverse(request.drone_covs[-1])    # np.linalg.inv's bits without its Python layer
        m = 0.5 * (m + m.T)
        wt, wj, wp = cfg.weight_terminal, cfg.weight_jerk, template.weight_progress
        goal = m @ request.target
        compiled = jit.available() and isinstance(layout.lag, LagModel)
        fill = _elementwise_compiled if compiled else _elementwise_numpy
        v0, p_data, q, q_hard, a_slot, l, u, in_range, upper_active = fill(template, request, m, goal)
        # |c|^2 = |V_0|^2, summed as numpy sums c * c
        v0_sq = float(v0[0] * v0[0] + v0[1] * v0[1]) + float(v0[2] * v0[2])
        constant = (wt + wp * N) * request.target @ m @ request.target + wj / tau**4 * v0_sq
        # walls: a.p_i - s <= b - r sqrt(a' S_i a) - R_drone
        wall_upper = formulation.wall_upper(request)
        u[layout.row["wall"].slice] = wall_upper.ravel()
        return cls(request=request, v0=v0, p_data=p_data, q=q, q_hard=q_hard, constant=constant, a_slot=a_slot,
                   l=l, u=u, wall_upper=wall_upper, in_range=in_range, upper_active=upper_active, y_warm=y_warm)


def obstacle_ranges(request: PlanRequest, cfg: PlannerConfig) -> np.ndarray:
    """(P,) how far out each obstacle of ``request`` is planned around, m: the request's own
    ranges, else the planner's ``sensing_range_m`` for all."""
    if request.obstacle_ranges_m is not None:
        return request.obstacle_ranges_m
    return np.full(request.num_obstacles, float(cfg.sensing_range_m))


def _elementwise_numpy(template: RequestTemplate, request: PlanRequest, m: np.ndarray, goal: np.ndarray) -> tuple:
    """``(v0, p_data, q, q_hard, a_slot, l, u, in_range, upper_active)`` of :meth:`RequestData.build`
    with numpy's operations (``m``: the symmetrised inverse of the terminal covariance, ``goal``:
    ``m`` times the target; the rows of the walls' upper side are left for build)."""
    cfg, layout = template.config, template.layout
    N = layout.N
    wt, wp = cfg.weight_terminal, template.weight_progress
    # V_0 clipped so that |V_1 - V_0| <= a tau and |V_1| <= v_max can hold together
    v0 = np.clip(request.velocity, template.v0_low, template.v0_high)
    # progress: (w_p / N) sum_i (p_i - g)' M (p_i - g): without it the plan only has to be
    # at the target at step N, so each replan arrives "N steps from now" and the drone
    # closes in asymptotically
    p_data = template.p_data(2.0 * wt * m, 2.0 * wp * m)
    q, q_hard = template.q.copy(), template.q_hard.copy()
    # jerk: |D2 V + c|^2 / tau^4 per axis with c_0 = V_0, the rest 0  ->  q += 2 w_j/tau^4 D2' c
    q_v = template.jerk_scale * template.jerk_q(v0)
    q_p = np.empty((N, 3))
    q_p[:] = -2.0 * wp * goal
    q_p[-1] += -2.0 * wt * goal
    for vec in (q, q_hard):        # the two differ in the slack penalties only (in the template)
        vec[layout.col["V"].slice] = q_v.ravel()
        vec[layout.col["p"].slice] = q_p.ravel()
    # A: constants plus wall normals (fixed for this request)
    a_slot = layout.a_data0.copy()
    if layout.W:
        a_slot[layout.slot["wall_p"].slice].reshape(layout.W, N, 3)[:] = request.walls_normal[:, None, :]
    # bounds: the template's, with V_0 and p_0 of this request (the walls' are written by build)
    l, u = template.l.copy(), template.u.copy()
    dyn = layout.lag.free_increments(v0, N, request.response_state)   # p_1 - b V_1 = p_0 + c V_0 for the lag
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
    # range: distance from the drone now to each obstacle's first predicted mean
    if request.num_obstacles:
        d = request.obstacle_means[:, 0, :] - request.position
        dist = np.sqrt(np.add.reduce(d * d, axis=-1))     # numpy's norm over the last axis, without its checks
        in_range = dist <= obstacle_ranges(request, cfg)
    else:
        in_range = np.zeros(0, dtype=bool)
    upper_active = in_range & request.upper_bound_mask  # obstacles c_max applies to
    return v0, p_data, q, q_hard, a_slot, l, u, in_range, upper_active


def _elementwise_compiled(template: RequestTemplate, request: PlanRequest, m: np.ndarray, goal: np.ndarray) -> tuple:
    """:func:`_elementwise_numpy` for a lag model, in one compiled pass (:func:`_fill`)."""
    cfg, layout, lag = template.config, template.layout, template.layout.lag
    wt, wp = cfg.weight_terminal, template.weight_progress
    v0, p_data = np.empty(3), np.empty(template._p_data.size)
    q, q_hard, a_slot = np.empty(layout.n), np.empty(layout.n), np.empty(layout.a_data0.size)
    l, u = np.empty(layout.m), np.empty(layout.m)
    in_range, upper_active = np.empty(request.num_obstacles, dtype=bool), np.empty(request.num_obstacles, dtype=bool)
    _fill()(np.ascontiguousarray(request.velocity, dtype=float), template.v0_low, template.v0_high,
            np.ascontiguousarray(m), np.ascontiguousarray(goal, dtype=float), 2.0 * wp, 2.0 * wt,
            -2.0 * wp, -2.0 * wt, template._p_data, *template.p_block_entries,
            template.jerk_scale, template.jerk_column, template.q, template.q_hard,
            layout.col["V"].start, layout.col["p"].start,
            layout.a_data0, np.ascontiguousarray(request.walls_normal, dtype=float),
            layout.slot["wall_p"].start if layout.W else 0, layout.N,
            template.l, template.u, float(lag.c), np.ascontiguousarray(request.position, dtype=float),
            layout.row["dyn"].start, bool(lag.bounds_command_steps), layout.row["accel"].start,
            bool(layout.row["cmd"].size), float(lag.alpha), layout.row["cmd"].start,
            np.ascontiguousarray(request.obstacle_means, dtype=float), obstacle_ranges(request, cfg),
            np.ascontiguousarray(request.upper_bound_mask, dtype=bool),
            v0, p_data, q, q_hard, a_slot, l, u, in_range, upper_active)
    return v0, p_data, q, q_hard, a_slot, l, u, in_range, upper_active
