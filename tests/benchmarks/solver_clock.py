"""The QP backends' own time inside a block of code, for the benchmarks' ratios.

``with SolverClock((OsqpQp,)) as clock:`` patches each backend class's ``solve`` for the
block and sums what the solver itself reports of every QP solved in it: ``total_s`` its
solve time (``QpSolution.solve_time_s``), ``update_s`` its update time before the solve
(new data, and OSQP's refactorisation of its KKT matrix: ``QpSolution.update_time_s``), and
``iterations[cls]`` the iteration count of each QP by backend class.
"""

from __future__ import annotations


class SolverClock:
    """Sums the backends' own solve and update times (s) and lists their iterations while active."""

    def __init__(self, backends: tuple[type, ...]) -> None:
        self.total_s = 0.0
        self.update_s = 0.0
        self.iterations: dict[type, list[int]] = {cls: [] for cls in backends}
        self._saved = {cls: cls.solve for cls in backends}

    def __enter__(self) -> "SolverClock":
        for cls, orig in self._saved.items():
            def solve(qp, max_iter=10000, _orig=orig, _cls=cls):
                sol = _orig(qp, max_iter)
                self.total_s += sol.solve_time_s
                self.update_s += sol.update_time_s
                self.iterations[_cls].append(sol.iterations)
                return sol
            cls.solve = solve
        return self

    def __exit__(self, *exc) -> None:
        for cls, orig in self._saved.items():
            cls.solve = orig
