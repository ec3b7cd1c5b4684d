"""How a replan reaches the planner and its plan comes back: the planning service protocol.

The loop submits a :class:`~companion.loop.request_builder.ReplanJob` when a replan is due
and the service is not :attr:`~PlanningService.busy` (a request is built only when the
planner can take it at once, so it starts from the freshest state and none is built to be
thrown away), and collects :class:`PlanResult` s at every tick. :class:`InlinePlanning` solves at
submission, so the plan is applied at the tick that asked for it: lockstep runs and
replays use it and are deterministic. The real-time edge passes a worker that solves
beside the setpoint stream (:class:`companion.realtime.stream.PlanWorker`); the loop itself
never waits for a plan and owns no thread.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Protocol

from companion.core.planner import Plan, Planner
from companion.loop.request_builder import ReplanJob

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class PlanResult:
    """The planner's answer to one job."""

    job: ReplanJob
    plan: Plan | None  #: None: the planner raised on this job (logged by the service), no plan came back


class PlanningService(Protocol):
    """Where the loop sends replans and picks up plans."""

    planner: Planner  #: the planner that solves; the loop reads only its vehicle model (``planner.lag``)
    #: False: every plan comes back in the tick that asked for it (lockstep), and arrivals go
    #: unrecorded. True: a plan comes back at whatever tick collects it, the asking one
    #: included, and the loop keeps every arrival (:class:`~companion.loop.plan_cycle.PlanArrival`)
    #: for the edge's tlog marks, so a replay applies it at the same tick.
    asynchronous: bool

    @property
    def busy(self) -> bool:
        """A submitted job has not been collected yet (the loop then builds no new request)."""

    def submit(self, job: ReplanJob) -> None:
        """Ask for a plan (never blocks in real time; a newer job may supersede an unsolved one)."""

    def collect(self) -> list[PlanResult]:
        """Plans finished since the last call, oldest first (never blocks)."""


class InlinePlanning:
    """Solve at :meth:`submit`; :meth:`collect` hands the plan back at once (lockstep, replay)."""

    asynchronous = False

    def __init__(self, planner: Planner) -> None:
        self.planner = planner
        self._done: list[PlanResult] = []

    @property
    def busy(self) -> bool:
        """Never: the plan is handed back in the tick that asked for it."""
        return False

    def submit(self, job: ReplanJob) -> None:
        self._done.append(PlanResult(job, self.planner.solve(job.request, warm_start=job.warm_start)))

    def collect(self) -> list[PlanResult]:
        done, self._done = self._done, []
        return done
