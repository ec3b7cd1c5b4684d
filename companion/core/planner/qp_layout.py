"""Fixed sparsity layout of the SCP's quadratic program (set up once per problem shape).

Decision vector ``x`` (blocks in this order; ``i`` step 0..N-1, ``k`` axis, ``j`` obstacle,
``w`` wall; row-major within a block)::

    V      (N, 3)   vehicle velocities at the step ends, m/s (the commands without lag)
    p      (N, 3)   positions p_1..p_N, NED metres
    s_lo   (P, N)   safety slack of the obstacle rows (>= 0, L1-penalised)
    s_hi   (P, N)   slack of the c_max side of the obstacle rows (only with c_max)
    lam    (P, N)   overlap parameters (``paper`` only)
    e_pos  (P, N)   slack of the admissibility rows, both signs (``paper`` only)
    e_neg  (P, N)
    s_wall (W, N)   safety slack of the wall rows

Constraint rows ``l <= A x <= u``::

    dyn    (N, 3)   p_i - p_{i-1} - sum_k h_k V_{i-k} = f_i v_0  (p_0, V_0 current -> l = u; h, f of the
                    vehicle model, :mod:`companion.core.planner.vehicle_model`: the lag has h = (b, c),
                    b = tau, c = 0 without lag; a :class:`ResponseModel` has N terms, V the commands)
    vbox   (N, 3)   V_i in [-v_max, v_max] ∩ trust region around the iterate
    accel  (N, 3)   V_i - V_{i-1} in [-a_max tau, a_max tau]   (V_0 = current velocity)
    cmd    (N, 3)   V_i - alpha V_{i-1} in (1 - alpha) [-v_max, v_max]: the command u_i within
                    the speed bound (only with a velocity lag, alpha > 0)
    obs    (P, N)   c . p_i (+ c_lam lam) + s_lo >= l      (formulation-specific)
    obs_hi (P, N)   c . p_i (+ c_lam lam) - s_hi <= u      (the c_max side; only with c_max)
    adm    (P, N)   g_p . p_i + g_lam lam + e_pos - e_neg = rhs    (``paper`` only)
    lambox (P, N)   lam in [eps, 1 - eps] ∩ trust region           (``paper`` only)
    wall   (W, N)   a_w . p_i - s_wall <= b_w - r_min sqrt(a' S_i a) - R_drone
    slack           every slack >= 0

Slack columns may be scaled (``slack_scale``: the row coefficient, the variable being
``slack / slack_scale``). The planner keeps 1: scaling the penalty out of ``q`` tightens
OSQP's relative dual tolerance but, when slack is really needed, it drove OSQP's adaptive
``rho`` to 1e-6 and the solve to its iteration cap (measured).

Keeping positions as variables (with the ``dyn`` equalities) keeps every obstacle and
wall row at three position nonzeros instead of ``3 i`` velocity nonzeros. The nonzero
pattern never changes: coefficients that the linearisation sets are written into fixed
slots of a data vector in this module's order, then permuted once into CSC order
(:attr:`QpLayout.a_perm`) for OSQP's in-place ``update(Ax=...)``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from companion.core.planner.vehicle_model import LagModel, VehicleModel

logger = logging.getLogger(__name__)


def _csc_pattern(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSC ``indices``, ``indptr`` of a COO pattern and ``perm`` with ``csc_data = coo_data[perm]``.

    The COO entries must be distinct; each carries its own position + 1 as a marker, so
    the CSC conversion reveals where it went.
    """
    marker = np.arange(1, rows.size + 1, dtype=float)
    m = sp.csc_matrix((marker, (rows, cols)), shape=shape)
    m.sort_indices()
    if m.nnz != rows.size:
        raise RuntimeError("duplicate entries in the QP pattern")  # a bug in this module
    return m.indices.astype(np.int64), m.indptr.astype(np.int64), m.data.astype(np.int64) - 1


@dataclass(frozen=True)
class Block:
    """A contiguous range ``[start, start + size)`` of columns, rows or data slots."""

    start: int
    size: int

    @property
    def slice(self) -> slice:
        return slice(self.start, self.start + self.size)

    @property
    def indices(self) -> np.ndarray:
        return np.arange(self.start, self.start + self.size)


def _blocks(sizes: list[tuple[str, int]]) -> tuple[dict[str, Block], int]:
    """Consecutive blocks of the given sizes, by name, and their total size."""
    blocks: dict[str, Block] = {}
    start = 0
    for name, size in sizes:
        blocks[name] = Block(start, size)
        start += size
    return blocks, start


