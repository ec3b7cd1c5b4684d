"""The companion's control loop: estimate, plan, command — as a function of messages and time.

:class:`Companion` owns no socket and reads no clock. The edge feeds it every inbound
message with :meth:`Companion.handle` and calls :meth:`Companion.tick` at the setpoint
rate with the link time; ``tick`` returns the MAVLink messages to send. Filters run on
the messages' own timestamps (vehicle time since boot), so a replayed tlog that calls
the same ticks with the same messages reproduces the same commands.

Time bases: *link time* ``t_s`` (wall clock for a real link, simulated time in
lockstep) schedules replans and setpoints; *vehicle time* stamps the estimates. The
offset between them is the smallest ``t_rx - t_msg`` of the autopilot's recent pose
messages (latency only adds to it).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages
from companion.mavlink.link import Received
from companion.mavlink.offboard import Notify, OffboardConfig, OffboardSequencer, SendCommand
from companion.core.overlap import contour_of_touch
from companion.core.planner import Plan, Planner, PlanRequest
from companion.loop.config import CompanionScenario
from estimator import DroneFilter, ObstacleTracker

logger = logging.getLogger(__name__)

SEV_WARNING = mavlink2.MAV_SEVERITY_WARNING
SEV_NOTICE = mavlink2.MAV_SEVERITY_NOTICE
SEV_INFO = mavlink2.MAV_SEVERITY_INFO

_HEARTBEAT_PERIOD_S = 1.0
_SLACK_WARN_PERIOD_S = 2.0


@dataclass(frozen=True)
class ReplanRecord:
    """One replanning cycle, for summaries, figures and replay comparison.

    Positions and covariances are NED metres / square metres in vehicle time ``t_vehicle_s``.
    ``realised_contour`` is the contour of touch between the drone's current estimate and
    each tracked obstacle's current estimate (physical radii included), keyed by track.
    """

    t_link_s: float
    t_vehicle_s: float
    status: str
    iterations: int
    solve_time_s: float
    slack_max: float
    planned_min_contour: float
    realised_contour: dict
    drone_position: np.ndarray
    drone_cov: np.ndarray
    drone_velocity: np.ndarray
    obstacle_positions: dict
    obstacle_covs: dict
    target: np.ndarray
    plan_positions: np.ndarray
    command: np.ndarray


@dataclass
class CompanionState:
    """What the loop is doing, for tests and the summary."""

    mode: str = "waiting"  # waiting | prestream | tracking | braking | stale | done | idle
    goal_reached_t_s: float | None = None
    braking_events: int = 0
    stale_events: int = 0
    failed_plans: int = 0
    slack_plans: int = 0
    obstacle_rejections: int = 0
    drone_rejections: int = 0
    messages_rejected: int = 0
    events: list = field(default_factory=list)


class Companion:
    """Estimator + planner + offboard sequence behind a message-in, message-out interface.

    Parameters
    ----------
    scenario : CompanionScenario
        Mission, planner, estimator, map and loop settings (``companion.loop.config``).
    offboard : OffboardConfig, optional
        Engagement settings (arming and takeoff are off unless asked for).
    """

    def __init__(self, scenario: CompanionScenario, offboard: OffboardConfig | None = None) -> None:
        self.scenario = scenario
        self.cfg = scenario.planner
        self.loop = scenario.loop
        self.planner = Planner(scenario.planner)
        self.drone = DroneFilter(scenario.drone_filter)
        self.tracker = ObstacleTracker(scenario.tracker)
        lp = scenario.loop
        self.sequencer = OffboardSequencer(offboard or lp.offboard_config())
        self.state = CompanionState()
        self.records: list[ReplanRecord] = []
        self._uses_odometry = False
        self._offsets: deque[tuple[float, float]] = deque(maxlen=64)
        self._plan: Plan | None = None
        self._plan_t0_v = 0.0
        self._plan_p0 = np.zeros(3)
        self._last_replan_t: float | None = None
        self._command = np.zeros(3)
        self._last_hb_t: float | None = None
        self._last_slack_warn = -math.inf
        self._route_start: np.ndarray | None = None
        self._dt = 1.0 / lp.setpoint_rate_hz
        self._statics = scenario.static_obstacles
        self._ignored_keys: set[tuple[int, int]] = set()
        self._reported_cov: np.ndarray | None = None  # the autopilot's own position covariance (ODOMETRY), m^2

    @property
    def autopilot(self) -> tuple[int, int] | None:
        """(system, component) of the PX4 autopilot the companion follows (the first one heard)."""
        return self.sequencer.target

    # ------------------------------------------------------------------ inbound

    def handle(self, rx: Received) -> None:
        """Take one inbound message (never raises for bad content: it is logged and counted)."""
        if rx.msg.get_type() == "HOME_POSITION" and self.autopilot is not None and messages.source_key(rx.msg) == self.autopilot:
            self.sequencer.on_home_altitude(rx.msg.altitude / 1000.0)  # mm AMSL -> m
            return
        decoded = messages.decode(rx.msg)
        if decoded is None:
            return
        if isinstance(decoded, messages.Rejected):
            self.state.messages_rejected += 1
            if self.autopilot is not None and decoded.key == self.autopilot:
                self.state.drone_rejections += 1
            else:
                self.state.obstacle_rejections += 1
            return
        if isinstance(decoded, messages.VehicleHeartbeat):
            known = self.autopilot
            self.sequencer.on_heartbeat(rx.t_s, decoded)  # follows the first PX4 autopilot, ignores the rest
            if known is None and self.autopilot is not None:
                logger.info("autopilot found: system %d component %d", *self.autopilot)
            return
        if isinstance(decoded, messages.CommandAck):
            if decoded.key == self.autopilot:
                self.sequencer.on_ack(rx.t_s, decoded)
            return
        if isinstance(decoded, messages.StatusText):
            if decoded.key == self.autopilot:
                self.sequencer.on_statustext(rx.t_s, decoded.text)
            return
        if isinstance(decoded, messages.PoseObservation):
            self._handle_pose(rx.t_s, decoded)

    def _handle_pose(self, t_rx: float, obs: messages.PoseObservation) -> None:
        if self.autopilot is None:
            return  # no frame of reference yet: the vehicle is unknown
        if obs.key == self.autopilot:
            # One source only: fusing ODOMETRY and LOCAL_POSITION_NED of the same estimate
            # would count the same information twice and make the filter overconfident.
            if obs.source == "ODOMETRY":
                self._uses_odometry = True
            elif self._uses_odometry:
                return
            result = self.drone.update(obs.t_s, obs.position_ned, obs.velocity_ned, obs.position_var, obs.velocity_var)
            if result.accepted:
                self._offsets.append((t_rx, t_rx - obs.t_s))
                if obs.position_cov is not None:
                    self._reported_cov = obs.position_cov
            else:
                self.state.drone_rejections += 1
            return
        if obs.key[0] == self.autopilot[0]:
            if obs.key not in self._ignored_keys:
                logger.info("ignoring pose from component %d of the vehicle's own system", obs.key[1])
                self._ignored_keys.add(obs.key)
            return
        result = self.tracker.update(obs.key, obs.t_s, obs.position_ned, obs.velocity_ned, obs.position_cov, obs.velocity_cov)
        if not result.accepted:
            self.state.obstacle_rejections += 1

    # ------------------------------------------------------------------ outbound

    def vehicle_time(self, t_s: float) -> float | None:
        """Vehicle time (s since its boot) corresponding to link time ``t_s``."""
        recent = [off for t, off in self._offsets if t >= t_s - 2.0] or [off for _, off in self._offsets]
        return None if not recent else t_s - min(recent)

    def tick(self, t_s: float) -> list[mavlink2.MAVLink_message]:
        """Advance the loop to link time ``t_s`` and return the messages to send now."""
        out: list[mavlink2.MAVLink_message] = []
        if self._last_hb_t is None or t_s - self._last_hb_t >= _HEARTBEAT_PERIOD_S - 1e-9:
            out.append(messages.companion_heartbeat())
            self._last_hb_t = t_s
        for action in self.sequencer.step(t_s):
            if isinstance(action, SendCommand):
                out.append(action.msg)
            elif isinstance(action, Notify):
                out.append(self._say(t_s, action.event.severity, action.event.text))
        seq = self.sequencer.state
        if not seq.streaming:
            if self.state.mode not in ("waiting", "idle"):
                self.state.mode = "idle"
            self._command = np.zeros(3)
            return out
        t_boot_ms = int(round(t_s * 1000.0))
        if not seq.engaged:
            self.state.mode = "prestream"
            self._command = np.zeros(3)  # hover while PX4 is asked to switch
        else:
            self._command = self._engaged_command(t_s, out)
        target = dict(zip(("target_system", "target_component"), self.autopilot or (1, 1)))
        reference = self._plan_reference(t_s) if seq.engaged and self.loop.setpoint_kind == "position_velocity" else None
        if reference is not None:
            out.append(messages.position_velocity_setpoint(t_boot_ms, *reference, **target))
        else:
            out.append(messages.velocity_setpoint(t_boot_ms, self._command, **target))
        return out

    def _plan_reference(self, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Position and velocity of the current plan at link time ``t_s`` (NED m, m/s), while tracking it.

        The position interpolates the plan's step-end positions from where it started;
        the velocity is the vehicle's under the plan's commands (the planner's model).
        PX4's position loop then adds ``MPC_XY_P (p - p_est)`` to the feed-forward.
        """
        t_v = self.vehicle_time(t_s)
        if self.state.mode != "tracking" or self._plan is None or t_v is None:
            return None
        dt = t_v - self._plan_t0_v
        plan, tau = self._plan, self.cfg.step_s
        times = tau * np.arange(plan.positions.shape[0] + 1)
        points = np.vstack([self._plan_p0[None], plan.positions])
        position = np.array([np.interp(dt, times, points[:, k]) for k in range(3)])
        velocity = self.planner.lag.velocity_at(plan.initial_velocity, plan.commands, dt)
        return position, np.asarray(velocity, dtype=float)

    def _say(self, t_s: float, severity: int, text: str) -> mavlink2.MAVLink_statustext_message:
        self.state.events.append((t_s, text))
        logger.info("%s", text)
        return messages.statustext(severity, text)

    def _brake(self) -> np.ndarray:
        """Velocity one setpoint period closer to zero, within the acceleration bound."""
        step = self.cfg.accel_max * self._dt
        return np.sign(self._command) * np.maximum(np.abs(self._command) - step, 0.0)

    def _engaged_command(self, t_s: float, out: list) -> np.ndarray:
        t_v = self.vehicle_time(t_s)
        est = self.drone.state
        if t_v is None or est is None or t_v - est.t_s > self.loop.estimate_timeout_s:
            if self.state.mode != "stale":
                self.state.stale_events += 1
                out.append(self._say(t_s, SEV_WARNING, "companion: estimate stale, braking"))
            self.state.mode = "stale"
            self._plan = None
            return self._brake()
        if self.state.mode == "stale":
            out.append(self._say(t_s, SEV_NOTICE, "companion: estimate back, resuming"))
        if self._route_start is None:
            self._route_start = est.position.copy()
        # Replan every replan_period, also while braking for lack of a plan (no 20 Hz retry storm).
        due = self._last_replan_t is None or t_s - self._last_replan_t >= self.cfg.replan_period_s - 1e-9
        if due:
            self._replan(t_s, t_v, out)
        if self._plan is None:
            self.state.mode = "braking"
            return self._brake()
        if self.state.mode == "braking":
            out.append(self._say(t_s, SEV_NOTICE, "companion: valid plan again, resuming"))
        k = int(math.floor((t_v - self._plan_t0_v) / self.cfg.step_s + 1e-9))
        if k >= self.cfg.horizon_steps:
            self.state.mode = "braking"
            return self._brake()
        self.state.mode = "tracking"
        return np.asarray(self._plan.commands[max(k, 0)], dtype=float).copy()

    # ------------------------------------------------------------------ planning

    def _target(self, position: np.ndarray) -> np.ndarray:
        """Intermediate waypoint on the straight route from where the companion took over to the goal."""
        goal = self.scenario.mission.goal
        start = self._route_start if self._route_start is not None else position
        route = goal - start
        length = float(np.linalg.norm(route))
        if length < 1e-9:
            return goal.copy()
        along = float(np.dot(position - start, route) / length)
        s = min(length, max(0.0, along) + self.scenario.mission.waypoint_spacing_m)
        return start + route * (s / length)

    def _leads_the_way(self, position: np.ndarray, obstacle: np.ndarray) -> bool:
        """Whether an obstacle is between the drone and its goal along the line to the goal.

        The ``c_max`` upper bound (keep the ``c_max`` contours touching) is meant for
        following an obstacle that leads the way through a tight space; it is released
        once that obstacle is behind the drone or past the goal, so the drone stops at
        its goal instead of being dragged along.
        """
        to_goal = self.scenario.mission.goal - position
        length = float(np.linalg.norm(to_goal))
        if length < 1e-9:
            return False
        along = float(np.dot(obstacle - position, to_goal) / length)
        return 0.0 < along < length

    def _initial_velocity(self, est, t_v: float) -> np.ndarray:
        """``V_0`` of the next plan, NED m/s, at vehicle time ``t_v``.

        The velocity the vehicle flies under the commands sent so far, as the planner's
        model predicts it: without a velocity lag (the paper's model) that is the last
        command; with one, the current plan's velocity at ``t_v`` (its commands run
        through the planner's :class:`~companion.core.planner.vehicle_model.LagModel`). Both are smooth.
        Feeding the estimated velocity back instead (reports with 0.1 m/s noise) made
        the corridor runs weave: 0.6-0.75 m from the walls against 0.98 m (6 seeds).
        Without a current plan (braking, or before the first) the estimate is used.
        """
        if self.planner.lag.instantaneous:
            return self._command.copy()
        if self._plan is None:
            return np.asarray(est.velocity, dtype=float).copy()
        return self.planner.lag.velocity_at(self._plan.initial_velocity, self._plan.commands, t_v - self._plan_t0_v)

    def _replan(self, t_s: float, t_v: float, out: list) -> None:
        est = self.drone.state
        n, tau = self.cfg.horizon_steps, self.cfg.step_s
        lag = max(0.0, t_v - est.t_s)
        position = est.position + est.velocity * lag
        if self.loop.drone_covariance == "reported" and self._reported_cov is not None:
            cov_now = self._reported_cov + self.loop.drone_cov_floor_m2 * np.eye(3)
        else:
            cov_now = est.position_cov + self.loop.drone_cov_floor_m2 * np.eye(3)
        if self.loop.drone_covariance == "predicted":
            drone_covs = self.drone.predict_position_covariances(t_v, np.zeros((n, 3)), tau) + self.loop.drone_cov_floor_m2 * np.eye(3)
        else:
            drone_covs = np.broadcast_to(cov_now, (n, 3, 3)).copy()
        if np.linalg.norm(position - self.scenario.mission.goal) <= self.scenario.mission.goal_tolerance_m and self.state.goal_reached_t_s is None:
            self.state.goal_reached_t_s = t_s
            self.sequencer.on_goal_reached(t_s)
            out.append(self._say(t_s, SEV_INFO, "companion: goal reached"))

        self.tracker.prune(t_v)
        times = t_v + tau * np.arange(1, n + 1)
        keys = list(self.tracker.keys())
        means, covs, radii, now_pos, now_cov = [], [], [], {}, {}
        for key in keys:
            m, c = self.tracker.predict(key, times)
            m0, c0 = self.tracker.predict(key, np.array([t_v]))
            means.append(m)
            covs.append(c)
            radii.append(self.loop.obstacle_radius_m)
            now_pos[key], now_cov[key] = m0[0], c0[0]
        for i, s in enumerate(self._statics):
            means.append(np.broadcast_to(s.center, (n, 3)))
            covs.append(np.broadcast_to(s.covariance, (n, 3, 3)))
            radii.append(s.radius)
        target = self._target(position)
        leading = [self._leads_the_way(position, now_pos[k]) for k in keys] + [False] * len(self._statics)
        request = PlanRequest(
            position=position,
            velocity=self._initial_velocity(est, t_v),
            drone_covs=drone_covs,
            target=target,
            obstacle_means=np.array(means).reshape(-1, n, 3),
            obstacle_covs=np.array(covs).reshape(-1, n, 3, 3),
            obstacle_radii=np.array(radii, dtype=float),
            walls_normal=self.scenario.walls_normal,
            walls_offset=self.scenario.walls_offset,
            upper_bound_mask=np.array(leading, dtype=bool),
        )
        plan = self.planner.solve(request, warm_start=self._plan)
        self._last_replan_t = t_s
        realised = {}
        if keys:
            ct = contour_of_touch(
                np.broadcast_to(position, (len(keys), 3)),
                np.broadcast_to(cov_now, (len(keys), 3, 3)),
                np.array([now_pos[k] for k in keys]),
                np.array([now_cov[k] for k in keys]),
                self.cfg.drone_radius_m + self.loop.obstacle_radius_m,
            )
            realised = {k: float(v) for k, v in zip(keys, np.atleast_1d(ct))}
        if realised:
            out.append(messages.named_value_float(int(round(t_s * 1000)), "ct_min", min(realised.values())))
        if plan.status == "failed":
            self.state.failed_plans += 1
            if self._plan is not None or self.state.mode != "braking":
                self.state.braking_events += 1
                out.append(self._say(t_s, SEV_WARNING, "companion: no valid plan, braking"))
            self._plan = None
        else:
            if plan.status == "slack":
                self.state.slack_plans += 1
                if t_s - self._last_slack_warn >= _SLACK_WARN_PERIOD_S:
                    self._last_slack_warn = t_s
                    out.append(self._say(t_s, SEV_WARNING, f"companion: safety slack used ({plan.slack_max:.2f})"))
            self._plan = plan
            self._plan_t0_v = t_v
            self._plan_p0 = position.copy()
        # Obstacles beyond sensing range were ignored by design: their contour says nothing.
        ct_plan = np.asarray(plan.contour_of_touch)[np.asarray(plan.in_range, dtype=bool)]
        self.records.append(
            ReplanRecord(
                t_link_s=t_s,
                t_vehicle_s=t_v,
                status=plan.status,
                iterations=int(plan.iterations),
                solve_time_s=float(plan.solve_time_s),
                slack_max=float(plan.slack_max),
                planned_min_contour=float(ct_plan.min()) if ct_plan.size else math.nan,
                realised_contour=realised,
                drone_position=position.copy(),
                drone_cov=cov_now.copy(),
                drone_velocity=est.velocity.copy(),
                obstacle_positions=now_pos,
                obstacle_covs=now_cov,
                target=target,
                plan_positions=np.asarray(plan.positions).copy(),
                command=np.asarray(plan.commands[0]).copy() if plan.status != "failed" else np.zeros(3),
            )
        )
