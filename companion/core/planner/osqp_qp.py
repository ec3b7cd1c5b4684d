"""OSQP behind a small interface: set up once per shape, then update in place and solve.

The QP is ``min 0.5 x'Px + q'x  s.t.  l <= Ax <= u`` with ``P`` upper-triangular CSC
(OSQP 1.x). Matrix data are passed in CSC order of the fixed pattern of
:class:`companion.core.planner.qp_layout.QpLayout`, so ``update(Px=..., Ax=...)`` only
refactors numerically.

Three settings differ from OSQP's defaults: the initial ``rho`` (below) and these two,
chosen on the planner benchmark's receding-horizon replans (8 scenes, 472 warm-started
replans, ``hyperplane``; ADMM iterations per replan, all QPs of its SCP):

- ``rho`` is restored to its initial value before every solve. OSQP adapts ``rho`` within
  a solve and keeps it for the next; the SCP's next QP (a new linearisation, often a new
  active set) then started from a step size tuned to the previous one. With OSQP's
  defaults (scaled, ``rho`` carried over) the 99th percentile was 357 and the largest 850.
- ``scaling=0``: the variables are already in physical units of similar size (m/s, m,
  unit-gradient rows, slacks scaled by ``QpLayout.slack_scale``). With the reset but
  Ruiz scaling on: p99 490, largest 900; with both settings: median 50, p99 150,
  largest 200. Each solve now depends only on its own data and warm start.

``rho`` starts at 0.4 (``PlannerConfig.solver_rho``; it was 0.1 until 3 December 2026).
Measured with 0.1 and 0.4 on the same flights:

- 60 lockstep campaign episodes of each family (seed 1, episodes 0 to 59,
  ``hyperplane``): ADMM iterations per replan 6.6 to 9.3 % fewer on average (antipodal
  141 -> 129, crossing 162 -> 149, random 140 -> 127, corridor 142 -> 133), their p99
  the same or lower (1,250 -> 1,225, 1,405 -> 1,400, 1,050 -> 950, 1,050 -> 950); no
  collision either way, failed plans 2 -> 0, replans with slack 3 -> 4, the goal in 180
  of 180 open-field episodes either way and in 12 and 11 of the 60 corridor ones within
  their 40 s;
- the corridor demo with ``c_max``, seeds 0 to 3: 8.6 % fewer in all (seed 0 3.5 % more);
- the planner benchmark (8 scenes, 3 rounds taking turns): p99 replan 2.20 to 2.63 ms
  against 2.51 to 3.72 ms, with the same median and replan / OSQP ratio.

OSQP's convergence check stays at its default, every 25 ADMM iterations. Every 10 was
measured twice (docs/PERFORMANCE.md): the median replan 0.82x, but the p99 0.97x (the
slowest QPs need 150 to 175 iterations either way) and more time around the solver than in
it per replan.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import osqp

from companion.core.planner.full_hessian import FullHessian
from companion.core.planner.qp_layout import QpLayout

logger = logging.getLogger(__name__)

#: Default cap on ADMM iterations per solve.
MAX_ITER = 10000

_SOLVED = {osqp.SolverStatus.OSQP_SOLVED}
_ACCEPTABLE = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}


@dataclass(frozen=True)
class QpSolution:
    """One OSQP solve.

    Attributes
    ----------
    x : (n,) primal solution (a copy).
    y : (m,) dual solution (a copy).
    objective : ``0.5 x'Px + q'x`` at ``x`` (without constants).
    status : OSQP's status text.
    usable : whether the status is solved or solved-inaccurate.
    accurate : whether the status is solved.
    iterations : ADMM iterations.
    solve_time_s : OSQP's own time for this solve (its ``info.solve_time``), seconds; a
        diagnostic only (benchmarks compare the replan time with it).
    update_time_s : OSQP's own time in the updates since the previous solve (its
        ``info.update_time``: new data, the numerical refactorisation of the KKT matrix
        after new ``P`` or ``A`` values or ``rho``), seconds; a diagnostic likewise.
    """

    x: np.ndarray
    y: np.ndarray
    objective: float
    status: str
    usable: bool
    accurate: bool
    iterations: int
    solve_time_s: float = 0.0
    update_time_s: float = 0.0


class OsqpQp:
    """An OSQP solver bound to one :class:`QpLayout`.

    Parameters
    ----------
    layout : QpLayout
        The fixed pattern.
    p_data, a_data : arrays
        Initial ``P`` and ``A`` data in CSC order of the pattern.
    q, l, u : arrays
        Initial vectors.
    eps, eps_rel : float
        ``eps_abs`` and ``eps_rel``.
    polish : bool
        OSQP solution polishing.
    rho : float
        Initial ADMM step size, restored before every solve (``PlannerConfig.solver_rho``).
    """

    def __init__(self, layout: QpLayout, p_data: np.ndarray, q: np.ndarray, a_data: np.ndarray,
                 l: np.ndarray, u: np.ndarray, *, eps: float, eps_rel: float, polish: bool,
                 rho: float) -> None:
        self.layout = layout
        self._rho = rho
        self._rho_adapted = False
        self._max_iter = MAX_ITER
        self.hessian = FullHessian(layout, p_data)     # the full P, for the objective's x'Px
        self._solver = osqp.OSQP()
        self._solver.setup(
            layout.p_matrix(p_data), q, layout.a_matrix_csc(a_data), l, u,
            eps_abs=eps, eps_rel=eps_rel, eps_prim_inf=1e-6, eps_dual_inf=1e-6, polishing=polish, verbose=False,
            warm_starting=True, max_iter=MAX_ITER, adaptive_rho=True, scaling=0, rho=rho,
        )
        self._direct = _extension_solver(self._solver)
        self._infinity = float(self._solver.constant("OSQP_INFTY"))

    #: Work units per iteration of this backend (:mod:`companion.core.planner.budget`): one per ADMM iteration.
    work_per_iteration = 1

    def p_times(self, x: np.ndarray) -> np.ndarray:
        """``P x`` with the full symmetric ``P`` (the objective's ``x'Px``), summed as scipy's CSR product sums it."""
        return self.hessian.times(x)

    def update(self, *, p_data: np.ndarray | None = None, q: np.ndarray | None = None,
               a_data: np.ndarray | None = None, l: np.ndarray | None = None, u: np.ndarray | None = None) -> None:
        """Update data in place (same pattern); ``None`` leaves a piece unchanged."""
        if p_data is not None:
            self.hessian.update(p_data)
        vectors = q is not None or l is not None or u is not None
        matrices = p_data is not None or a_data is not None
        ext = self._direct
        if ext is None:
            given = {"q": q, "l": l, "u": u, "Px": p_data, "Ax": a_data}
            if vectors or matrices:
                self._solver.update(**{k: v for k, v in given.items() if v is not None})
            return
        # what osqp.OSQP.update passes on: l and u clipped to OSQP's infinity, vectors before matrices
        if vectors:
            ext.update_data_vec(q=q, l=None if l is None else np.maximum(l, -self._infinity),
                                u=None if u is None else np.minimum(u, self._infinity))
        if matrices:
            ext.update_data_mat(P_x=p_data, P_i=None, A_x=a_data, A_i=None)

    def warm_start(self, x: np.ndarray | None = None, y: np.ndarray | None = None) -> None:
        """Set the starting primal (and dual) point of the next solve."""
        (self._direct or self._solver).warm_start(x, y)

    def solve(self, max_iter: int = MAX_ITER) -> QpSolution:
        """Solve from ``rho`` within ``max_iter`` ADMM iterations.

        Never raises on a solver status (the caller reads ``usable``).
        """
        ext = self._direct
        if self._rho_adapted:         # a refactorisation, so only when the last solve moved rho
            if ext is None:
                self._solver.update_settings(rho=self._rho)
            else:
                ext.update_rho(self._rho)
        if max_iter != self._max_iter:
            self._solver.update_settings(max_iter=max_iter)
            self._max_iter = max_iter
        if ext is None:
            r = self._solver.solve(raise_error=False)
            info, x, y = r.info, np.array(r.x, dtype=float), np.array(r.y, dtype=float)
        else:
            ext.solve()
            # the extension hands back a new array at every access: already a copy
            info, x, y = ext.info, np.asarray(ext.solution.x, dtype=float), np.asarray(ext.solution.y, dtype=float)
        self._rho_adapted = info.rho_updates > 0
        status = info.status_val
        return QpSolution(
            x=x, y=y,
            objective=math.nan if status == osqp.SolverStatus.OSQP_NON_CVX else float(info.obj_val),
            status=str(info.status), usable=status in _ACCEPTABLE and bool(np.isfinite(x).all()),
            accurate=status in _SOLVED, iterations=int(info.iter), solve_time_s=float(info.solve_time),
            update_time_s=float(info.update_time),
        )


#: What :class:`OsqpQp` calls on the extension's solver (osqp 1.x's ``OSQPSolver``).
_EXTENSION_CALLS = ("update_data_vec", "update_data_mat", "update_rho", "warm_start", "solve", "info", "solution")


def _extension_solver(wrapper: osqp.OSQP) -> object | None:
    """The compiled solver inside ``wrapper``, for the calls made per QP; None to go through the wrapper.

    osqp's Python class keeps its extension's solver as ``_solver`` and adds bookkeeping
    to every call that the planner does not use (a derivative cache, the solve's info
    copied into a namespace, the infinity constant looked up by module import): about
    11 us a call measured on the benchmark's QPs (22.9 against 11.5 us for an update of
    ``q``, ``l``, ``u``), several percent of a replan. The calls here pass the same data
    to the same C functions, so the solutions are the same bits (tested). An osqp without
    that attribute or those methods gets the wrapper's public calls.
    """
    ext = getattr(wrapper, "_solver", None)
    return ext if ext is not None and all(hasattr(ext, name) for name in _EXTENSION_CALLS) else None
