"""What the planner needs of a QP solver backend: the :class:`QpBackend` protocol.

The planner writes every QP as ``min 0.5 x'Px + q'x  s.t.  l <= Ax <= u`` on one fixed
sparsity pattern per shape (:class:`companion.core.planner.qp_layout.QpLayout`) and hands
it to a backend built on that pattern: :class:`companion.core.planner.osqp_qp.OsqpQp`
(``[planner] solver = "osqp"``) or :class:`companion.core.planner.piqp_qp.PiqpQp`
(``"piqp"``); ``companion.core.planner.qp_step.BACKENDS`` maps the names to them. The work
budget (:mod:`companion.core.planner.budget`) prices a solve in the backend's own
iterations, ``work_per_iteration`` units each.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from companion.core.planner.full_hessian import FullHessian
from companion.core.planner.osqp_qp import QpSolution


class QpBackend(Protocol):
    """A QP solver bound to one pattern: data in, solution out (see the module docstring)."""

    #: Work units one of its iterations costs the replan's budget.
    work_per_iteration: int
    #: The full symmetric ``P`` of the current data (``x'Px`` for the objective and the recheck).
    hessian: FullHessian

    def update(self, *, p_data: np.ndarray | None = None, q: np.ndarray | None = None,
               a_data: np.ndarray | None = None, l: np.ndarray | None = None, u: np.ndarray | None = None) -> None:
        """New data on the same pattern (CSC order of ``P``'s upper triangle and of ``A``); None: unchanged."""

    def warm_start(self, x: np.ndarray | None = None, y: np.ndarray | None = None) -> None:
        """A primal and dual starting point for the next solve (a backend may ignore it)."""

    def solve(self, max_iter: int = 10000) -> QpSolution:
        """Solve within ``max_iter`` work units; never raises on a solver status."""

    def p_times(self, x: np.ndarray) -> np.ndarray:
        """``P x`` with the full symmetric ``P``."""
