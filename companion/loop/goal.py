"""Where the drone is going: the goal source the loop asks at every replan.

A :class:`GoalSource` gives the planner its target for one replan (an intermediate
waypoint on the route, so a far goal does not pull the plan across everything in
between), says when the goal is reached, and where the final goal lies (the ``c_max``
upper bound is kept only for an obstacle between the drone and it). All positions are
local NED metres in the autopilot's frame.

:class:`ScenarioGoal` is the scenario file's ``[mission] goal_ned_m``; :class:`PlacedGoal`
is a goal given relative to home or on the earth (``goal_home_m``, ``goal_geo``, or
``companion fly --goal``), placed once through the vehicle's origin and home. A mission
from the vehicle or a ground station is another source with the same answers.

A source that must be placed before it can be flown also has ``prepare(t_s, autopilot)
-> Preparation`` (``autopilot`` the followed (system, component), or None): the loop asks
it at every tick until it is ready and keeps the offboard sequence from starting (no
arming, take-off or streaming) meanwhile; a source that gives up ends the run before
anything was flown. Optional too: ``on_message(t_s, msg) -> [msg]`` (the autopilot's
MISSION_* messages, answered at once) and ``take_outbound(t_s) -> ([msg], [(severity,
text)])`` (what it sends and says at each tick once ready: a mission's progress).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.config import GOAL_BELOW_ORIGIN_MAX_M, MissionConfig
from companion.loop.goal_frames import GoalSpec, place
from companion.loop.vehicle_reference import VehicleReference

logger = logging.getLogger(__name__)


class GoalSource(Protocol):
    """What the loop asks of a goal (NED metres throughout)."""

    @property
    def goal(self) -> np.ndarray | None:
        """The final goal now (3,), or None when there is none yet."""

    def start(self, position: np.ndarray) -> None:
        """The companion took control at ``position``: where the route starts (later calls: no effect)."""

    def target(self, position: np.ndarray) -> np.ndarray:
        """The planner's target for a replan from ``position``: the next point along the route."""

    def reached(self, position: np.ndarray) -> bool:
        """Whether ``position`` counts as having reached the goal."""

    def at_goal(self, position: np.ndarray) -> bool:
        """Whether ``position`` is inside the final goal's acceptance now (no side effects)."""


class ScenarioGoal:
    """The scenario's one goal, approached along the straight route from where the companion took over.

    The target of a replan is ``waypoint_spacing_m`` further along that route than the
    drone's projection on it (the goal itself once that is past it).

    Parameters
    ----------
    mission : MissionConfig
        The scenario's ``[mission]`` table.
    """

    def __init__(self, mission: MissionConfig) -> None:
        self.mission = mission
        self.route_start: np.ndarray | None = None

    @property
    def goal(self) -> np.ndarray | None:
        return self.mission.goal

    def start(self, position: np.ndarray) -> None:
        if self.route_start is None:
            self.route_start = np.asarray(position, dtype=float).copy()

    def target(self, position: np.ndarray) -> np.ndarray:
        goal = self.goal
        if goal is None:
            return np.asarray(position, dtype=float).copy()  # nothing placed: stay
        start = self.route_start if self.route_start is not None else position
        return route_target(start, goal, position, self.mission.waypoint_spacing_m)

    def reached(self, position: np.ndarray) -> bool:
        return self.at_goal(position)

    def at_goal(self, position: np.ndarray) -> bool:
        goal = self.goal
        return goal is not None and bool(np.linalg.norm(position - goal) <= self.mission.goal_tolerance_m)


@dataclass
class Preparation:
    """What a goal source that must be placed says at one tick: ready, what to announce, or why it gave up."""

    ready: bool
    said: list[tuple[int, str]] = field(default_factory=list)   # (MAV_SEVERITY, text) to announce
    failed: str | None = None                                  # set once: the run ends with this error
    send: list = field(default_factory=list)                    # MAVLink messages to send now


