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
from companion.mavlink.messages import Key, PoseObservation
from estimator import DroneFilter, ObstacleTracker, PositionDrift, Reason

logger = logging.getLogger(__name__)


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
        window = scenario.loop.drift_window_s
        #: The drift of the autopilot's position estimate against its velocity, when asked for.
        self.drift = PositionDrift(window) if window > 0.0 else None
        self.tracker = ObstacleTracker(scenario.tracker)
        #: Link time onto the autopilot's clock (pose arrivals, TIMESYNC answers).
        self.clock = VehicleClock()
        self._uses_odometry = False
        self._ignored_keys: set[Key] = set()
        #: The autopilot's own position covariance from ODOMETRY (m^2, NED), if it reports one.
        self.reported_cov: np.ndarray | None = None
        #: The response model's internal state, observed (``[companion] response_state = "observed"``).
        self.response: ResponseObserver | None = None
        if scenario.loop.response_state == "observed":
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

    def drift_mps(self) -> np.ndarray:
        """How fast the autopilot's position estimate moves against its velocity estimate (m/s NED;
        zeros when ``[companion] drift_window_s`` is 0)."""
        return np.zeros(3) if self.drift is None else self.drift.value()

    def vehicle_time(self, t_s: float) -> float | None:
        """Vehicle time (s since its boot) corresponding to link time ``t_s``; None before any pose."""
        return self.clock.vehicle_time(t_s)
