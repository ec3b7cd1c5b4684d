"""The companion's control loop: estimate, plan, command, as a function of messages and time.

:class:`Companion` owns no socket, thread or clock. The edge feeds it every inbound
message with :meth:`Companion.handle` and calls :meth:`Companion.tick` at the setpoint
rate with the link time; ``tick`` returns the MAVLink messages to send (its outbox), and
:attr:`Companion.plan_arrivals` then says which plans that tick collected (for the edge's
tlog marks, :mod:`companion.realtime.tlog_marks`; nothing goes on the wire for them).
Filters run on the messages' own timestamps (vehicle time since boot), so a replayed
tlog that calls the same ticks with the same messages reproduces the same commands.
Every edge (lockstep, real time, replay) makes those calls through one
:class:`~companion.loop.driver.Driver`, which sends and records what they return.

``Companion`` is wiring; each stage does one job, and data flows one way through them:

- :class:`~companion.loop.inbound.InboundRouter`: each inbound message routed once;
- :class:`~companion.loop.perception.Perception`: the vehicle state (filters, clock mapping,
  drift, response observer) and the obstacle tracks, at one vehicle time;
- :class:`~companion.loop.intake.obstacles.ObstacleIntake`: traffic from every link onto the tracks;
- :class:`~companion.loop.request_builder.RequestBuilder`: one planning problem from the
  vehicle state, a goal source (:mod:`~companion.loop.goal`), the tracks and the other
  obstacle sources (:mod:`~companion.loop.obstacle_sources`), and the map;
- :class:`~companion.loop.plan_cycle.PlanCycle`: when to replan, and what to do with a plan;
- :class:`~companion.loop.executor.Executor`: the plan in force to this tick's command, braking;
- :class:`~companion.loop.commanding.Commanding`: the loop's mode and each tick's command and setpoint;
- :class:`~companion.loop.goal_stage.GoalStage`: placing the goal before flying, a mission's messages;
- :class:`~companion.loop.mission_watch.MissionWatch`: the autopilot's own mission flight, its path
  predicted and judged (``[offboard] takeover = "watch"`` or ``"guard"``);
- :class:`~companion.loop.mission_guard.MissionGuard`: takeovers on a predicted conflict and
  hand-backs to the mission (``[offboard] takeover = "guard"``);
- an injected :class:`~companion.loop.engagement.OffboardSequence` (arm, take-off, engage, hand back);
- :class:`~companion.loop.supervisor.Supervisor`: HEARTBEAT, TIMESYNC, announcements.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import MutableSequence, Sequence

from pymavlink.dialects.v20 import common as mavlink2

from companion.core.planner import Planner
from companion.loop.config import CompanionScenario
from companion.loop.engagement import OffboardSequence
from companion.loop.commanding import Commanding, brake_hand_back_s
from companion.loop.executor import Executor
from companion.loop.goal import GoalSource, PlacedGoal
from companion.loop.fence_source import FenceSource, scenario_fence
from companion.loop.goal_stage import GoalStage
from companion.loop.inbound import InboundRouter
from companion.loop.obstacle_sources import ObstacleSource
from companion.loop.intake.obstacles import ObstacleIntake
from companion.loop.mission_file import read_mission_file
from companion.loop.mission_goal import MissionGoal
from companion.loop.mission_guard import MissionGuard
from companion.loop.mission_watch import MissionProgress, MissionWatch
from companion.loop.perception import Perception
from companion.loop.plan_cycle import PlanArrival, PlanCycle
from companion.loop.planning import InlinePlanning, PlanningService
from companion.loop.fleet_announcer import FleetAnnouncer
from companion.loop.fleet_frame import FleetFrame
from companion.loop.peer_intents import PeerIntents
from companion.loop.records import CompanionState, LoopMode, ReplanRecord, ReplanTally
from companion.loop.right_of_way import RightOfWay
from companion.loop.request_builder import RequestBuilder
from companion.loop.supervisor import Supervisor
from companion.loop.vehicle_reference import VehicleReference
from companion.mavlink import messages
from companion.mavlink.link import Received
from companion.errors import ConfigError
from companion.mavlink.offboard import MISSION_TAKEOVERS, Notify, OffboardConfig, OffboardSequencer, Phase, SendCommand

logger = logging.getLogger(__name__)

Outbox = list[mavlink2.MAVLink_message]


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
    goal : GoalSource, optional
        Where to go (default: the scenario's ``[mission]`` goal, :class:`~companion.loop.goal.ScenarioGoal`).
        A goal given relative to home or on the earth is a
        :class:`~companion.loop.goal.PlacedGoal`; a source with ``prepare`` holds the offboard
        sequence at its start until it is ready (see :mod:`companion.loop.goal`).
    obstacle_sources : sequence of ObstacleSource, optional
        Obstacles besides the tracks (default: the scenario's static obstacles,
        :class:`~companion.loop.obstacle_sources.StaticObstacles`).
    reference : VehicleReference, optional
        The vehicle's origin and home, shared by the obstacle intake and the goal (default: a new one).
    fence : FenceSource, optional
        The geofence (default: the scenario's ``fence_file`` or its ``plan_file``'s fence, if any).
    fleet : bool
        Whether this companion flies in a fleet (``companion fly --fleet``): peers' intents
        heard on obstacle links are used as ``[fleet]`` says (:mod:`companion.loop.peer_intents`),
        and each tick fills :attr:`fleet_outbox` with this drone's announcements
        (:mod:`companion.loop.fleet_announcer`) for the edge to send on the fleet link.
    replan_history : int or None
        Keep only the latest this many :attr:`records` (a live flight: a record is about 7 KB,
        3.3 a second); None keeps every one (lockstep runs, figures, campaigns). The run report
        reads :attr:`tally`, which sums every replan either way.
    """

    def __init__(self, scenario: CompanionScenario, offboard: OffboardConfig | None = None, *,
                 sequencer: OffboardSequence | None = None, planning: PlanningService | None = None,
                 goal: GoalSource | None = None, obstacle_sources: Sequence[ObstacleSource] | None = None,
                 reference: VehicleReference | None = None, fence: FenceSource | None = None,
                 fleet: bool = False, replan_history: int | None = None) -> None:
        self.scenario = scenario
        self.planner_config = scenario.planner
        self.settings = scenario.companion
        self.planning: PlanningService = planning or InlinePlanning(Planner(scenario.planner))
        self.sequencer: OffboardSequence = sequencer or OffboardSequencer(offboard or scenario.offboard)
        self.perception = Perception(scenario)
        #: the vehicle's origin and home: where geodetic traffic and goals are placed
        self.reference = reference if reference is not None else VehicleReference()
        #: the fleet's intents, and what this drone announces (None: no fleet)
        self.peers = PeerIntents(scenario.fleet, own_system=None) if fleet else None
        self.announcer = FleetAnnouncer(scenario.fleet, scenario.planner.step_s) if fleet else None
        #: where this vehicle's local frame sits in the fleet's (None: no fleet)
        self.fleet_frame = FleetFrame(scenario.fleet.origin, self.reference) if fleet else None
        #: this tick's messages for the fleet link (empty without a fleet)
        self.fleet_outbox: Outbox = []
        # obstacle links, traffic reports and GPS_GLOBAL_ORIGIN, onto the same tracks and time base
        self.obstacles = ObstacleIntake(scenario.traffic, self.perception.tracker, self.perception.vehicle_time,
                                        self.settings.obstacle_radius_m, reference=self.reference, peers=self.peers,
                                        fleet_frame=self.fleet_frame)
        plan = read_mission_file(scenario.mission.plan_file) if scenario.mission.plan_file is not None else None
        if goal is None and plan is not None:  # a mission file named by the scenario
            goal = MissionGoal(scenario.mission, self.reference, plan, upload=scenario.mission.plan_upload)
        elif goal is None and scenario.mission.goal is None:  # given relative to home or on the earth
            goal = PlacedGoal(scenario.mission, self.reference)
        #: the geofence the plans keep to (default: the scenario's, :func:`~companion.loop.fence_source.scenario_fence`)
        self.fence = fence if fence is not None else scenario_fence(scenario.mission, self.reference, plan)
        self.builder = RequestBuilder(scenario, obstacle_radius=self.obstacles.radius,
                                      obstacle_range=self.obstacles.planning_range, goal=goal, sources=obstacle_sources,
                                      fence=self.fence, peers=self.peers,
                                      right_of_way=_right_of_way(scenario) if fleet else None)
        self.executor = Executor(scenario.planner, 1.0 / self.settings.setpoint_rate_hz, self.planner.lag,
                                 max_plan_age_s=self.settings.max_plan_age_s,
                                 brake_accel_mps2=self.settings.brake_accel_mps2)
        self.state = CompanionState()
        #: the applied replans' records: every one, or the latest ``replan_history`` (a live flight)
        self.records: MutableSequence[ReplanRecord] = [] if replan_history is None else deque(maxlen=replan_history)
        #: every applied replan summed, for the report (whatever ``records`` keeps)
        self.tally = ReplanTally()
        self.supervisor = Supervisor(self.settings.timesync_hz, events=self.state.events)
        self.cycle = PlanCycle(self.planner_config, self.settings, planning=self.planning, builder=self.builder,
                               executor=self.executor, perception=self.perception, supervisor=self.supervisor,
                               state=self.state, records=self.records, tally=self.tally,
                               on_goal_reached=self.sequencer.on_goal_reached, on_at_goal=self.sequencer.on_at_goal)
        #: the autopilot's progress through its own mission, as it reports it
        self.progress = MissionProgress()
        self.inbound = InboundRouter(self.obstacles, self.perception, self.sequencer, self.state, self.progress)
        self.commanding = Commanding(self.settings, perception=self.perception, executor=self.executor,
                                     cycle=self.cycle, supervisor=self.supervisor, goal=self.builder.goal,
                                     state=self.state)
        #: hand-backs requested from outside the loop, as (link time s, reason), in order
        self.hand_backs: list[tuple[float, str]] = []
        self.goal_stage = GoalStage(self.builder.goal, self.sequencer, self.supervisor, fence=self.fence)
        #: the autopilot's own mission flight watched (``[offboard] takeover = "watch"`` or ``"guard"``), else None
        self.watch: MissionWatch | None = None
        #: takeovers on predicted conflicts (``[offboard] takeover = "guard"``), else None
        self.guard: MissionGuard | None = None
        takeover = getattr(getattr(self.sequencer, "config", None), "takeover", "always")
        if takeover in MISSION_TAKEOVERS:
            if not callable(getattr(self.builder.goal, "route_from", None)):
                raise ConfigError(f"takeover \"{takeover}\" needs a mission to watch: [mission] plan_file, or "
                                  "companion fly --mission FILE|vehicle")
            self.watch = MissionWatch(scenario.planner, self.settings, scenario.mission, builder=self.builder,
                                      supervisor=self.supervisor, progress=self.progress)
        if takeover == "guard":
            self.guard = MissionGuard(self.watch, self.sequencer, self.builder.goal, self.cycle, self.supervisor)
            self.commanding.mirror = True   # guarding: the stream carries the vehicle's own velocity

    @property
    def goal_error(self) -> str | None:
        """Why the goal could not be placed (the run gave up before flying), else None."""
        return self.goal_stage.error

    @property
    def planner(self) -> Planner:
        """The planner the planning service solves with."""
        return self.planning.planner

    @property
    def goal(self) -> GoalSource:
        """Where the companion is going."""
        return self.builder.goal

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
        """(system, component) of the autopilot the companion follows (the first one heard)."""
        return self.sequencer.target

    def vehicle_time(self, t_s: float) -> float | None:
        """Vehicle time (s since its boot) corresponding to link time ``t_s``."""
        return self.perception.vehicle_time(t_s)

    def plan_lead_s(self) -> float:
        """How long after its request the next plan starts (s; see :meth:`PlanCycle.lead_s`)."""
        return self.cycle.lead_s()

    @property
    def plan_arrivals(self) -> tuple[PlanArrival, ...]:
        """The jobs the last :meth:`tick` collected from an asynchronous planning service (and
        every job lost), oldest first; the real-time edge marks them in its tlog."""
        return tuple(self.cycle.arrivals)

    def handle(self, rx: Received) -> Outbox:
        """Take one inbound message; return what must answer it at once (never raises for bad content)."""
        if self.goal_stage.takes(rx.msg.get_type()):
            return self.goal_stage.route(rx.t_s, rx.msg)
        return self.inbound.route(rx)

    def hand_back(self, t_s: float, reason: str) -> bool:
        """Hand the vehicle back (Hold, streaming until the HEARTBEAT shows it) on an outside request at
        link time ``t_s``, made after that tick (a signal, the run's end); whether it started. A
        started one is kept in :attr:`hand_backs` so the edge can mark it in the tlog and a replay
        can make the same request."""
        started = self.sequencer.hand_back(t_s, reason)
        if started:
            self.hand_backs.append((t_s, reason))
        return started

    def on_signatures_rejected(self, total: int) -> None:
        """The links' running count of packets dropped for a bad or missing signature (reported by
        the real-time edge before every tick; the next tick announces new rejections)."""
        self.supervisor.signatures_rejected(total)

    def tick(self, t_s: float) -> Outbox:
        """Advance the loop to link time ``t_s`` and return the messages to send now (to the
        autopilot; the fleet's are in :attr:`fleet_outbox`)."""
        out = self._tick(t_s)
        if self.announcer is not None:
            self.fleet_outbox = self._announce(t_s)
        return out

    def _announce(self, t_s: float) -> Outbox:
        """This tick's fleet messages: the estimate, and the plan in force while one is tracked."""
        if self.peers.own_system is None and self.autopilot is not None:
            self.peers.own_system = self.autopilot[0]   # the fleet knows this drone by its vehicle's system id
        estimate = self.perception.drone.state
        flying = self.sequencer.state.streaming and self.state.mode is LoopMode.TRACKING
        ex = self.executor
        return self.announcer.outbox(t_s, estimate, ex.plan if flying else None, ex.plan_t0_v, ex.plan_p0,
                                     self.fleet_frame.offset())

    def _tick(self, t_s: float) -> Outbox:
        self.cycle.begin_tick()
        out: Outbox = self.supervisor.heartbeat(t_s)
        out.extend(self.goal_stage.before_sequence(t_s, self.autopilot))
        if self.guard is not None:   # a takeover or a hand-back asked now goes out with this tick's actions
            out.extend(self.guard.step(t_s, self.perception))
        for action in self.sequencer.step(t_s):
            if isinstance(action, SendCommand):
                out.append(action.msg)
            elif isinstance(action, Notify):
                out.append(self.supervisor.say(t_s, action.event.severity, action.event.text))
        out.extend(self.goal_stage.after_sequence(t_s))
        out.extend(self.supervisor.link_warnings(t_s))
        out.extend(self.supervisor.clock_warning(t_s, self.perception.clock.disagrees))
        if self.supervisor.timesync_due(t_s, self.autopilot is not None):
            out.append(messages.timesync(0, self.perception.clock.request(t_s)))
        requests, texts = self.obstacles.outbound(t_s, self.autopilot)
        out.extend(requests)
        out.extend(self.supervisor.say(t_s, severity, text) for severity, text in texts)
        seq = self.sequencer.state
        if not seq.streaming:
            out.extend(self.commanding.released(t_s))
            if self.watch is not None and seq.phase is Phase.WATCHING:
                out.extend(self.watch.step(t_s, self.perception, bool(getattr(self.sequencer, "vehicle_in_mission", False))))
            return out
        command, said = self.commanding.command(t_s, seq.engaged)
        out.extend(said)
        out.append(self.commanding.setpoint(t_s, seq.engaged, command, self.autopilot))
        why = self.commanding.braked_to_a_stop(t_s, seq.engaged, command, brake_hand_back_s(self.sequencer))
        if why is not None:  # this tick's request; it goes out with the next tick's commands
            self.sequencer.hand_back(t_s, why)
        return out


def _right_of_way(scenario: CompanionScenario) -> RightOfWay | None:
    """The fleet's rules of the road for this drone (``[fleet] keep_right``), or None."""
    fleet = scenario.fleet
    if not fleet.keep_right:
        return None
    return RightOfWay(scenario.planner.horizon_steps * scenario.planner.step_s, after_s=fleet.deadlock_after_s,
                      progress_m=fleet.deadlock_progress_m, recovery_s=fleet.recovery_s)
