"""The compute budget of one replan, counted in solver work (never in wall time).

A replan's work is the iterations of every QP it solves, each worth its backend's
``work_per_iteration`` units (OSQP: 1 per ADMM iteration; PIQP:
:data:`companion.core.planner.piqp_qp.WORK_PER_ITERATION` per interior-point iteration,
the ADMM iterations that take the same time), plus a fixed charge per QP solve
(:data:`QP_SOLVE_WORK`) for what happens around the solver at each SCP iteration
(linearisation, solver update, exact recheck). Because the count is a function of the
request alone, a budgeted replan gives the same answer on any machine; its wall time is
the count times the machine's cost per unit (measured in
``tests/benchmarks/bench_budget.py``).
"""

from __future__ import annotations

import logging

from companion.core.planner.osqp_qp import QpSolution
from companion.core.planner.qp_backend import QpBackend

logger = logging.getLogger(__name__)

#: Work units charged per QP solve on top of its ADMM iterations. Measured on the
#: corridor and planner-benchmark replans (N = 40, P <= 3): the work around one QP
#: (rows, update, refactorisation, recheck) costs about as much wall time as 100 to 200
#: ADMM iterations of that QP.
QP_SOLVE_WORK = 150
#: A QP is not started with fewer ADMM iterations than this left: it could not converge.
MIN_QP_ITERATIONS = 25


class WorkBudget:
    """Work left in one replan; every QP of the replan is solved through :meth:`solve`.

    Parameters
    ----------
    total : int
        The replan's budget in work units (``PlannerConfig.replan_work_budget``).

    Attributes
    ----------
    used : int
        Work spent so far.
    admm_iterations : int
        Solver iterations spent so far (ADMM for OSQP, interior-point for PIQP; times the
        backend's ``work_per_iteration``, part of ``used``).
    qp_solves : int
        QPs solved so far.
    exhausted : bool
        Set when a QP could not be given the iterations it would otherwise have had.
    """

    def __init__(self, total: int) -> None:
        self.total = int(total)
        self.used = 0
        self.admm_iterations = 0
        self.qp_solves = 0
        self.exhausted = False

    @property
    def left(self) -> int:
        """Work units not yet spent."""
        return self.total - self.used

    def solve(self, qp: QpBackend, cap: int) -> QpSolution | None:
        """Solve ``qp`` within ``cap`` work units and what the budget has left; charge it.

        ``qp`` is a backend (:class:`companion.core.planner.qp_backend.QpBackend`): its ``solve(max_iter)`` takes work
        units and its ``work_per_iteration`` prices its iterations. Returns None (and marks
        the budget exhausted) when fewer than :data:`MIN_QP_ITERATIONS` units (or one of the
        backend's iterations) are left. A QP that stops unsolved at a cap the budget lowered
        also marks it exhausted: it stopped for the budget, not for itself.
        """
        unit = int(qp.work_per_iteration)
        left = self.total - self.used - QP_SOLVE_WORK
        if left < max(unit, min(cap, MIN_QP_ITERATIONS)):
            self.exhausted = True
            return None
        grant = min(cap, left)
        sol = qp.solve(max_iter=grant)
        self.charge(sol.iterations, unit)
        if grant < cap and not sol.accurate and (sol.iterations + 1) * unit > grant:
            self.exhausted = True
        return sol

    def charge(self, iterations: int, unit: int = 1) -> None:
        """Account one QP solve of ``iterations`` solver iterations worth ``unit`` work units each."""
        self.used += QP_SOLVE_WORK + int(iterations) * int(unit)
        self.admm_iterations += int(iterations)
        self.qp_solves += 1
