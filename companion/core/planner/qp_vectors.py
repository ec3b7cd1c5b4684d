"""What an SCP iteration writes into its QP before the solve, and reads from the solution after.

Per QP the SCP writes the linearised obstacle rows (their ``A`` coefficients and bounds,
with the rows of obstacles out of sensing range made inactive and the ``c_max`` side
released where it does not apply), the velocity box (the speed bounds intersected with
the trust region around the iterate) and the slack bounds of the hard QP (safety slacks
pinned to 0, the ``c_max`` slack free): :func:`write_rows`. After the solve it reads the
solution with its slacks clipped at 0 (for the cost), the slacks per row, the largest
safety slack and the largest velocity change from the iterate: :func:`read_solution`.
In numpy each is about a dozen small operations on arrays of a hundred entries, and
each of those, timed inside the replans, costs several microseconds; with numba each is
one loop, otherwise those operations run. Both give the same bytes: copies, products,
``+0.0`` and ``+-inf`` for inactive entries, numpy's ``maximum``/``minimum`` (on a tie
the second operand, NaN propagated), maxima that are one value in any order (or else
numpy's own reduction), which ``tests/core/test_qp_vectors.py`` checks. Units: the rows'
own (metres for the hyperplane rows), velocities in m/s.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core import jit
from companion.core.planner.formulations import ObstacleRows, relax_out_of_range
from companion.core.planner.qp_layout import QpLayout


def _signature(t):
    """Rows (P, N, 3), (P, N), (P, N), masks (P,), the iterate (N, 3), the speed bounds (3,); the QP's vectors out."""
    r1, r2, r3 = jit.readonly(t, 1), jit.readonly(t, 2), jit.readonly(t, 3)
    b1 = t.Array(t.boolean, 1, "C", readonly=True)
    w1, w2, i1 = t.float64[::1], t.float64[:, ::1], t.Array(t.intp, 1, "C", readonly=True)
    return t.void(r3, r2, r2, b1, b1, t.boolean, r2, t.float64, r1, r1, w1, w1, w1,
                  t.intp, t.intp, t.intp, t.intp, t.intp, t.intp, t.intp, i1, w2, w2)


@jit.lazy(_signature)
def _write_rows(coef_p, lower, upper, in_range, upper_active, has_upper, v_bar, trust, v_low, v_high,
                a_slot, l, u, slot_p, row_obs, slot_hi_p, row_hi, row_vbox, row_slack, slack_count, safety,
                v_lo, v_hi):
    """:func:`write_rows` in one loop (the same values as the numpy form there)."""
    inf = math.inf
    n_obs, n_steps = lower.shape[0], lower.shape[1]
    for j in range(n_obs):
        on = in_range[j]
        hi_on = on and upper_active[j]
        for i in range(n_steps):
            k = j * n_steps + i
            for c in range(3):
                value = coef_p[j, i, c] if on else 0.0
                a_slot[slot_p + 3 * k + c] = value
                if has_upper:
                    a_slot[slot_hi_p + 3 * k + c] = value
            l[row_obs + k] = lower[j, i] if on else -inf
            u[row_obs + k] = inf
            if has_upper:
                l[row_hi + k] = -inf
                u[row_hi + k] = upper[j, i] if hi_on else inf
    for i in range(v_bar.shape[0]):
        for c in range(3):
            a, b = v_low[c], v_bar[i, c] - trust
            lo = a if (a > b or a != a) else b
            a, b = v_high[c], v_bar[i, c] + trust
            hi = a if (a < b or a != a) else b
            v_lo[i, c], v_hi[i, c] = lo, hi
            l[row_vbox + 3 * i + c], u[row_vbox + 3 * i + c] = lo, hi
    for k in range(slack_count):
        u[row_slack + k] = inf
    for k in range(safety.shape[0]):
        u[row_slack + safety[k]] = 0.0


