"""Each inbound message routed once: to the obstacle intake, the vehicle state or the offboard sequence.

Obstacle links, traffic reports and GPS_GLOBAL_ORIGIN go to the
:class:`~companion.loop.intake.obstacles.ObstacleIntake` first (it claims what is its own); the
rest is decoded once (:func:`companion.mavlink.messages.decode`) and goes by kind: the
autopilot's HEARTBEATs to the sequence, poses to :class:`~companion.loop.perception.Perception`
(the autopilot's to the drone filter, other systems' to tracks), and the autopilot's
acknowledgements, texts, home position, clock and mission progress to where they belong. Bad
content is counted, never raised.
"""

from __future__ import annotations

import logging

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.engagement import OffboardSequence
from companion.loop.intake.obstacles import ObstacleIntake
from companion.loop.mission_watch import MissionProgress
from companion.loop.perception import Perception, PoseOutcome
from companion.loop.records import CompanionState
from companion.loop.vehicle_clock import link_ns
from companion.mavlink import messages
from companion.mavlink.link import Received

logger = logging.getLogger(__name__)


class InboundRouter:
    """Routes every inbound message of one companion (see the module docstring)."""

    def __init__(self, obstacles: ObstacleIntake, perception: Perception, sequencer: OffboardSequence,
                 state: CompanionState, progress: MissionProgress | None = None) -> None:
        self.obstacles, self.perception, self.sequencer, self.state = obstacles, perception, sequencer, state
        #: the autopilot's progress through its own mission (MISSION_CURRENT, MISSION_ITEM_REACHED)
        self.progress = progress if progress is not None else MissionProgress()

    def route(self, rx: Received) -> list[mavlink2.MAVLink_message]:
        """Take one inbound message; return what must answer it at once (the autopilot's TIMESYNC request)."""
        autopilot = self.sequencer.target
        if self.obstacles.claims(rx, autopilot):  # obstacle links, traffic, GPS_GLOBAL_ORIGIN
            return []
        decoded = messages.decode(rx.msg)
        if decoded is None:
            return []
        if isinstance(decoded, messages.Rejected):
            self.state.messages_rejected += 1
            if decoded.msg_type == "TIMESYNC":
                pass  # a clock message, not an estimate: counted, no filter involved
            elif autopilot is not None and decoded.key == autopilot:
                self.state.drone_rejections += 1
            else:
                self.state.obstacle_rejections += 1
        elif isinstance(decoded, messages.VehicleHeartbeat):
            self.sequencer.on_heartbeat(rx.t_s, decoded)  # follows the first autopilot, ignores the rest
            if autopilot is None and self.sequencer.target is not None:
                logger.info("autopilot found: system %d component %d", *self.sequencer.target)
        elif isinstance(decoded, messages.PoseObservation):
            if autopilot is not None and decoded.key == autopilot:  # a takeoff may end by the vehicle's height
                vz = None if decoded.velocity_ned is None else float(decoded.velocity_ned[2])
                self.sequencer.on_vehicle_position(rx.t_s, float(decoded.position_ned[2]), vz)
            outcome = self.perception.observe(rx.t_s, decoded, autopilot)
            if outcome is PoseOutcome.DRONE_REJECTED:
                self.state.drone_rejections += 1
            elif outcome is PoseOutcome.OBSTACLE_REJECTED:
                self.state.obstacle_rejections += 1
        elif decoded.key != autopilot:
            return []  # acknowledgements, texts, clocks and home positions count only from the autopilot
        elif isinstance(decoded, messages.TimeSync):
            return self._timesync(rx.t_s, decoded)
        elif isinstance(decoded, messages.CommandAck):
            self.sequencer.on_ack(rx.t_s, decoded)
        elif isinstance(decoded, messages.StatusText):
            self.sequencer.on_statustext(rx.t_s, decoded.text)
        elif isinstance(decoded, messages.HomePosition):
            self.sequencer.on_home_altitude(decoded.altitude_amsl_m)
            self.sequencer.on_home_local_z(decoded.local_z_m)
            self.obstacles.reference.on_home(decoded)  # where goals relative to home are placed
        elif isinstance(decoded, messages.EstimatorStatus):
            self.sequencer.on_estimator_status(rx.t_s, decoded.flags)
        elif isinstance(decoded, messages.LandedState):
            self.sequencer.on_landed_state(rx.t_s, decoded.on_ground)
        elif isinstance(decoded, messages.MissionCurrent):
            self.progress.on_current(rx.t_s, decoded)
        elif isinstance(decoded, messages.MissionItemReached):
            if self.progress.on_reached(rx.t_s, decoded.seq):
                logger.info("autopilot reached mission item %d", decoded.seq)
        return []

    def _timesync(self, t_rx: float, sync: messages.TimeSync) -> list[mavlink2.MAVLink_message]:
        """Answer the autopilot's TIMESYNC request, or take its answer to ours as a clock sample.

        PX4 asks at 10 Hz and uses only answers back within 10 ms, so the answer cannot wait
        for the next tick: the edge sends it as soon as :meth:`route` returns.
        """
        if sync.is_request:
            return [messages.timesync(max(1, link_ns(t_rx)), sync.ts1_ns)]  # tc1 0 would read as a request
        self.perception.clock.answer(t_rx, sync.tc1_ns, sync.ts1_ns)  # a disagreement is said at the next tick
        return []
