"""Avoidance on demand (``[offboard] takeover = "guard"``): take over on a predicted conflict, give back once clear.

The autopilot flies its own mission. :class:`MissionGuard` has the
:class:`~companion.loop.mission_watch.MissionWatch` judge the path the autopilot would fly
(every replan period, while the vehicle is armed in its mission mode) and, when a step of it
falls below ``c_min``, takes the vehicle over: the mission goal flies on from the autopilot's
current item (:meth:`~companion.loop.mission_goal.MissionGoal.resume_at`), a replan is asked
at once, and OFFBOARD is requested (:meth:`~companion.mavlink.offboard.OffboardSequencer.take_over`)
while the plan's setpoints already stream. Taken over, it judges the path the autopilot would
fly if given back now (from the vehicle's estimate through the waypoints the companion still
has to fly); once that is clear at :data:`CLEAR_EVALUATIONS` evaluations in a row, it makes
the companion's current item the autopilot's (MISSION_SET_CURRENT) and requests the mission
mode back (:meth:`~companion.mavlink.offboard.OffboardSequencer.resume_mission`). Every
takeover and hand-back is announced and kept for the report, with the time from the decision
to the HEARTBEAT showing OFFBOARD. Pure: link time (s) in, messages out.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.mission_watch import KEPT, MissionWatch
from companion.loop.perception import Perception
from companion.loop.plan_cycle import PlanCycle
from companion.loop.supervisor import SEV_NOTICE, SEV_WARNING, Supervisor
from companion.mavlink.mission_protocol import set_current
from companion.mavlink.offboard import Phase

logger = logging.getLogger(__name__)

Outbox = list[mavlink2.MAVLink_message]

#: Evaluations in a row (one a replan period) with the mission path clear before it is given back.
CLEAR_EVALUATIONS = 3


@dataclass
class Takeover:
    """One takeover, in link time (s): decided, confirmed by the HEARTBEAT (OFFBOARD), given back
    (the HEARTBEAT showing the mission mode again); ``reason`` as announced, ``item`` the
    autopilot's current item when it was taken."""

    start_s: float
    reason: str
    item: int | None
    offboard_s: float | None = None
    end_s: float | None = None

    @property
    def decision_to_offboard_s(self) -> float | None:
        return None if self.offboard_s is None else self.offboard_s - self.start_s


class MissionGuard:
    """Takeovers and hand-backs of a guarding companion (see the module docstring).

    Parameters
    ----------
    watch : judges the mission path (its progress is the autopilot's).
    sequencer : the offboard sequence (``take_over``, ``resume_mission``, ``vehicle_in_mission``).
    goal : the mission goal (``resume_at``, ``current_seq``).
    cycle : the replanning cycle (a replan asked at once on a takeover).
    supervisor : says what happened.
    """

    def __init__(self, watch: MissionWatch, sequencer, goal, cycle: PlanCycle, supervisor: Supervisor) -> None:
        self.watch, self.sequencer, self.goal, self.cycle, self.supervisor = watch, sequencer, goal, cycle, supervisor
        self.takeovers: deque[Takeover] = deque(maxlen=KEPT)
        self.takeover_count = 0
        self._current: Takeover | None = None
        self._clear = 0   # evaluations in a row with the path clear, taken over
        self._unflyable = None   # the conflict last found with no waypoint left to take over for

    def step(self, t_s: float, perception: Perception) -> Outbox:
        """This tick's part of the guard at link time ``t_s``: judge, take over, give back."""
        seq, phase = self.sequencer, self.sequencer.phase
        self._follow_phase(t_s, phase)
        if phase is Phase.GUARDING:
            before = self.watch.evaluations
            out = self.watch.step(t_s, perception, seq.vehicle_in_mission)
            conflict = self.watch.open
            if self.watch.evaluations > before and conflict is not None:   # (the stream may be too young yet)
                out.extend(self._take_over(t_s, self.watch.lead_s))
            return out
        if phase is Phase.ENGAGED and self._current is not None:
            before = self.watch.evaluations
            out = self.watch.step(t_s, perception, True, from_seq=self.goal.current_seq)
            if self.watch.evaluations > before:
                self._clear = self._clear + 1 if self.watch.open is None else 0
                if self._clear >= CLEAR_EVALUATIONS:
                    out.extend(self._give_back(t_s))
            return out
        return []

    def _follow_phase(self, t_s: float, phase: Phase) -> None:
        """Keep the current takeover's times as the sequence confirms them."""
        taken = self._current
        if taken is None:
            return
        if taken.offboard_s is None and phase is Phase.ENGAGED:   # since the HEARTBEAT that showed OFFBOARD
            since = self.sequencer.state.since_s
            taken.offboard_s = since if since is not None else t_s
        if phase not in (Phase.TAKING_OVER, Phase.ENGAGED, Phase.RESUMING_MISSION):
            taken.end_s = t_s
            self._current = None
            if phase is Phase.GUARDING and taken.offboard_s is None:
                logger.warning("takeover at %.2f s not confirmed; guarding on", taken.start_s)

    def _take_over(self, t_s: float, lead_s: float) -> Outbox:
        item = self.watch.progress.current_seq
        if item is None or not len(self.goal.route_from(item)):
            if self._unflyable is not self.watch.open:   # said once a conflict
                self._unflyable = self.watch.open
                logger.warning("conflict predicted with no waypoint left to fly (item %s): not taken over", item)
            return []
        reason = f"conflict in {lead_s:.1f} s"
        if not self.sequencer.take_over(t_s, reason):   # (not yet: the stream is too young)
            return []
        self.goal.resume_at(item)
        self.cycle.replan_now()
        self._current = Takeover(t_s, reason, item)
        self.takeovers.append(self._current)
        self.takeover_count += 1
        self._clear = 0
        return [self.supervisor.say(t_s, SEV_WARNING, f"companion: taking over, {reason}")]

    def _give_back(self, t_s: float) -> Outbox:
        item = self.goal.current_seq
        if item is None and self.goal.waypoints:   # the mission ends at its last waypoint: it, reached already
            item = self.goal.waypoints[-1].seq
        target = self.sequencer.target
        if item is None or target is None or not self.sequencer.resume_mission(t_s, "mission path clear"):
            return []
        self._clear = 0
        return [set_current(item, target),
                self.supervisor.say(t_s, SEV_NOTICE, f"companion: giving back, mission item {item}")]

    def items_reached(self) -> list[tuple[float, int, str]]:
        """Every mission item reached, in order, as (link time s, seq, by whom: ``"autopilot"`` flying
        its mission, ``"companion"`` while taken over); the latest :data:`KEPT`."""
        merged = [(t, seq, "autopilot") for t, seq in self.watch.progress.reached]
        merged += [(t, seq, "companion") for t, seq in getattr(self.goal, "reached_items", ())]
        return sorted(merged)[-KEPT:]

    def summary(self) -> dict:
        """For the run report: every takeover (link times s) and how many, and the items reached by either."""
        return {"mission_items_reached_by": [{"item": seq, "t_s": t, "by": by} for t, seq, by in self.items_reached()],
                "takeovers_count": self.takeover_count,
                "takeovers": [{"start_s": k.start_s, "offboard_s": k.offboard_s, "end_s": k.end_s, "reason": k.reason,
                               "item": k.item, "decision_to_offboard_s": k.decision_to_offboard_s}
                              for k in self.takeovers]}