def write_rows(layout: QpLayout, rows: ObstacleRows, in_range: np.ndarray, upper_active: np.ndarray,
               v_bar: np.ndarray, trust_mps: float, v_low: np.ndarray, v_high: np.ndarray,
               a_slot: np.ndarray, l: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Write one QP's obstacle rows, velocity box and hard slack bounds into ``a_slot``, ``l``, ``u``.

    ``rows``: the formulation's rows (P, N) as linearised; obstacles not ``in_range`` (P,)
    get zero coefficients and ``(-inf, inf)`` bounds, the ``c_max`` side (when the layout
    has it) is released (``+inf``) where ``upper_active`` (P,) is false. The velocity box is
    ``[max(v_low, v_bar - trust), min(v_high, v_bar + trust)]`` (N, 3), m/s (``v_low``,
    ``v_high``: the speed bounds, (3,)), and is returned.
    Slack rows: upper bound ``+inf``, the safety slacks' 0. The ``paper`` formulation's
    ``lam`` and admissibility entries are not written here.
    """
    N = layout.N
    v_lo, v_hi = np.empty((N, 3)), np.empty((N, 3))
    slack = layout.row["slack"]
    if jit.available():
        _write_rows()(np.ascontiguousarray(rows.coef_p, dtype=float), np.ascontiguousarray(rows.lower, dtype=float),
                      np.ascontiguousarray(rows.upper, dtype=float), np.ascontiguousarray(in_range, dtype=bool),
                      np.ascontiguousarray(upper_active, dtype=bool), layout.upper,
                      np.ascontiguousarray(v_bar, dtype=float), float(trust_mps), v_low, v_high, a_slot, l, u,
                      layout.slot["obs_p"].start, layout.row["obs"].start,
                      layout.slot["obs_hi_p"].start if layout.upper else 0,
                      layout.row["obs_hi"].start if layout.upper else 0,
                      layout.row["vbox"].start, slack.start, slack.size, layout.safety_slacks, v_lo, v_hi)
        return v_lo, v_hi
    rows = relax_out_of_range(rows, in_range)
    a_slot[layout.slot["obs_p"].slice] = rows.coef_p.ravel()
    l[layout.row["obs"].slice], u[layout.row["obs"].slice] = rows.lower.ravel(), np.inf
    if layout.upper:
        a_slot[layout.slot["obs_hi_p"].slice] = rows.coef_p.ravel()
        upper = np.where(upper_active[:, None], rows.upper, np.inf)  # c_max released where masked
        l[layout.row["obs_hi"].slice], u[layout.row["obs_hi"].slice] = -np.inf, upper.ravel()
    np.maximum(v_low, v_bar - trust_mps, out=v_lo)
    np.minimum(v_high, v_bar + trust_mps, out=v_hi)
    l[layout.row["vbox"].slice], u[layout.row["vbox"].slice] = v_lo.ravel(), v_hi.ravel()
    u[slack.slice] = np.inf
    u[slack.start + layout.safety_slacks] = 0.0
    return v_lo, v_hi


def largest_safety_slack(s_lo: np.ndarray, s_wall: np.ndarray, in_range: np.ndarray) -> float:
    """The largest safety slack: of the in-range obstacles' ``s_lo`` (P, N) and of ``s_wall`` (W, N)
    (0.0 without such rows). Each block's largest as numpy's ``maximum.reduce`` gives it (NaN
    propagates; which zero of a tie between +0 and -0 it returns depends on its SIMD lanes),
    then Python's ``max`` of the two (the first unless the second is larger)."""
    arrays = (s_lo[in_range], s_wall)
    return max((float(np.maximum.reduce(a, axis=None)) for a in arrays if a.size), default=0.0)


def _read_signature(t):
    """The solution (n,), slack columns (intp), slack scale, block starts, in-range mask, iterate; readings out."""
    w1, w2, i1 = t.float64[::1], t.float64[:, ::1], t.Array(t.intp, 1, "C", readonly=True)
    return t.boolean(jit.readonly(t, 1), i1, t.float64, t.intp, t.intp, t.intp, t.boolean,
                     t.Array(t.boolean, 1, "C", readonly=True), t.intp, jit.readonly(t, 2),
                     w1, w1, w2, w2, w2, w1)


@jit.lazy(_read_signature)
def _read_solution(x, slack_cols, scale, s_lo_col, s_hi_col, s_wall_col, has_upper, in_range, v_col, v_bar,
                   xc, xs, s_lo, s_hi, s_wall, largest):
    """:func:`read_solution` in one loop (the same values as the numpy form there).

    Writes ``largest[1]``, the step's largest velocity change (a maximum of absolute
    values: one value whatever the order, NaN propagated). Returns whether ``largest[0]``
    is :func:`largest_safety_slack`: not when a block's largest is a zero (its sign is
    numpy's SIMD lanes' choice), nor when there are none.
    """
    for k in range(x.shape[0]):
        xc[k] = x[k]
    moved, nan = 0.0, False
    for i in range(v_bar.shape[0]):
        for c in range(3):
            d = abs(x[v_col + 3 * i + c] - v_bar[i, c])
            if d != d:
                nan = True
            elif d > moved:
                moved = d
    largest[1] = math.nan if nan else moved
    for k in range(slack_cols.shape[0]):
        v = x[slack_cols[k]]
        v = v if (v > 0.0 or v != v) else 0.0
        xc[slack_cols[k]] = v
        xs[k] = v
    n_steps = s_lo.shape[1]
    found, nan, top = False, False, 0.0
    for j in range(s_lo.shape[0]):
        for i in range(n_steps):
            v = scale * x[s_lo_col + j * n_steps + i]
            s_lo[j, i] = v
            s_hi[j, i] = scale * x[s_hi_col + j * n_steps + i] if has_upper else 0.0
            if in_range[j]:
                if v != v:
                    nan = True
                elif not found or v > top:
                    top = v
                found = True
    first, first_found = (math.nan if nan else top), found
    found, nan, top = False, False, 0.0
    for w in range(s_wall.shape[0]):
        for i in range(n_steps):
            v = scale * x[s_wall_col + w * n_steps + i]
            s_wall[w, i] = v
            if v != v:
                nan = True
            elif not found or v > top:
                top = v
            found = True
    second = math.nan if nan else top
    if (first_found and first == 0.0) or (found and second == 0.0) or not (first_found or found):
        return False
    if first_found and found:
        largest[0] = second if second > first else first
    else:
        largest[0] = first if first_found else second
    return True


def read_solution(layout: QpLayout, x: np.ndarray, in_range: np.ndarray, v_bar: np.ndarray) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """What the SCP reads from a QP's solution ``x`` (n,), solved around the velocities ``v_bar`` (N, 3).

    Returns ``xc``: ``x`` with the slack columns clipped at 0 (``np.maximum(x, 0)``, the cost
    is evaluated there); ``xs``: ``xc`` at ``layout.slack_cols``; the slacks in their rows'
    units (the columns times ``slack_scale``): ``s_lo`` (P, N), ``s_hi`` (P, N, zero without
    ``c_max`` rows), ``s_wall`` (W, N); :func:`largest_safety_slack` with ``in_range`` (P,);
    and the largest change of a velocity from ``v_bar``, m/s (``max |V - v_bar|``).
    """
    P, N, W, col, sig = layout.P, layout.N, layout.W, layout.col, layout.slack_scale
    if jit.available():
        xc, xs = np.empty(x.shape[0]), np.empty(layout.slack_cols.shape[0])
        s_lo, s_hi, s_wall, largest = np.empty((P, N)), np.empty((P, N)), np.empty((W, N)), np.empty(2)
        exact = _read_solution()(np.ascontiguousarray(x, dtype=float), layout.slack_cols, float(sig),
                                 col["s_lo"].start, col["s_hi"].start, col["s_wall"].start, layout.upper,
                                 np.ascontiguousarray(in_range, dtype=bool), col["V"].start,
                                 np.ascontiguousarray(v_bar, dtype=float), xc, xs, s_lo, s_hi, s_wall, largest)
        slack = float(largest[0]) if exact else largest_safety_slack(s_lo, s_wall, in_range)
        return xc, xs, s_lo, s_hi, s_wall, slack, float(largest[1])
    xc = x.copy()
    xc[layout.slack_cols] = np.maximum(xc[layout.slack_cols], 0.0)
    s_hi = sig * x[col["s_hi"].slice].reshape(P, N) if layout.upper else np.zeros((P, N))
    s_lo, s_wall = sig * x[col["s_lo"].slice].reshape(P, N), sig * x[col["s_wall"].slice].reshape(W, N)
    moved = float(np.abs(x[col["V"].slice].reshape(N, 3) - v_bar).max())
    return xc, xc[layout.slack_cols], s_lo, s_hi, s_wall, largest_safety_slack(s_lo, s_wall, in_range), moved
