"""PIQP behind the planner's QP interface (``[planner] solver = "piqp"``).

PIQP (proximal interior point, sparse; Schwan, Jiang, Kuhn and Jones, 2023) solves
``min 0.5 x'Px + c'x  s.t.  Ax = b, h_l <= Gx <= h_u``. The planner writes its QPs as
OSQP does, ``l <= Ax <= u`` on one fixed pattern (:class:`companion.core.planner.qp_layout.QpLayout`),
so each solve splits the rows: ``l = u`` (finite) are equalities, rows with no finite bound
(obstacles out of sensing range) are left out, the rest are two-sided inequalities. Which
rows are equalities changes within a replan (the hard QP pins the safety slacks, the
least-violation QPs free or cap them), so one PIQP solver is kept per split and updated in
place (numerical refactorisation only) when a split comes back; a new split is a new
``setup`` (symbolic analysis too). At most :data:`MAX_SPLITS` are kept per shape.

The solver study (docs/SOLVERS.md) chose it for the tail: on the planner's recorded QPs
no failure, every infeasible QP proved infeasible, and a p99 per QP of 0.10x OSQP's. It has
no warm start (an interior-point method starts from its own central point), so
:meth:`PiqpQp.warm_start` does nothing, and its time hardly depends on the QP.

Work: one PIQP iteration (a factorisation of the KKT system and a few solves) is charged
:data:`WORK_PER_ITERATION` units of the replan's budget (:mod:`companion.core.planner.budget`),
the ADMM iterations an OSQP solve of these QPs gets for the same time (measured in
``tests/benchmarks/bench_backends.py``). A ``max_iter`` given in work units becomes
``max_iter // WORK_PER_ITERATION`` PIQP iterations.
"""

from __future__ import annotations

import logging
import math
import time
from collections import OrderedDict

import numpy as np

from companion.core.planner.full_hessian import FullHessian
from companion.core.planner.osqp_qp import QpSolution
from companion.core.planner.qp_layout import QpLayout

logger = logging.getLogger(__name__)

#: Work units charged per PIQP iteration (ADMM iterations of OSQP taking the same time on
#: the planner benchmark's QPs; tests/benchmarks/bench_backends.py measures it).
WORK_PER_ITERATION = 10
#: Splits (sets of equality rows) kept per QP shape; the least recently used goes first.
MAX_SPLITS = 8
#: A bound at or beyond this magnitude is no bound (OSQP's infinity is 1e30).
INFINITE_BOUND = 1e20


class _Split:
    """One PIQP solver for a set of equality and inequality rows, with the index maps from
    the full ``A`` data (CSC order of the layout) to its ``A`` and ``G`` data."""

    def __init__(self, markers, eq: np.ndarray, ineq: np.ndarray) -> None:
        """``markers``: the layout's ``A`` (CSR) holding ``k + 1`` at the ``k``-th entry of its CSC data."""
        self.eq, self.ineq = eq, ineq
        self.a_eq = markers[eq].tocsc()
        self.g = markers[ineq].tocsc()
        self.map_eq = self.a_eq.data.astype(np.intp) - 1
        self.map_g = self.g.data.astype(np.intp) - 1
        self.solver = None           # set up at the first solve
        self.max_iter = -1