class PlacedGoal(ScenarioGoal):
    """One goal in any frame (:class:`~companion.loop.goal_frames.GoalSpec`), placed in the local frame
    once the vehicle's origin and home it needs are known, then flown as :class:`ScenarioGoal`.

    While a reference is missing the goal asks for it (the shared
    :class:`~companion.loop.vehicle_reference.VehicleReference` requests GPS_GLOBAL_ORIGIN or
    HOME_POSITION every 2 s) and says once that it waits; after ``mission.goal_wait_s`` from the
    first tick the autopilot was known it gives up with one error naming what never came. A
    placed goal under the ground at the origin is refused the same way. The goal is placed
    once: a later change of origin or home does not move it.

    Parameters
    ----------
    mission : MissionConfig
        Tolerance, waypoint spacing and the wait; the goal in it unless ``spec`` is given.
    reference : VehicleReference
        The vehicle's origin and home (shared with the obstacle intake).
    spec : GoalSpec, optional
        The goal (default: the mission's, :attr:`MissionConfig.goal_spec`).
    """

    def __init__(self, mission: MissionConfig, reference: VehicleReference, spec: GoalSpec | None = None) -> None:
        super().__init__(mission)
        self.spec = spec if spec is not None else mission.goal_spec
        self.reference = reference
        self.placed: np.ndarray | None = place(self.spec, None, None) if self.spec.frame == "ned" else None
        self.placed_t_s: float | None = None
        self.failed: str | None = None
        self._wait_from: float | None = None

    @property
    def goal(self) -> np.ndarray | None:
        return self.placed

    def _missing(self) -> str:
        names = []
        if self.spec.needs_origin and self.reference.origin is None:
            names.append("GPS_GLOBAL_ORIGIN")
        if self.spec.needs_home and self.reference.home is None:
            names.append("HOME_POSITION")
        return " and ".join(names)

    def prepare(self, t_s: float, autopilot: tuple[int, int] | None) -> Preparation:
        """Place the goal if its references are known (see the class docstring)."""
        if self.placed is not None:
            return Preparation(True)
        if self.failed is not None:
            return Preparation(False)
        ned = place(self.spec, self.reference.origin_point, self.reference.home)
        if ned is not None:
            if ned[2] > GOAL_BELOW_ORIGIN_MAX_M:
                return self._fail(f"goal {self.spec.describe()} is {ned[2]:.1f} m below the local origin (under the "
                                  f"ground at home)", "companion: goal below ground, not flown")
            self.placed, self.placed_t_s = ned, t_s
            text = f"goal {self.spec.describe()} placed at NED {np.round(ned, 2).tolist()} m"
            logger.info("%s", text)
            return Preparation(True, [(mavlink2.MAV_SEVERITY_INFO,
                                       f"companion: goal at N {ned[0]:.1f} E {ned[1]:.1f} D {ned[2]:.1f}")])
        if autopilot is None:
            return Preparation(False)
        self.reference.origin_request.wanted = self.spec.needs_origin and self.reference.origin is None
        self.reference.home_request.wanted = self.spec.needs_home and self.reference.home is None
        said: list[tuple[int, str]] = []
        if self._wait_from is None:
            self._wait_from = t_s
            logger.info("goal %s waits for %s (at most %g s)", self.spec.describe(), self._missing(), self.mission.goal_wait_s)
            said.append((mavlink2.MAV_SEVERITY_NOTICE, f"companion: goal waits for {self._missing()}"[:50]))
        elif t_s - self._wait_from >= self.mission.goal_wait_s - 1e-9:
            missing = self._missing()
            self.reference.origin_request.wanted = self.reference.home_request.wanted = False
            return self._fail(f"goal {self.spec.describe()} not placed: no {missing} from the autopilot after "
                              f"{self.mission.goal_wait_s:g} s (does it have a position fix?)",
                              f"companion: goal not placed, no {missing}"[:50])
        return Preparation(False, said)

    def _fail(self, reason: str, short: str) -> Preparation:
        self.failed = reason
        logger.error("%s", reason)
        return Preparation(False, [(mavlink2.MAV_SEVERITY_WARNING, short)], failed=reason)


def route_target(start: np.ndarray, goal: np.ndarray, position: np.ndarray, spacing_m: float) -> np.ndarray:
    """The intermediate waypoint (NED m): ``spacing_m`` ahead of ``position``'s projection on the
    straight route from ``start`` to ``goal``, held at the goal (and at the start behind it)."""
    route = goal - start
    length = float(np.linalg.norm(route))
    if length < 1e-9:
        return np.array(goal, dtype=float)
    along = float(np.dot(position - start, route) / length)
    s = min(length, max(0.0, along) + spacing_m)
    return start + route * (s / length)


def leads_the_way(goal: np.ndarray | None, position: np.ndarray, obstacle: np.ndarray,
                  block_m: float = math.inf) -> bool:
    """Whether an obstacle at ``obstacle`` leads the way: between the drone at ``position`` and
    ``goal`` along the line to it, and within ``block_m`` (m) of that line (it blocks the way).

    The ``c_max`` upper bound (keep the ``c_max`` contours touching) is meant for following
    an obstacle that leads the way through a tight space; it is released once that
    obstacle is behind the drone, past the goal or off the way, so the drone stops at its
    goal instead of being dragged along. ``block_m`` is how near the line a body must be to
    stand in the way (the loop: both radii and both ``c_min`` reaches); without it an obstacle
    beside the line "led" whenever its projection fell between, e.g. the leader just past the
    goal while the drone's last few centimetres to the goal were vertical (issue 46).
    No goal: no obstacle leads.
    """
    if goal is None:
        return False
    to_goal = goal - position
    length = float(np.linalg.norm(to_goal))
    if length < 1e-9:
        return False
    offset = obstacle - position
    along = float(np.dot(offset, to_goal) / length)
    if not 0.0 < along < length:
        return False
    return float(np.linalg.norm(offset - to_goal * (along / length))) < block_m