class QpLayout:
    """Index bookkeeping and constant entries of the QP for one shape.

    Parameters
    ----------
    n_steps, n_obstacles, n_walls : int
        ``N``, ``P``, ``W``.
    paper : bool
        Whether the ``lam``/admissibility blocks exist (``paper`` formulation).
    upper : bool
        Whether the obstacle rows carry a ``c_max`` side (``s_hi`` block).
    step_s : float
        ``tau``, seconds (the step of the default ``lag``).
    lag : LagModel or ResponseModel, optional
        The vehicle's velocity response (``dyn`` coefficients ``h_k``); default no lag
        (``h_0 = tau``).
    slack_scale : float
        Coefficient ``1/rho`` of the slack columns in their rows.
    """

    def __init__(self, n_steps: int, n_obstacles: int, n_walls: int, *, paper: bool, upper: bool, step_s: float,
                 lag: VehicleModel | None = None, slack_scale: float = 1.0) -> None:
        N, P, W = n_steps, n_obstacles, n_walls
        self.N, self.P, self.W, self.paper, self.upper = N, P, W, paper, upper
        self.lag = lag if lag is not None else LagModel.from_time_constant(step_s, 0.0)
        self.slack_scale = slack_scale
        PN = P * N
        # ---- columns
        sizes = [("V", 3 * N), ("p", 3 * N), ("s_lo", PN), ("s_hi", PN if upper else 0),
                 ("lam", PN if paper else 0), ("e_pos", PN if paper else 0), ("e_neg", PN if paper else 0),
                 ("s_wall", W * N)]
        self.col, self.n = _blocks(sizes)
        slack_names = ("s_lo", "s_hi", "e_pos", "e_neg", "s_wall")
        self.slack_cols = np.concatenate([self.col[s].indices for s in slack_names])
        #: the safety slacks (all but ``s_hi``), as positions within ``slack_cols``
        self.safety_slacks = np.flatnonzero(~np.isin(self.slack_cols, self.col["s_hi"].indices))
        # ---- rows
        lagged = self.lag.alpha > 0.0
        rsizes = [("dyn", 3 * N), ("vbox", 3 * N), ("accel", 3 * N), ("cmd", 3 * N if lagged else 0),
                  ("obs", PN), ("obs_hi", PN if upper else 0), ("adm", PN if paper else 0),
                  ("lambox", PN if paper else 0), ("wall", W * N), ("slack", self.slack_cols.size)]
        self.row, self.m = _blocks(rsizes)
        self._build_shift()
        self._build_a()
        self._build_p()

    def _build_shift(self) -> None:
        """``shift_rows``: row index of step ``i + 1`` for each row of step ``i`` (the last step repeats).

        Used to carry OSQP's dual solution over to the next receding-horizon problem.
        """
        N, W = self.N, self.W

        def shifted(count: int, lead: int, tail: int) -> np.ndarray:
            idx = np.arange(count).reshape(lead, N, tail) if count else np.zeros((0, N, tail), dtype=np.int64)
            return np.concatenate([idx[:, 1:], idx[:, -1:]], axis=1).ravel()

        parts = []
        for name in ("dyn", "vbox", "accel", "cmd"):
            if self.row[name].size:
                parts.append(self.row[name].start + shifted(3 * N, 1, 3))
        for name in ("obs", "obs_hi", "adm", "lambox"):
            size = self.row[name].size
            parts.append(self.row[name].start + shifted(size, size // N if size else 0, 1))
        parts.append(self.row["wall"].start + shifted(W * N, W, 1))
        start = self.row["slack"].start
        for name in ("s_lo", "s_hi", "e_pos", "e_neg", "s_wall"):
            size = self.col[name].size
            parts.append(start + shifted(size, size // N if size else 0, 1))
            start += size
        self.shift_rows = np.concatenate(parts).astype(np.int64)
        if self.shift_rows.size != self.m:
            raise RuntimeError("row shift map does not cover every row")  # a bug in this module

    # ------------------------------------------------------------------ constraint matrix
    def _build_a(self) -> None:
        N, P, W, slack_scale = self.N, self.P, self.W, self.slack_scale
        V, p = self.col["V"].start, self.col["p"].start
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        self.slot: dict[str, Block] = {}

        def add(name: str | None, r: np.ndarray, c: np.ndarray, v: np.ndarray | float) -> None:
            r, c = np.asarray(r, dtype=np.int64).ravel(), np.asarray(c, dtype=np.int64).ravel()
            if name is not None:
                self.slot[name] = Block(sum(x.size for x in rows), r.size)
            rows.append(r)
            cols.append(c)
            vals.append(np.broadcast_to(np.asarray(v, dtype=float), r.shape).copy())

        e3 = np.arange(3 * N)               # flat (i, k) index
        later = np.arange(3, 3 * N)          # entries with a predecessor step
        # dyn: p_i - p_{i-1} - b V_i - c V_{i-1} = 0 (V_0 is data: it goes to the bounds)
        r0 = self.row["dyn"].start
        # and, with a richer vehicle response, - h_k V_{i-k} for every earlier command (a fixed
        # lower-triangular band per axis; the lag has h_0 = b, h_1 = c)
        add(None, r0 + e3, p + e3, 1.0)
        add(None, r0 + later, p + later - 3, -1.0)
        for k, h in enumerate(self.lag.increment_coefficients(N)[:N]):
            if k == 0 or np.any(h != 0.0):
                add(None, r0 + e3[3 * k:], V + e3[:3 * (N - k)], -np.tile(h, N - k))
        # vbox: V_i
        add(None, self.row["vbox"].start + e3, V + e3, 1.0)
        # accel: V_i - V_{i-1}
        r0 = self.row["accel"].start
        add(None, r0 + e3, V + e3, 1.0)
        add(None, r0 + later, V + later - 3, -1.0)
        # cmd: V_i - alpha V_{i-1} = (1 - alpha) u_i, the command (only with a velocity lag)
        if self.row["cmd"].size:
            r0 = self.row["cmd"].start
            add(None, r0 + e3, V + e3, 1.0)
            add(None, r0 + later, V + later - 3, -self.lag.alpha)
        # obs: c . p_i (+ c_lam lam) + s_lo >= l ; obs_hi: c . p_i (+ c_lam lam) - s_hi <= u. Two rows,
        # not one row with both slacks: the columns +s_lo and -s_hi of one row are collinear
        # and OSQP left both positive together (measured)
        jn = np.arange(P * N)                          # flat (j, i)
        step = jn % N
        p_cols = p + (3 * step[:, None] + np.arange(3)).ravel()
        r0 = self.row["obs"].start
        add("obs_p", np.repeat(r0 + jn, 3), p_cols, 0.0)
        add(None, r0 + jn, self.col["s_lo"].start + jn, slack_scale)
        if self.upper:
            rh = self.row["obs_hi"].start
            add("obs_hi_p", np.repeat(rh + jn, 3), p_cols, 0.0)
            add(None, rh + jn, self.col["s_hi"].start + jn, -slack_scale)
        if self.paper:
            lam = self.col["lam"].start
            add("obs_lam", r0 + jn, lam + jn, 0.0)
            if self.upper:
                add("obs_hi_lam", rh + jn, lam + jn, 0.0)
            r1 = self.row["adm"].start
            add("adm_p", np.repeat(r1 + jn, 3), p + (3 * step[:, None] + np.arange(3)).ravel(), 0.0)
            add("adm_lam", r1 + jn, lam + jn, 0.0)
            add(None, r1 + jn, self.col["e_pos"].start + jn, slack_scale)
            add(None, r1 + jn, self.col["e_neg"].start + jn, -slack_scale)
            add(None, self.row["lambox"].start + jn, lam + jn, 1.0)
        # wall: a . p_i - s_wall
        wn = np.arange(W * N)
        r0 = self.row["wall"].start
        add("wall_p", np.repeat(r0 + wn, 3), p + (3 * (wn % N)[:, None] + np.arange(3)).ravel(), 0.0)
        add(None, r0 + wn, self.col["s_wall"].start + wn, -slack_scale)
        # slack >= 0
        add(None, self.row["slack"].start + np.arange(self.slack_cols.size), self.slack_cols, 1.0)

        r, c = np.concatenate(rows), np.concatenate(cols)
        self.a_data0 = np.concatenate(vals)
        self.a_indices, self.a_indptr, self.a_perm = _csc_pattern(r, c, (self.m, self.n))

    def a_csc_data(self, slot_data: np.ndarray) -> np.ndarray:
        """``A`` data in CSC order from a vector in this layout's slot order."""
        return slot_data[self.a_perm]

    def a_matrix_csc(self, csc_data: np.ndarray) -> sp.csc_matrix:
        """CSC constraint matrix from data already in CSC order."""
        return sp.csc_matrix((csc_data, self.a_indices, self.a_indptr), shape=(self.m, self.n))

    # ------------------------------------------------------------------ cost matrix
    def _build_p(self) -> None:
        """Upper-triangular pattern: velocity block (jerk + effort) and terminal 3x3 block."""
        N = self.N
        # jerk operator on one axis: (D2 V)_r = V_{r+1} - 2 V_r + V_{r-1}, r = 0..N-2, V_{-1} = v0
        d2 = sp.diags([np.ones(N - 1), -2.0 * np.ones(N - 1)], [1, 0], shape=(N - 1, N)).tolil()
        d2[np.arange(1, N - 1), np.arange(0, N - 2)] = 1.0
        self.d2 = sp.csr_matrix(d2)
        self.d2_t = self.d2.T      # (N, N-1) CSC, for the jerk term's q at every request
        dtd = sp.kron(self.d2.T @ self.d2, sp.eye(3)).tocoo()
        keep = dtd.row <= dtd.col
        vr, vc, vv = dtd.row[keep], dtd.col[keep], dtd.data[keep]
        diag = np.arange(3 * N)
        # velocity block pattern = pattern of D2'D2 (x) I3 plus the diagonal (effort term)
        key = np.unique(np.concatenate([vr * (3 * N) + vc, diag * (3 * N) + diag]))
        self.p_vel_rows, self.p_vel_cols = key // (3 * N), key % (3 * N)
        lookup = {int(k): idx for idx, k in enumerate(key)}
        self.p_vel_jerk = np.zeros(key.size)
        for r_, c_, v_ in zip(vr, vc, vv):            # setup only, O(N) entries
            self.p_vel_jerk[lookup[int(r_ * (3 * N) + c_)]] += v_
        self.p_vel_diag = np.isin(key, diag * (3 * N) + diag).astype(float)
        # position blocks p_1..p_N (upper triangle of 3x3): progress cost on every step,
        # plus the terminal cost on p_N
        tr, tc = np.triu_indices(3)
        self.p_term_idx = (tr, tc)
        starts = self.col["p"].start + 3 * np.arange(N)
        rows = np.concatenate([self.p_vel_rows, (starts[:, None] + tr).ravel()])
        cols = np.concatenate([self.p_vel_cols, (starts[:, None] + tc).ravel()])
        self.p_n_vel = key.size
        self.p_indices, self.p_indptr, self.p_perm = _csc_pattern(rows, cols, (self.n, self.n))
        # where each entry lands in the CSC data: the velocity block's, and the position blocks' (N, 6)
        rank = np.empty_like(self.p_perm)
        rank[self.p_perm] = np.arange(self.p_perm.size)
        self.p_vel_slots = rank[:key.size]
        self.p_block_slots = rank[key.size:].reshape(N, tr.size)

    def p_data(self, jerk_scale: float, effort_scale: float, terminal: np.ndarray,
               stage: np.ndarray | None = None) -> np.ndarray:
        """P data (CSC order) for ``0.5 x'Px``.

        Parameters
        ----------
        jerk_scale : float
            Multiplies ``D2'D2 (x) I3`` on the velocity block.
        effort_scale : float
            Multiplies the identity on the velocity block.
        terminal : (3, 3) array
            Hessian block on ``p_N`` (symmetric; its upper triangle is used).
        stage : (3, 3) array, optional
            Hessian block on every ``p_i`` (progress cost), added to the terminal block on ``p_N``.
        """
        data = np.empty(self.p_perm.size)
        data[self.p_vel_slots] = jerk_scale * self.p_vel_jerk + effort_scale * self.p_vel_diag
        self.write_p_blocks(data, terminal, stage)
        return data

    def write_p_blocks(self, data: np.ndarray, terminal: np.ndarray, stage: np.ndarray | None = None) -> None:
        """Write the position blocks of :meth:`p_data` into ``data`` (CSC order) in place: ``stage``
        (zero if None) on every ``p_i``, ``stage + terminal`` on ``p_N`` (upper triangles)."""
        tr, tc = self.p_term_idx
        blocks = np.zeros(self.p_block_slots.shape)
        if stage is not None:
            blocks[:] = stage[tr, tc]
        blocks[-1] += terminal[tr, tc]
        data[self.p_block_slots] = blocks

    def p_matrix(self, data_csc: np.ndarray) -> sp.csc_matrix:
        return sp.csc_matrix((data_csc, self.p_indices, self.p_indptr), shape=(self.n, self.n))
