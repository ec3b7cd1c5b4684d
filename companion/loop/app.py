"""The companion's control loop: estimate, plan, command — as a function of messages and time.

:class:`Companion` owns no socket, thread or clock. The edge feeds it every inbound
message with :meth:`Companion.handle` and calls :meth:`Companion.tick` at the setpoint
rate with the link time; ``tick`` returns the MAVLink messages to send (its outbox).
Filters run on the messages' own timestamps (vehicle time since boot), so a replayed
tlog that calls the same ticks with the same messages reproduces the same commands.

The loop orchestrates one-job modules: :mod:`~companion.loop.perception` (filters and
the vehicle-time base), :mod:`~companion.loop.request_builder` (estimates + mission + map
to a planning problem), a :class:`~companion.loop.planning.PlanningService` (inline in
lockstep and replay, a worker beside the stream in real time), the
:mod:`~companion.loop.executor` (plan to this tick's command, braking) and an injected
:class:`~companion.loop.engagement.OffboardSequence` (PX4's OFFBOARD handshake).
"""

from __future__ import annotations

import logging
import math
from collections import deque

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.planner import Planner
from companion.loop.config import CompanionScenario
from companion.loop.engagement import OffboardSequence
from companion.loop.executor import Executor, Follow
from companion.loop.obstacles import ObstacleIntake
from companion.loop.perception import Perception, PoseOutcome
from companion.loop.planning import InlinePlanning, PlanningService, PlanResult
from companion.loop.records import CompanionState, LoopMode, PlanStatus, ReplanRecord
from companion.loop.request_builder import RequestBuilder
from companion.loop.vehicle_clock import link_ns
from companion.mavlink import messages
from companion.mavlink.link import Received
from companion.mavlink.offboard import Notify, OffboardConfig, OffboardSequencer, SendCommand

logger = logging.getLogger(__name__)

SEV_WARNING = mavlink2.MAV_SEVERITY_WARNING
SEV_NOTICE = mavlink2.MAV_SEVERITY_NOTICE
SEV_INFO = mavlink2.MAV_SEVERITY_INFO

_HEARTBEAT_PERIOD_S = 1.0
_UNCONSTRAINED_WARN_PERIOD_S = 5.0
_SIGNATURE_WARN_PERIOD_S = 5.0  # as mavsim's

#: Start of the STATUSTEXT announcing packets dropped for a bad or missing MAVLink 2
#: signature; the text ends with the links' running total: ``"... (12 rejected)"``.
SIGNATURE_TEXT = "companion: bad or no signature ("

Outbox = list[mavlink2.MAVLink_message]

#: STATUSTEXT when the autopilot's TIMESYNC answers disagree with its pose stamps (<= 50 characters).
CLOCK_DISAGREES_TEXT = "companion: TIMESYNC off pose clock, using arrivals"

#: NAMED_VALUE_FLOAT sent at the tick a plan arrives from an asynchronous planning service
#: (real time; :attr:`~companion.loop.planning.PlanningService.asynchronous`), also when that
#: is the tick of its request: the value is the replan's number, so a replay applies it at
#: the same tick.
PLAN_ARRIVED = "plan_seq"
#: NAMED_VALUE_FLOAT sent at the tick a job came back without a plan (the planning process
#: raised): the value is the replan's number, so a replay drops that job at the same tick.
PLAN_LOST = "plan_lost"


