"""The replanning cycle: when to ask for a plan, from which state, and what to do with the answer.

:class:`PlanCycle` builds the replan due at a tick (from the vehicle state, the goal and
the obstacle sources, through the :class:`~companion.loop.request_builder.RequestBuilder`),
hands it to the planning service, takes the plans that came back and adopts or refuses
them (the :class:`~companion.loop.executor.Executor` flies the adopted one), and keeps the
loop's records of it: one :class:`~companion.loop.records.ReplanRecord` per applied plan,
the statistics in :class:`~companion.loop.records.CompanionState`, and the STATUSTEXTs a
replan is worth. Pure: link time (s) and vehicle time (s) come in as arguments.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable, MutableSequence
from dataclasses import dataclass

import numpy as np

from companion.core.planner import PlannerConfig
from companion.loop.config import LoopConfig
from companion.loop.executor import Executor
from companion.loop.perception import Perception
from companion.loop.planning import PlanningService, PlanResult
from companion.loop.intake.traffic_config import is_fleet_peer
from companion.loop.records import CompanionState, LoopMode, PlanStatus, ReplanRecord, ReplanTally
from companion.loop.request_builder import RequestBuilder
from companion.loop.supervisor import SEV_INFO, SEV_NOTICE, SEV_WARNING, RateLimiter, Supervisor
from companion.mavlink import messages

logger = logging.getLogger(__name__)

_UNCONSTRAINED_WARN_PERIOD_S = 5.0

#: Once the goal is reached, the vehicle is *settled* at it when it is inside the goal's
#: acceptance and would still be this long later at its present velocity (s; the estimate's
#: position rate): handed back then, an autopilot's Hold stops it inside, where it was asked
#: to be, not where an overshoot would carry it.
GOAL_SETTLE_LOOKAHEAD_S = 1.0


@dataclass(frozen=True)
class PlanArrival:
    """A job the planning service handed back at a tick: a plan arrived, or (``lost``) none did.

    Kept for jobs of an asynchronous service (real time: the tick that collects a plan is a
    race with the stream) and for every lost job; the real-time edge writes them into its
    tlog (:meth:`companion.realtime.tlog_marks.TlogMarks.plans`) so a replay applies each plan,
    and drops each lost job, at the same tick.
    """

    seq: int            #: the replan's number (:attr:`~companion.loop.request_builder.ReplanJob.seq`)
    lost: bool = False  #: the job came back without a plan (the planning process raised)


Outbox = list


class PlanCycle:
    """Replan scheduling, the plan's start state, plan collection and adoption.

    Parameters
    ----------
    planner_config, settings : the scenario's ``[planner]`` and ``[companion]`` settings.
    planning : where replans are solved.
    builder : builds a replan from the estimates, the goal and the map.
    executor : flies the adopted plan.
    perception : the vehicle state (filters, clock, drift, response observer).
    supervisor : says what happened.
    state, records : the loop's statistics and replan records (shared with the run report; ``records``
        may keep only the latest, a ``deque`` with a ``maxlen``).
    tally : every applied replan summed (:class:`~companion.loop.records.ReplanTally`), for the report.
    on_goal_reached : called with the link time when the goal is first reached.
    on_at_goal : called at every replan after that with the link time and whether the vehicle is
        settled at the goal (inside its acceptance now and :data:`GOAL_SETTLE_LOOKAHEAD_S` later).
    """

    def __init__(self, planner_config: PlannerConfig, settings: LoopConfig, *, planning: PlanningService,
                 builder: RequestBuilder, executor: Executor, perception: Perception, supervisor: Supervisor,
                 state: CompanionState, records: MutableSequence[ReplanRecord], tally: ReplanTally,
                 on_goal_reached: Callable[[float], None], on_at_goal: Callable[[float, bool], None]) -> None:
        self.cfg, self.settings = planner_config, settings
        self.planning, self.builder, self.executor = planning, builder, executor
        self.perception, self.supervisor = perception, supervisor
        self.state, self.records, self.tally = state, records, tally
        self._on_goal_reached = on_goal_reached
        self._on_at_goal = on_at_goal
        self._replans_asked = 0
        self._replan = RateLimiter(planner_config.replan_period_s, tolerance_s=1e-9)
        self._unconstrained = RateLimiter(_UNCONSTRAINED_WARN_PERIOD_S)
        self._arrival_delays: deque[float] = deque(maxlen=5)  # link s from request to the tick that took the plan
        #: The jobs handed back since :meth:`begin_tick` (the current tick's), oldest first.
        self.arrivals: list[PlanArrival] = []
        self._epoch_of: dict[int, int] = {}  # replan seq -> the estimator reset epoch it was built in

    def begin_tick(self) -> None:
        """A new tick starts: forget the previous tick's :attr:`arrivals`."""
        self.arrivals = []

    def step(self, t_s: float, t_v: float) -> Outbox:
        """Engaged with a fresh estimate: ask for the replan due, then take what came back.

        Replan every replan_period, also while braking for lack of a plan (no 20 Hz retry storm),
        and only when the planner is free: a request built while it solves would wait for it
        (up to a replan period in the mailbox) and start from an older state. A slow solve
        thus stretches the period instead (the next request goes at the first tick after).
        """
        said: Outbox = []
        if self._replan.ready(t_s) and not self.planning.busy:
            self._replan.take(t_s)
            said.extend(self._request(t_s, t_v))
        said.extend(self.collect(t_s, apply=True))
        return said

    def collect(self, t_s: float, *, apply: bool) -> Outbox:
        """Take the plans that arrived; adopt them, or discard them (not in control, estimate stale).

        Every plan from an asynchronous service, and every job lost, is kept in :attr:`arrivals`
        (not sent). Its arrival tick is a race with the stream: a fast solve can be back before
        the tick that asked for it collects, and that arrival is kept too, or a replay would
        wait for it forever.
        """
        said: Outbox = []
        for result in self.planning.collect():
            if result.plan is None:
                self._epoch_of.pop(result.job.seq, None)
                self.arrivals.append(PlanArrival(result.job.seq, lost=True))
                logger.warning("replan %d came back without a plan (planner error); the plan in force stays", result.job.seq)
                continue
            if self.planning.asynchronous:
                self.arrivals.append(PlanArrival(result.job.seq))
            self._arrival_delays.append(t_s - result.job.t_link_s)
            epoch = self._epoch_of.pop(result.job.seq, self.perception.reset_epoch)
            if epoch != self.perception.reset_epoch:
                self.state.plans_before_reset += 1
                logger.info("plan of replan %d discarded: built before the autopilot's estimator reset", result.job.seq)
                continue
            if apply:
                said.extend(self._apply(result, t_s))
            else:
                logger.debug("plan of replan %d discarded: the loop is not flying a plan", result.job.seq)
        return said

    def replan_now(self) -> None:
        """Ask for the next replan at the first tick the planner is free (not a period later)."""
        self._replan.last_t = -math.inf

    def lead_s(self) -> float:
        """How long after its request the next plan starts (s): the longest of the last five
        plans' arrival delays (link time from request to the tick that took the plan), at most
        ``[companion] plan_lead_max_s`` and a setpoint period short of the replan period.

        0 in lockstep and its replays, where a plan comes back in the tick that asked for it.
        In real time it plans from where the drone will be when the plan takes over, not from
        where it was when asked; the delays are the recorded arrival ticks, so a replay of a
        real-time log computes the same leads.
        """
        if not self._arrival_delays or self.executor.waiting:
            return 0.0
        cap = min(self.settings.plan_lead_max_s, self.cfg.replan_period_s - 1.0 / self.settings.setpoint_rate_hz)
        return max(0.0, min(max(self._arrival_delays), cap))

    # ------------------------------------------------------------------ request

    def _initial_velocity(self, velocity: np.ndarray, t_v: float, lead: float) -> np.ndarray:
        """``V_0`` at the plan's start (NED m/s, the plans' frame; see ``[companion] initial_velocity``)."""
        if self.settings.initial_velocity == "plan":
            return self.executor.initial_velocity(velocity, t_v + lead)
        if lead > 0.0:   # anchored on the estimate, changed as the plan in force changes it over the lead
            return velocity + (self.executor.initial_velocity(velocity, t_v + lead)
                               - self.executor.initial_velocity(velocity, t_v))
        return np.array(velocity, dtype=float)   # a copy, as the executor hands out

    def _request(self, t_s: float, t_v: float) -> Outbox:
        """Build the replan due now and hand it to the planning service."""
        said: Outbox = []
        lead = self.lead_s()
        velocity = self.perception.plan_velocity()
        if self.perception.drift is not None:
            drift = self.perception.drift_mps()
            self.state.drift_max_mps = [max(a, abs(float(b))) for a, b in zip(self.state.drift_max_mps, drift)]
        job = self.builder.build(
            seq=self._replans_asked,
            t_s=t_s,
            t_v=t_v,
            perception=self.perception,
            initial_velocity=self._initial_velocity(velocity, t_v, lead),
            warm_start=self.executor.plan,
            lead_s=lead,
            response_state=self.perception.response_state(t_v + lead),
            shift=self.executor.displacement(t_v, t_v + lead, velocity) if lead > 0.0 else None,
            plan_in_force=self.executor.position_at,
        )
        self._replans_asked += 1
        self._epoch_of[job.seq] = self.perception.reset_epoch
        # where the plan in force put the drone at the request's start against where it is
        # (job.position is the estimate moved along that plan by the lead: the difference is the same)
        planned = self.executor.position_at(job.t_vehicle_s)   # the position only: no velocity model run
        if planned is not None:
            self.state.tracking.add(job.position - planned)
        # the goal is judged on the estimate now, not on where the next plan will start (a
        # lead later in real time: on the way in that is closer to the goal than the drone)
        if self.state.goal_reached_t_s is None and self.builder.goal.reached(job.position_now):
            self.state.goal_reached_t_s = t_s
            self._on_goal_reached(t_s)
            said.append(self.supervisor.say(t_s, SEV_INFO, "companion: goal reached"))
        if self.state.goal_reached_t_s is not None:
            goal, p = self.builder.goal, job.position_now
            self._on_at_goal(t_s, goal.at_goal(p) and goal.at_goal(p + velocity * GOAL_SETTLE_LOOKAHEAD_S))
        self.state.tracks_beyond_walls_max = max(self.state.tracks_beyond_walls_max, len(job.tracks_beyond_walls))
        left_out = len(job.tracks_unconstrained)
        if left_out:
            self.state.tracks_unconstrained_max = max(self.state.tracks_unconstrained_max, left_out)
            if self._unconstrained.take(t_s):
                limit = self.settings.max_constrained_tracks
                said.append(self.supervisor.say(t_s, SEV_NOTICE, f"companion: {left_out} tracks beyond {limit} not constrained"))
        self._note_clearance(job)
        if job.realised_contour:
            now_min = min(job.realised_contour.values())
            best = self.state.min_realised_contour
            self.state.min_realised_contour = now_min if best is None else min(best, now_min)
            said.append(messages.named_value_float(int(round(t_s * 1000)), "ct_min", now_min))
        self.planning.submit(job)
        return said

    def _note_clearance(self, job) -> None:
        """The smallest estimated clearance to a track at this request (m: centre distance less both
        radii), and to the geofence (m: the drone's centre, signed: negative outside)."""
        fence = getattr(self.builder, "fence", None)
        if fence is not None and fence.fence is not None:
            d = fence.fence.clearance(job.position_now)
            best = self.state.min_fence_clearance_m
            self.state.min_fence_clearance_m = d if best is None else min(best, d)
        if not job.obstacle_positions:
            return
        keys = list(job.obstacle_positions)
        centres = np.array([job.obstacle_positions[k] for k in keys])
        radii = self.cfg.drone_radius_m + np.array([self.builder.obstacle_radius(k) for k in keys])
        clearance = float(np.min(np.linalg.norm(centres - job.position_now, axis=1) - radii))
        best = self.state.min_track_clearance_m
        self.state.min_track_clearance_m = clearance if best is None else min(best, clearance)

    # ------------------------------------------------------------------ answer

    def _apply(self, result: PlanResult, t_s: float) -> Outbox:
        """Adopt (or refuse) a finished plan at link time ``t_s`` and record it."""
        said: Outbox = []
        plan, job = result.plan, result.job
        status = PlanStatus.of(plan)
        if status is PlanStatus.FAILED:
            self.state.failed_plans += 1
            if self.executor.plan is not None or self.state.mode is not LoopMode.BRAKING:
                self.state.braking_events += 1
                said.append(self.supervisor.say(t_s, SEV_WARNING, "companion: no valid plan, braking"))
            self.executor.drop()
        else:
            if status is PlanStatus.SLACK:
                self.state.slack_plans += 1
                # One short STATUSTEXT on every slack replan: at most one per replan_period_s
                # (3.3 Hz), about 60 bytes each, well within a telemetry link.
                said.append(self.supervisor.say(t_s, SEV_WARNING,
                                                f"companion: safety slack used ({plan.slack_max:.2f}) #{self.state.slack_plans}"))
            self.executor.adopt(plan, job.t_vehicle_s, job.t_link_s, job.position, now_v=self.perception.vehicle_time(t_s))
        # Obstacles beyond sensing range were ignored by design: their contour says nothing.
        in_range = np.asarray(plan.in_range, dtype=bool)
        ct_plan = np.asarray(plan.contour_of_touch)[in_range]
        planned_contour = {} if status is PlanStatus.FAILED else {
            key: float(plan.contour_of_touch[i][0]) for i, key in enumerate(job.tracks_constrained) if in_range[i]}
        record = ReplanRecord(
            t_link_s=job.t_link_s,
            t_vehicle_s=job.t_vehicle_s,
            status=status,
            iterations=int(plan.iterations),
            solve_time_s=float(plan.solve_time_s),
            slack_max=float(plan.slack_max),
            planned_min_contour=float(ct_plan.min()) if ct_plan.size else math.nan,
            realised_contour=job.realised_contour,
            drone_position=job.position.copy(),
            drone_cov=job.drone_cov.copy(),
            drone_velocity=job.drone_velocity,
            obstacle_positions=job.obstacle_positions,
            obstacle_covs=job.obstacle_covs,
            target=job.target,
            plan_positions=np.asarray(plan.positions).copy(),
            command=np.asarray(plan.commands[0]).copy() if status is not PlanStatus.FAILED else np.zeros(3),
            t_applied_s=t_s,
            tracks_unconstrained=len(job.tracks_unconstrained),
            tracks_giving_way=len(job.tracks_giving_way),
            tracks_along_intent=len(job.tracks_along_intent),
            planned_contour=planned_contour,
        )
        self.records.append(record)
        self.tally.add(record, is_peer=is_fleet_peer)
        return said
