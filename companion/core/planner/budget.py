"""The compute budget of one replan, counted in solver work (never in wall time).

A replan's work is the ADMM iterations of every QP it solves plus a fixed charge per QP
solve (:data:`QP_SOLVE_WORK`) for what happens around the solver at each SCP iteration
(linearisation, OSQP update and refactorisation, exact recheck). Because the count is a
function of the request alone, a budgeted replan gives the same answer on any machine;
its wall time is the count times the machine's cost per unit (measured in
``tests/benchmarks/bench_budget.py``).
"""

from __future__ import annotations

import logging

from companion.core.planner.osqp_qp import OsqpQp, QpSolution

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
        ADMM iterations spent so far (part of ``used``).
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

    def solve(self, qp: OsqpQp, cap: int) -> QpSolution | None:
        """Solve ``qp`` within ``cap`` ADMM iterations and what the budget has left; charge it.

        Returns None (and marks the budget exhausted) when fewer than
        :data:`MIN_QP_ITERATIONS` are left. A QP that stops unsolved at a cap the budget
        lowered also marks it exhausted: it stopped for the budget, not for itself.
        """
        left = self.total - self.used - QP_SOLVE_WORK
        if left < min(cap, MIN_QP_ITERATIONS):
            self.exhausted = True
            return None
        grant = min(cap, left)
        sol = qp.solve(max_iter=grant)
        self.charge(sol.iterations)
        if grant < cap and not sol.accurate and sol.iterations >= grant:
            self.exhausted = True
        return sol

    def charge(self, iterations: int) -> None:
        """Account one QP solve of ``iterations`` ADMM iterations."""
        self.used += QP_SOLVE_WORK + int(iterations)
        self.admm_iterations += int(iterations)
        self.qp_solves += 1