class Companion:
    """Estimator + planner + offboard sequence behind a message-in, message-out interface.

    Parameters
    ----------
    scenario : CompanionScenario
        Mission, planner, estimator, map and loop settings (``companion.loop.config``).
    offboard : OffboardConfig, optional
        Engagement settings of the default sequencer (default: the scenario's ``[offboard]`` table).
    sequencer : OffboardSequence, optional
        The engagement state machine (default: an
        :class:`~companion.mavlink.offboard.OffboardSequencer` with ``offboard``).
    planning : PlanningService, optional
        Where replans are solved (default: :class:`~companion.loop.planning.InlinePlanning`,
        the plan applied at the tick that asked for it).
    """

    def __init__(
        self,
        scenario: CompanionScenario,
        offboard: OffboardConfig | None = None,
        *,
        sequencer: OffboardSequence | None = None,
        planning: PlanningService | None = None,
    ) -> None:
        self.scenario = scenario
        self.cfg = scenario.planner
        self.loop = scenario.loop
        self.planning: PlanningService = planning or InlinePlanning(Planner(scenario.planner))
        self.sequencer: OffboardSequence = sequencer or OffboardSequencer(offboard or scenario.offboard)
        self.perception = Perception(scenario)
        # obstacle links, traffic reports and GPS_GLOBAL_ORIGIN, onto the same tracks and time base
        self.obstacles = ObstacleIntake(scenario.traffic, self.perception.tracker, self.perception.vehicle_time,
                                        scenario.loop.obstacle_radius_m)
        self.builder = RequestBuilder(scenario, obstacle_radius=self.obstacles.radius)
        self.executor = Executor(scenario.planner, 1.0 / scenario.loop.setpoint_rate_hz, self.planner.lag,
                                 max_plan_age_s=scenario.loop.max_plan_age_s)
        self.state = CompanionState()
        self.records: list[ReplanRecord] = []
        self._replans_asked = 0
        self._last_replan_t: float | None = None
        self._last_hb_t: float | None = None
        self._last_unconstrained_warn = -math.inf
        self._plan_too_old = False  # braking for an old plan was announced
        self._signatures_rejected = 0
        self._signatures_announced = 0
        self._last_signature_warn = -math.inf
        self._last_timesync_t: float | None = None
        self._arrival_delays: deque[float] = deque(maxlen=5)  # link s from request to the tick that took the plan
        self._clock_warned = False  # CLOCK_DISAGREES_TEXT said (once a run)

    @property
    def planner(self) -> Planner:
        """The planner the planning service solves with."""
        return self.planning.planner

    @property
    def drone(self):
        """The drone's filter (:class:`estimator.DroneFilter`)."""
        return self.perception.drone

    @property
    def tracker(self):
        """The obstacle tracks (:class:`estimator.ObstacleTracker`)."""
        return self.perception.tracker

    @property
    def autopilot(self) -> tuple[int, int] | None:
        """(system, component) of the PX4 autopilot the companion follows (the first one heard)."""
        return self.sequencer.target

    def vehicle_time(self, t_s: float) -> float | None:
        """Vehicle time (s since its boot) corresponding to link time ``t_s``."""
        return self.perception.vehicle_time(t_s)

    # ------------------------------------------------------------------ inbound

    def handle(self, rx: Received) -> Outbox:
        """Take one inbound message; return what must answer it at once (never raises for bad content).

        The answer is the autopilot's TIMESYNC request answered (PX4 asks at 10 Hz and uses
        only answers back within 10 ms, so it cannot wait for the next tick); the edge
        sends it to the autopilot as soon as this returns. Bad content is logged and counted.
        """
        if self.obstacles.claims(rx, self.autopilot):  # obstacle links, traffic, GPS_GLOBAL_ORIGIN
            return []
        decoded = messages.decode(rx.msg)
        if decoded is None:
            return []
        if isinstance(decoded, messages.Rejected):
            self.state.messages_rejected += 1
            if decoded.msg_type == "TIMESYNC":
                pass  # a clock message, not an estimate: counted, no filter involved
            elif self.autopilot is not None and decoded.key == self.autopilot:
                self.state.drone_rejections += 1
            else:
                self.state.obstacle_rejections += 1
        elif isinstance(decoded, messages.VehicleHeartbeat):
            known = self.autopilot
            self.sequencer.on_heartbeat(rx.t_s, decoded)  # follows the first PX4 autopilot, ignores the rest
            if known is None and self.autopilot is not None:
                logger.info("autopilot found: system %d component %d", *self.autopilot)
        elif isinstance(decoded, messages.PoseObservation):
            outcome = self.perception.observe(rx.t_s, decoded, self.autopilot)
            if outcome is PoseOutcome.DRONE_REJECTED:
                self.state.drone_rejections += 1
            elif outcome is PoseOutcome.OBSTACLE_REJECTED:
                self.state.obstacle_rejections += 1
        elif decoded.key != self.autopilot:
            return []  # acknowledgements, texts, clocks and home positions count only from the autopilot
        elif isinstance(decoded, messages.TimeSync):
            return self._on_timesync(rx.t_s, decoded)
        elif isinstance(decoded, messages.CommandAck):
            self.sequencer.on_ack(rx.t_s, decoded)
        elif isinstance(decoded, messages.StatusText):
            self.sequencer.on_statustext(rx.t_s, decoded.text)
        elif isinstance(decoded, messages.HomePosition):
            self.sequencer.on_home_altitude(decoded.altitude_amsl_m)
        return []

    def _on_timesync(self, t_rx: float, sync: messages.TimeSync) -> Outbox:
        """Answer the autopilot's TIMESYNC request, or take its answer to ours as a clock sample."""
        if sync.is_request:
            return [messages.timesync(max(1, link_ns(t_rx)), sync.ts1_ns)]  # tc1 0 would read as a request
        self.perception.clock.answer(t_rx, sync.tc1_ns, sync.ts1_ns)  # a disagreement is said at the next tick
        return []

    def on_signatures_rejected(self, total: int) -> None:
        """The links' running count of packets dropped for a bad or missing signature.

        The real-time edge reports it before every tick (a rejected packet never reaches
        :meth:`handle`); the next tick announces new rejections in a STATUSTEXT
        (:data:`SIGNATURE_TEXT`, at most one every 5 s, the count in the text).
        """
        self._signatures_rejected = max(self._signatures_rejected, int(total))

    # ------------------------------------------------------------------ outbound

    def tick(self, t_s: float) -> Outbox:
        """Advance the loop to link time ``t_s`` and return the messages to send now."""
        out: Outbox = []
        if self._last_hb_t is None or t_s - self._last_hb_t >= _HEARTBEAT_PERIOD_S - 1e-9:
            out.append(messages.companion_heartbeat())
            self._last_hb_t = t_s
        for action in self.sequencer.step(t_s):
            if isinstance(action, SendCommand):
                out.append(action.msg)
            elif isinstance(action, Notify):
                out.append(self._say(t_s, action.event.severity, action.event.text))
        if self._signatures_rejected > self._signatures_announced \
                and t_s - self._last_signature_warn >= _SIGNATURE_WARN_PERIOD_S:
            self._signatures_announced, self._last_signature_warn = self._signatures_rejected, t_s
            out.append(self._say(t_s, SEV_WARNING, f"{SIGNATURE_TEXT}{self._signatures_rejected} rejected)"))
        out.extend(self._clock_messages(t_s))
        requests, texts = self.obstacles.outbound(t_s, self.autopilot)
        out.extend(requests)
        out.extend(self._say(t_s, severity, text) for severity, text in texts)
        seq = self.sequencer.state
        if not seq.streaming:
            if self.state.mode not in (LoopMode.WAITING, LoopMode.IDLE):
                self.state.mode = LoopMode.IDLE
            self.executor.hold()
            if self.perception.response is not None:
                self.perception.response.reset()   # no setpoint of ours in force
            out.extend(self._collect_plans(t_s, apply=False))
            return out
        if not seq.engaged:
            self.state.mode = LoopMode.PRESTREAM
            command = self.executor.hold()  # hover while PX4 is asked to switch
            out.extend(self._collect_plans(t_s, apply=False))
        else:
            command, said = self._engaged_command(t_s)
            out.extend(said)
        target = dict(zip(("target_system", "target_component"), self.autopilot or (1, 1)))
        t_boot_ms = int(round(t_s * 1000.0))
        reference = None
        if seq.engaged and self.loop.setpoint_kind == "position_velocity" and self.state.mode is LoopMode.TRACKING:
            t_v = self.perception.vehicle_time(t_s)
            reference = self.executor.reference(t_v) if t_v is not None else None
        if seq.engaged and self.perception.drift is not None and self.state.mode is not LoopMode.STALE:
            # the plan is in the estimate's position rate: the autopilot's velocity loop gets
            # the plan's velocity less the estimate's drift (see LoopConfig.drift_window_s);
            # not while the estimate is stale: a drift measured before the silence is no
            # reason to command a velocity while braking blind
            drift = self.perception.drift_mps()
            command = command - drift
            if reference is not None:
                reference = (reference[0], reference[1] - drift)
        if reference is not None:
            out.append(messages.position_velocity_setpoint(t_boot_ms, *reference, **target))
        else:
            out.append(messages.velocity_setpoint(t_boot_ms, command, **target))
        self._tell_response_observer(t_s, seq.engaged, command)
        return out

    def _tell_response_observer(self, t_s: float, engaged: bool, command: np.ndarray) -> None:
        """The setpoint just sent, to the response observer (``[companion] response_state =
        "observed"``): while engaged its velocity loop follows our setpoints; before, it is
        the autopilot's own, so the observer starts afresh from the first report after."""
        observer = self.perception.response
        if observer is None:
            return
        t_v = self.perception.vehicle_time(t_s)
        if not engaged or t_v is None:
            observer.reset()
            return
        observer.command(t_v, command)

    def _clock_messages(self, t_s: float) -> Outbox:
        """This tick's TIMESYNC request to the autopilot (every ``1 / timesync_hz`` s), and the
        warning that its TIMESYNC clock is not the one that stamps its poses."""
        out: Outbox = []
        if self.perception.clock.disagrees and not self._clock_warned:
            self._clock_warned = True
            out.append(self._say(t_s, SEV_WARNING, CLOCK_DISAGREES_TEXT))
        rate = self.loop.timesync_hz
        if rate > 0.0 and self.autopilot is not None and (
                self._last_timesync_t is None or t_s - self._last_timesync_t >= 1.0 / rate - 1e-9):
            self._last_timesync_t = t_s
            out.append(messages.timesync(0, self.perception.clock.request(t_s)))
        return out

    def _say(self, t_s: float, severity: int, text: str) -> mavlink2.MAVLink_statustext_message:
        self.state.events.append((t_s, text))
        logger.info("%s", text)
        return messages.statustext(severity, text)

    def _collect_plans(self, t_s: float, *, apply: bool) -> Outbox:
        """Take the plans that arrived; adopt them, or discard them (not in control, estimate stale).

        Every plan from an asynchronous service is announced (:data:`PLAN_ARRIVED`). Its arrival
        tick is a race with the stream: a fast solve can be back before the tick that asked for
        it collects, and that arrival is announced too, or a replay would wait for it forever.
        """
        said: Outbox = []
        for result in self.planning.collect():
            if result.plan is None:
                said.append(messages.named_value_float(int(round(t_s * 1000)), PLAN_LOST, float(result.job.seq)))
                logger.warning("replan %d came back without a plan (planner error); the plan in force stays", result.job.seq)
                continue
            if self.planning.asynchronous:
                said.append(messages.named_value_float(int(round(t_s * 1000)), PLAN_ARRIVED, float(result.job.seq)))
            self._arrival_delays.append(t_s - result.job.t_link_s)
            if apply:
                said.extend(self._apply_plan(result, t_s))
            else:
                logger.debug("plan of replan %d discarded: the loop is not flying a plan", result.job.seq)
        return said

    def _engaged_command(self, t_s: float) -> tuple[np.ndarray, Outbox]:
        said: Outbox = []
        t_v = self.perception.vehicle_time(t_s)
        est = self.perception.drone.state
        if t_v is None or est is None or t_v - est.t_s > self.loop.estimate_timeout_s:
            if self.state.mode is not LoopMode.STALE:
                self.state.stale_events += 1
                said.append(self._say(t_s, SEV_WARNING, "companion: estimate stale, braking"))
            self.state.mode = LoopMode.STALE
            self.executor.drop()
            said.extend(self._collect_plans(t_s, apply=False))
            return self.executor.brake(), said
        if self.state.mode is LoopMode.STALE:
            said.append(self._say(t_s, SEV_NOTICE, "companion: estimate back, resuming"))
        self.builder.start_route(est.position)
        # Replan every replan_period, also while braking for lack of a plan (no 20 Hz retry storm),
        # and only when the planner is free: a request built while it solves would wait for it
        # (up to a replan period in the mailbox) and start from an older state. A slow solve
        # thus stretches the period instead (the next request goes at the first tick after).
        due = self._last_replan_t is None or t_s - self._last_replan_t >= self.cfg.replan_period_s - 1e-9
        if due and not self.planning.busy:
            said.extend(self._request_plan(t_s, t_v))
        said.extend(self._collect_plans(t_s, apply=True))
        command, why = self.executor.follow(t_s, t_v)
        if why is Follow.PLAN:
            if self.state.mode is LoopMode.BRAKING:
                said.append(self._say(t_s, SEV_NOTICE, "companion: valid plan again, resuming"))
            self.state.mode = LoopMode.TRACKING
            self._plan_too_old = False
            return command, said
        if why is Follow.TOO_OLD and not self._plan_too_old:
            self._plan_too_old = True
            self.state.old_plan_events += 1
            said.append(self._say(t_s, SEV_WARNING, f"companion: plan older than {self.executor.max_plan_age_s:g} s, braking"))
        self.state.mode = LoopMode.BRAKING
        return command, said

    # ------------------------------------------------------------------ planning

    def _request_plan(self, t_s: float, t_v: float) -> Outbox:
        """Build the replan due now and hand it to the planning service."""
        said: Outbox = []
        lead = self.plan_lead_s()
        velocity = self.perception.drone.state.velocity
        response = self.perception.response
        response_state = None if response is None else response.internal(t_v + lead)
        if self.perception.drift is not None:   # the estimate's position rate, which the plans are in
            drift = self.perception.drift_mps()
            velocity = velocity + drift
            self.state.drift_max_mps = [max(a, abs(float(b))) for a, b in zip(self.state.drift_max_mps, drift)]
            if response_state is not None:
                # the observer's state is the autopilot's, which holds its velocity; the plan's
                # model runs on velocity + drift, so its state also holds the drift's drag (else
                # the model would brake the drift away: k d, 0.4 m/s^2 for 0.5 m/s east on PX4 SITL)
                response_state = response_state + response.model.steady_internal(drift)
        if self.loop.initial_velocity == "plan":
            v0 = self.executor.initial_velocity(velocity, t_v + lead)
        elif lead > 0.0:   # anchored on the estimate, changed as the plan in force changes it over the lead
            v0 = velocity + (self.executor.initial_velocity(velocity, t_v + lead)
                             - self.executor.initial_velocity(velocity, t_v))
        else:
            v0 = np.array(velocity, dtype=float)   # a copy, as the executor hands out
        job = self.builder.build(
            seq=self._replans_asked,
            t_s=t_s,
            t_v=t_v,
            perception=self.perception,
            initial_velocity=v0,
            warm_start=self.executor.plan,
            lead_s=lead,
            response_state=response_state,
            shift=self.executor.displacement(t_v, t_v + lead, velocity) if lead > 0.0 else None,
        )
        self._replans_asked += 1
        self._last_replan_t = t_s
        # where the plan in force put the drone at the request's start against where it is
        # (job.position is the estimate moved along that plan by the lead: the difference is the same)
        planned = self.executor.position_at(job.t_vehicle_s)   # the position only: no velocity model run
        if planned is not None:
            self.state.tracking.add(job.position - planned)
        # the goal is judged on the estimate now, not on where the next plan will start (a
        # lead later in real time: on the way in that is closer to the goal than the drone)
        if self.state.goal_reached_t_s is None and self.builder.at_goal(job.position_now):
            self.state.goal_reached_t_s = t_s
            self.sequencer.on_goal_reached(t_s)
            said.append(self._say(t_s, SEV_INFO, "companion: goal reached"))
        self.state.tracks_beyond_walls_max = max(self.state.tracks_beyond_walls_max, len(job.tracks_beyond_walls))
        left_out = len(job.tracks_unconstrained)
        if left_out:
            self.state.tracks_unconstrained_max = max(self.state.tracks_unconstrained_max, left_out)
            if t_s - self._last_unconstrained_warn >= _UNCONSTRAINED_WARN_PERIOD_S:
                self._last_unconstrained_warn = t_s
                limit = self.loop.max_constrained_tracks
                said.append(self._say(t_s, SEV_NOTICE, f"companion: {left_out} tracks beyond {limit} not constrained"))
        if job.realised_contour:
            now_min = min(job.realised_contour.values())
            best = self.state.min_realised_contour
            self.state.min_realised_contour = now_min if best is None else min(best, now_min)
            said.append(messages.named_value_float(int(round(t_s * 1000)), "ct_min", now_min))
        self.planning.submit(job)
        return said

    def plan_lead_s(self) -> float:
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
        cap = min(self.loop.plan_lead_max_s, self.cfg.replan_period_s - 1.0 / self.loop.setpoint_rate_hz)
        return max(0.0, min(max(self._arrival_delays), cap))

    def _apply_plan(self, result: PlanResult, t_s: float) -> Outbox:
        """Adopt (or refuse) a finished plan at link time ``t_s`` and record it."""
        said: Outbox = []
        plan, job = result.plan, result.job
        status = PlanStatus.of(plan)
        if status is PlanStatus.FAILED:
            self.state.failed_plans += 1
            if self.executor.plan is not None or self.state.mode is not LoopMode.BRAKING:
                self.state.braking_events += 1
                said.append(self._say(t_s, SEV_WARNING, "companion: no valid plan, braking"))
            self.executor.drop()
        else:
            if status is PlanStatus.SLACK:
                self.state.slack_plans += 1
                # One short STATUSTEXT on every slack replan (issue 15): at most one per
                # replan_period_s (3.3 Hz), about 60 bytes each, well within a telemetry link.
                said.append(self._say(t_s, SEV_WARNING,
                                      f"companion: safety slack used ({plan.slack_max:.2f}) #{self.state.slack_plans}"))
            self.executor.adopt(plan, job.t_vehicle_s, job.t_link_s, job.position, now_v=self.perception.vehicle_time(t_s))
        # Obstacles beyond sensing range were ignored by design: their contour says nothing.
        in_range = np.asarray(plan.in_range, dtype=bool)
        ct_plan = np.asarray(plan.contour_of_touch)[in_range]
        planned_contour = {} if status is PlanStatus.FAILED else {
            key: float(plan.contour_of_touch[i][0]) for i, key in enumerate(job.tracks_constrained) if in_range[i]}
        self.records.append(
            ReplanRecord(
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
                planned_contour=planned_contour,
            )
        )
        return said
