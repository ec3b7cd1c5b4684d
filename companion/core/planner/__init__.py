"""Overlap-constrained MPC: sequential convex programming on OSQP (docs/METHOD.md section 2).

Pure core: arrays and frozen dataclasses in, a :class:`Plan` out; no sockets, threads,
plotting, or clocks (``time.perf_counter`` only feeds the ``solve_time_s`` diagnostic).

>>> from companion.core.planner import Planner, PlannerConfig, PlanRequest, Plan  # doctest: +SKIP
"""

from companion.core.planner.config import FORMULATIONS, PlannerConfig
from companion.core.planner.request import STATUSES, Plan, PlanRequest
from companion.core.planner.scp import Planner, QpStep

__all__ = ["FORMULATIONS", "STATUSES", "Plan", "PlanRequest", "Planner", "PlannerConfig", "QpStep"]
