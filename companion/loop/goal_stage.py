"""The goal's part of each tick: place it before flying, feed it its messages, send what it says.

A plain goal (a point in local NED) needs nothing of this. A goal that must be placed
(relative to home, on the earth) or fetched (a mission on the vehicle) has ``prepare``:
until it is ready, the offboard sequence is held at its start (nothing armed, taken off or
streamed); once ready, the sequence is released (a mission's take-off item becomes the
take-off height when none was asked for); if it gives up, so does the sequence, with its
reason in :attr:`GoalStage.error`. A mission also takes the autopilot's MISSION_* messages
(``on_message``) and says things in flight (``take_outbound``: MISSION_SET_CURRENT, reached
items). A geofence (:mod:`companion.loop.fence_source`) is placed the same way, before the
goal. Pure: messages and link time (s) in, messages out.
"""

from __future__ import annotations

import dataclasses

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.engagement import OffboardSequence
from companion.loop.goal import GoalSource, Preparation
from companion.loop.supervisor import Supervisor
from companion.mavlink.offboard import OffboardConfig, Phase

Outbox = list[mavlink2.MAVLink_message]

#: s at the last waypoint of a mission that ends in a landing or a return before the vehicle is
#: handed back for it (flown in OFFBOARD, without ``--exit-after-goal``)
FINAL_ITEM_AFTER_S = 1.0


class GoalStage:
    """What a goal source needs of the loop besides being asked where to go."""

    def __init__(self, goal: GoalSource, sequencer: OffboardSequence, supervisor: Supervisor, fence=None) -> None:
        self.goal = goal
        #: the geofence to place before the goal (:class:`~companion.loop.fence_source.FenceSource`), or None
        self.fence = fence
        self.sequencer = sequencer
        self.supervisor = supervisor
        #: why the goal could not be placed (the run gave up before flying), else None
        self.error: str | None = None
        self.pending = callable(getattr(goal, "prepare", None)) or fence is not None
        self._messages = getattr(goal, "MISSION_MESSAGES", None) if callable(getattr(goal, "on_message", None)) else None
        self._outbound = getattr(goal, "take_outbound", None)
        if self.pending and callable(getattr(sequencer, "hold_start", None)):
            sequencer.hold_start("placing the goal")

    def takes(self, msg_type: str) -> bool:
        """Whether a message of this type is the goal's or the fence's (a mission transfer's)."""
        if self.fence is not None and self.fence.takes(msg_type):
            return True
        return self._messages is not None and msg_type in self._messages

    def route(self, t_s: float, msg) -> Outbox:
        """The goal's (or, while it downloads and reads, the fence's) message at link time ``t_s``; what answers it at once."""
        if self.fence is not None and self.fence.takes(msg.get_type()):
            return self.fence.on_message(t_s, msg)
        return self.goal.on_message(t_s, msg)  # type: ignore[attr-defined]

    def before_sequence(self, t_s: float, autopilot) -> Outbox:
        """Before the sequencer steps: place the goal while it is pending."""
        return self._prepare(t_s, autopilot) if self.pending else []

    def after_sequence(self, t_s: float) -> Outbox:
        """After the sequencer steps: what a placed goal sends and says this tick."""
        if self._outbound is None or self.pending:
            return []
        sent, said = self._outbound(t_s, self.sequencer.state.engaged, self.sequencer.phase is Phase.HELD)
        return [*sent, *(self.supervisor.say(t_s, severity, text) for severity, text in said)]

    def _prepare(self, t_s: float, autopilot) -> Outbox:
        prep = self.fence.prepare(t_s, autopilot, getattr(self.sequencer, "kind", None)) if self.fence is not None else None
        if prep is None or prep.ready and not prep.said:     # the fence first, then the goal
            prep = self.goal.prepare(t_s, autopilot) if callable(getattr(self.goal, "prepare", None)) else Preparation(True)
        elif prep.ready:                                       # placed at this tick: said now, the goal next tick
            prep = Preparation(False, prep.said, None, prep.send)
        if prep.ready and self.fence is not None:
            prep = self._inside_fence(prep)
        out: Outbox = list(prep.send)
        out.extend(self.supervisor.say(t_s, severity, text) for severity, text in prep.said)
        if prep.ready:
            self.pending = False
            self._adopt_mission_ends()
            release = getattr(self.sequencer, "release_start", None)
            if release is not None:
                release(t_s)
        elif prep.failed is not None:
            self.pending = False
            self.error = prep.failed
            give_up = getattr(self.sequencer, "give_up", None)
            if give_up is not None:
                give_up(t_s, prep.failed)
        return out

    def _adopt_mission_ends(self) -> None:
        """A placed mission's take-off and end become the offboard sequence's (it has not started):
        its NAV_TAKEOFF the take-off height (with ``arm`` and none asked for); flown in OFFBOARD
        (``takeover = "always"``), its final NAV_LAND or NAV_RETURN_TO_LAUNCH the hand-back
        :data:`FINAL_ITEM_AFTER_S` after the last waypoint (none asked for, ``--exit-after-goal``),
        after which the item is the autopilot's (:meth:`MissionGoal.take_outbound`)."""
        config = getattr(self.sequencer, "config", None)
        if not isinstance(config, OffboardConfig):
            return
        changes: dict = {}
        takeoff = getattr(self.goal, "takeoff_alt_m", None)
        if takeoff is not None and config.arm and config.takeoff_alt_m is None:
            changes["takeoff_alt_m"] = max(1.0, float(takeoff))
        if (getattr(self.goal, "final_command", None) is not None and config.takeover == "always"
                and config.hold_after_goal_s is None):
            changes["hold_after_goal_s"] = FINAL_ITEM_AFTER_S
        if changes:
            self.sequencer.config = dataclasses.replace(config, **changes)

    def _inside_fence(self, prep: Preparation) -> Preparation:
        """The placed goal (every waypoint of a mission) inside the fence, or the run gives up naming it."""
        fence = self.fence.fence
        points = [w.position for w in getattr(self.goal, "waypoints", [])] or [self.goal.goal]
        for k, p in enumerate(q for q in points if q is not None):
            d = fence.clearance(p)
            if d < 0.0:
                what = f"waypoint {k + 1}" if len(points) > 1 else "the goal"
                reason = (f"{what} at N {p[0]:.1f} E {p[1]:.1f} D {p[2]:.1f} is {-d:.1f} m outside the fence "
                          f"({self.fence.source}): not flown")
                return Preparation(False, prep.said + [(mavlink2.MAV_SEVERITY_WARNING, "companion: goal outside the fence")],
                                   failed=reason, send=prep.send)
        return prep
