"""Perception: the drone filter, the obstacle tracks and the time base that joins them to the link.

Time bases: *link time* (wall clock on a real link, simulated time in lockstep) schedules
replans and setpoints; *vehicle time* (the autopilot's boot clock, from the messages'
own stamps) stamps the estimates. :class:`~companion.loop.vehicle_clock.VehicleClock`
joins them: the smallest ``t_rx - t_msg`` of the autopilot's recent accepted pose messages
(latency only adds to it), lowered by its TIMESYNC answers where they show the latency.
"""

from __future__ import annotations

import enum
import logging

import numpy as np

from companion.core.planner.response_observer import ResponseObserver
from companion.core.planner.vehicle_model import ResponseModel
from companion.loop.config import CompanionScenario
from companion.loop.vehicle_clock import VehicleClock
from companion.loop.vehicle_clock_line import TimesyncLineClock
from companion.mavlink.messages import Key, PoseObservation
from estimator import DroneFilter, ObstacleTracker, PositionDrift, Reason

logger = logging.getLogger(__name__)

#: A LOCAL_POSITION_NED (no reset counter) this far (m) from the drone filter's prediction, less
#: than :data:`JUMP_WITHIN_S` after the previous report, is the autopilot's estimator reset: no
#: multicopter moves a metre between two reports at 30 Hz or more.
LOCAL_POSITION_JUMP_M = 1.0
JUMP_WITHIN_S = 0.5


class PoseOutcome(enum.Enum):
    """What became of one pose observation."""

    DRONE = "drone"                        # fused into the drone filter
    DRONE_REJECTED = "drone_rejected"      # the drone filter's gate refused it
    OBSTACLE = "obstacle"                  # fused into a track
    OBSTACLE_REJECTED = "obstacle_rejected"
    IGNORED = "ignored"                    # no autopilot yet, a duplicate source, or our own vehicle's component