class PiqpQp:
    """A PIQP solver bound to one :class:`QpLayout`, with :class:`companion.core.planner.osqp_qp.OsqpQp`'s interface.

    Parameters
    ----------
    layout : QpLayout
        The fixed pattern.
    p_data, a_data : arrays
        Initial ``P`` (upper triangle) and ``A`` data in CSC order of the pattern.
    q, l, u : arrays
        Initial vectors (``±inf`` or beyond :data:`INFINITE_BOUND`: no bound).
    eps, eps_rel : float
        PIQP's ``eps_abs`` and ``eps_rel`` (primal and dual residuals).
    polish, rho : ignored
        OSQP's settings, accepted so that the backends are made alike.
    """

    work_per_iteration = WORK_PER_ITERATION

    def __init__(self, layout: QpLayout, p_data: np.ndarray, q: np.ndarray, a_data: np.ndarray,
                 l: np.ndarray, u: np.ndarray, *, eps: float, eps_rel: float, polish: bool = False,
                 rho: float = 0.0) -> None:
        import piqp     # here, so that an OSQP-only planner never loads it

        self._piqp = piqp
        self.layout = layout
        self._eps, self._eps_rel = float(eps), float(eps_rel)
        self.hessian = FullHessian(layout, p_data)
        self._p = layout.p_matrix(np.array(p_data, dtype=float))
        self._q = np.array(q, dtype=float)
        self._a_data = np.array(a_data, dtype=float)
        self._l = np.array(l, dtype=float)
        self._u = np.array(u, dtype=float)
        self._splits: OrderedDict[bytes, _Split] = OrderedDict()
        # A with each entry's place in the CSC data (+1), in rows: every split's maps come from it
        self._markers = layout.a_matrix_csc(np.arange(1.0, len(layout.a_indices) + 1.0)).tocsr()
        self.setups = 0           # new PIQP set-ups (a split seen for the first time, or evicted)

    def p_times(self, x: np.ndarray) -> np.ndarray:
        """``P x`` with the full symmetric ``P`` (the objective's ``x'Px``)."""
        return self.hessian.times(x)

    def update(self, *, p_data: np.ndarray | None = None, q: np.ndarray | None = None,
               a_data: np.ndarray | None = None, l: np.ndarray | None = None, u: np.ndarray | None = None) -> None:
        """New data on the same pattern (``None`` leaves a piece unchanged); PIQP sees it at the next solve."""
        if p_data is not None:
            self.hessian.update(p_data)
            self._p.data[:] = p_data
        if q is not None:
            self._q[:] = q
        if a_data is not None:
            self._a_data[:] = a_data
        if l is not None:
            self._l[:] = l
        if u is not None:
            self._u[:] = u

    def warm_start(self, x: np.ndarray | None = None, y: np.ndarray | None = None) -> None:
        """Nothing: PIQP starts every solve from its own initial point."""

    def solve(self, max_iter: int = 10000) -> QpSolution:
        """Solve within ``max_iter`` work units (``max_iter // WORK_PER_ITERATION`` PIQP iterations, at least 1).

        Never raises on a solver status (the caller reads ``usable``). ``iterations`` is PIQP's.
        """
        piqp = self._piqp
        t0 = time.perf_counter()
        l, u = self._l, self._u
        lo_finite, hi_finite = l > -INFINITE_BOUND, u < INFINITE_BOUND
        eq_mask = lo_finite & hi_finite & (l == u)
        ineq_mask = ~eq_mask & (lo_finite | hi_finite)
        split = self._split(eq_mask, ineq_mask)
        a_eq, g = split.a_eq, split.g
        np.take(self._a_data, split.map_eq, out=a_eq.data)
        np.take(self._a_data, split.map_g, out=g.data)
        b = u[split.eq]
        h_l = np.where(lo_finite[split.ineq], l[split.ineq], -np.inf)
        h_u = np.where(hi_finite[split.ineq], u[split.ineq], np.inf)
        iterations = max(1, int(max_iter) // WORK_PER_ITERATION)
        s = split.solver
        if s is None:
            s = split.solver = piqp.SparseSolver()
            s.settings.verbose = False
            s.settings.eps_abs, s.settings.eps_rel = self._eps, self._eps_rel
            # the duality gap to the same tolerances (PIQP: 1e-8, 1e-9): 3.8 iterations a QP on
            # the planner benchmark against 6.2, measured
            s.settings.eps_duality_gap_abs, s.settings.eps_duality_gap_rel = self._eps, self._eps_rel
            # a split's later QPs are the same rows relinearised: its first scaling serves them
            # (benchmark replan median 0.89x, corridor p99 0.96x, the same flights; measured)
            s.settings.preconditioner_reuse_on_update = True
            s.settings.max_iter = split.max_iter = iterations
            s.setup(self._p, self._q, a_eq, b, g, h_l, h_u)
            self.setups += 1
        else:
            if iterations != split.max_iter:
                s.settings.max_iter = split.max_iter = iterations
            s.update(P=self._p, c=self._q, A=a_eq, b=b, G=g, h_l=h_l, h_u=h_u)
        t1 = time.perf_counter()
        status = s.solve()
        t2 = time.perf_counter()
        r = s.result
        x = np.array(r.x, dtype=float)     # a copy: PIQP's result is overwritten by its next solve
        y = np.zeros(self.layout.m)
        y[split.eq] = r.y
        y[split.ineq] = np.asarray(r.z_u) - np.asarray(r.z_l)
        solved = status == piqp.PIQP_SOLVED and bool(np.isfinite(x).all())
        objective = 0.5 * float(x @ self.hessian.times(x)) + float(self._q @ x) if solved else math.nan
        return QpSolution(x=x, y=y, objective=objective, status=_status_text(status), usable=solved,
                          accurate=solved, iterations=int(r.info.iter), solve_time_s=t2 - t1, update_time_s=t1 - t0)

    def _split(self, eq_mask: np.ndarray, ineq_mask: np.ndarray) -> _Split:
        key = np.packbits(eq_mask).tobytes() + np.packbits(ineq_mask).tobytes()
        split = self._splits.get(key)
        if split is None:
            split = _Split(self._markers, np.flatnonzero(eq_mask), np.flatnonzero(ineq_mask))
            self._splits[key] = split
            if len(self._splits) > MAX_SPLITS:
                self._splits.popitem(last=False)
        else:
            self._splits.move_to_end(key)
        return split


def _status_text(status) -> str:
    """``'solved'``, ``'max_iter_reached'``, ... from PIQP's status enum."""
    return str(status).rsplit(".", 1)[-1].removeprefix("PIQP_").lower()
