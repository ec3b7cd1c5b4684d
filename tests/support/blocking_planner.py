"""A planner for real-time tests: the real one for the first request, then it blocks (a stuck solve)."""

from __future__ import annotations

import time

from companion.core.planner import Planner, PlannerConfig

BLOCK_S = 30.0  # longer than any test waits: every later solve is "stuck" for the whole test


class FirstThenBlock:
    """Solves the first request with :class:`Planner`, then sleeps ``BLOCK_S`` in every later solve."""

    def __init__(self, config: PlannerConfig) -> None:
        self._planner = Planner(config)
        self._calls = 0

    def solve(self, request, warm_start=None):
        self._calls += 1
        if self._calls > 1:
            time.sleep(BLOCK_S)
        return self._planner.solve(request, warm_start=warm_start)