class Perception:
    """Filters and the vehicle-time base, fed with decoded pose observations.

    Parameters
    ----------
    scenario : CompanionScenario
        Its ``drone_filter`` and ``tracker`` settings are used.
    """

    def __init__(self, scenario: CompanionScenario) -> None:
        self.drone = DroneFilter(scenario.drone_filter)
        window = scenario.companion.drift_window_s
        #: The drift of the autopilot's position estimate against its velocity, when asked for.
        self.drift = PositionDrift(window) if window > 0.0 else None
        self.tracker = ObstacleTracker(scenario.tracker)
        #: Link time onto the autopilot's clock (pose arrivals, TIMESYNC answers).
        self.clock = VehicleClock() if scenario.companion.vehicle_clock == "arrivals" else TimesyncLineClock()
        self._uses_odometry = False
        self._ignored_keys: set[Key] = set()
        self._reset_counter: int | None = None
        #: The autopilot's estimator resets seen: (vehicle time s of the first report after it,
        #: the jump of the reported position, NED m). Its length is the reset epoch.
        self.resets: list[tuple[float, np.ndarray]] = []
        #: The autopilot's own position covariance from ODOMETRY (m^2, NED), if it reports one.
        self.reported_cov: np.ndarray | None = None
        #: The response model's internal state, observed (``[companion] response_state = "observed"``).
        self.response: ResponseObserver | None = None
        if scenario.companion.response_state == "observed":
            planner = scenario.planner
            self.response = ResponseObserver(ResponseModel(planner.step_s, *planner.vehicle_response))

    def observe(self, t_rx: float, obs: PoseObservation, autopilot: Key | None) -> PoseOutcome:
        """Fuse one pose observation received at link time ``t_rx`` (s).

        The autopilot's poses feed the drone filter, every other system's an obstacle track.
        """
        if autopilot is None:
            return PoseOutcome.IGNORED  # no frame of reference yet: the vehicle is unknown
        if obs.key == autopilot:
            # One source only: fusing ODOMETRY and LOCAL_POSITION_NED of the same estimate
            # would count the same information twice and make the filter overconfident.
            if obs.source == "ODOMETRY":
                self._uses_odometry = True
            elif self._uses_odometry:
                return PoseOutcome.IGNORED
            self._reset_if_jumped(obs)
            result = self.drone.update(obs.t_s, obs.position_ned, obs.velocity_ned, obs.position_var, obs.velocity_var)
            if not result.accepted:
                return PoseOutcome.DRONE_REJECTED
            if self.drift is not None:
                if result.reason in (Reason.INITIALISED, Reason.REINITIALISED):
                    self.drift.clear()       # a new estimate after a gap: no rate across it
                if obs.velocity_ned is not None:
                    self.drift.add(obs.t_s, obs.position_ned, obs.velocity_ned)
            if self.response is not None and obs.velocity_ned is not None:
                self.response.observe(obs.t_s, obs.velocity_ned)
            self.clock.observe_pose(t_rx, obs.t_s)
            if obs.position_cov is not None:
                self.reported_cov = obs.position_cov
            return PoseOutcome.DRONE
        if obs.key[0] == autopilot[0]:
            if obs.key not in self._ignored_keys:
                logger.info("ignoring pose from component %d of the vehicle's own system", obs.key[1])
                self._ignored_keys.add(obs.key)
            return PoseOutcome.IGNORED
        result = self.tracker.update(obs.key, obs.t_s, obs.position_ned, obs.velocity_ned, obs.position_cov, obs.velocity_cov)
        return PoseOutcome.OBSTACLE if result.accepted else PoseOutcome.OBSTACLE_REJECTED

    @property
    def reset_epoch(self) -> int:
        """How many estimator resets of the autopilot have been seen (plans of an older epoch are stale)."""
        return len(self.resets)

    def _reset_if_jumped(self, obs: PoseObservation) -> None:
        """Forget the drone estimate when the autopilot's estimator reset: ODOMETRY's ``reset_counter``
        changed, or (LOCAL_POSITION_NED) the position jumped :data:`LOCAL_POSITION_JUMP_M` from the
        prediction. Reports either side of a reset are a jump apart: blended, they would make a
        position between the two and a velocity out of the jump."""
        counter, previous = obs.reset_counter, self._reset_counter
        if counter is not None:
            self._reset_counter = counter
        state = self.drone.state
        if state is None:
            return
        predicted = state.position + state.velocity * max(0.0, obs.t_s - state.t_s)
        jump = np.asarray(obs.position_ned, dtype=float) - predicted
        if counter is not None and previous is not None:
            if counter == previous:
                return
        elif obs.source == "ODOMETRY" or not (0.0 <= obs.t_s - state.t_s <= JUMP_WITHIN_S
                                             and float(np.linalg.norm(jump)) > LOCAL_POSITION_JUMP_M):
            return
        logger.warning("autopilot estimator reset at t=%.3f s (%s): position jumped %s m; estimate restarted",
                       obs.t_s, f"reset_counter {previous} -> {counter}" if counter is not None else "LOCAL_POSITION_NED jump",
                       np.round(jump, 2).tolist())
        self.resets.append((float(obs.t_s), jump))
        self.drone.reset()
        if self.drift is not None:
            self.drift.clear()
        if self.response is not None:
            self.response.reset()

    # ------------------------------------------------------------------ the plans' frame

    def plan_velocity(self) -> np.ndarray:
        """The drone's velocity in the plans' frame (NED m/s): the estimate's position rate, that
        is the velocity estimate plus the drift (see ``[companion] drift_window_s``)."""
        velocity = self.drone.state.velocity
        return velocity + self.drift_mps() if self.drift is not None else velocity

    def autopilot_command(self, command: np.ndarray) -> np.ndarray:
        """A velocity of the plans' frame as the autopilot's velocity loop must get it (NED m/s):
        less the estimate's drift (the inverse of :meth:`plan_velocity`)."""
        return command - self.drift_mps() if self.drift is not None else command

    def response_state(self, t_v: float) -> np.ndarray | None:
        """The response model's internal state at vehicle time ``t_v`` for a plan's start (None
        unless ``[companion] response_state = "observed"``).

        The observer's state is the autopilot's, which holds its velocity; the plan's model runs
        on velocity + drift, so its state also holds the drift's drag (else the model would brake
        the drift away: k d, 0.4 m/s^2 for 0.5 m/s east on PX4 SITL).
        """
        if self.response is None:
            return None
        state = self.response.internal(t_v)
        if state is not None and self.drift is not None:
            state = state + self.response.model.steady_internal(self.drift_mps())
        return state

    def setpoint_sent(self, t_s: float, engaged: bool, command: np.ndarray) -> None:
        """The velocity setpoint just sent at link time ``t_s`` (autopilot frame), for the response
        observer: while engaged its velocity loop follows our setpoints; before, it is the
        autopilot's own, so the observer starts afresh from the first report after."""
        if self.response is None:
            return
        t_v = self.vehicle_time(t_s)
        if not engaged or t_v is None:
            self.response.reset()
            return
        self.response.command(t_v, command)

    def released(self) -> None:
        """No setpoint of ours is in force (not streaming): the response observer starts afresh."""
        if self.response is not None:
            self.response.reset()

    def drift_mps(self) -> np.ndarray:
        """How fast the autopilot's position estimate moves against its velocity estimate (m/s NED;
        zeros when ``[companion] drift_window_s`` is 0)."""
        return np.zeros(3) if self.drift is None else self.drift.value()

    def vehicle_time(self, t_s: float) -> float | None:
        """Vehicle time (s since its boot) corresponding to link time ``t_s``; None before any pose."""
        return self.clock.vehicle_time(t_s)
