"""A mission as a goal source: its NAV_WAYPOINT items flown in order, progress kept on the autopilot.

:class:`MissionGoal` gets its items from a file (:mod:`companion.loop.mission_file`; uploaded
to the vehicle first, so the autopilot's mission is the one flown) or from the vehicle
(downloaded), with the mission protocol's state machines
(:mod:`companion.mavlink.mission_protocol`). Before it is ready the offboard sequence does not
start (``prepare``, :mod:`companion.loop.goal`): the transfer runs, then the items are placed
in the local frame through the vehicle's GPS_GLOBAL_ORIGIN (and HOME_POSITION for
altitudes relative to home), as :class:`~companion.loop.goal.PlacedGoal` places one goal.

In flight, the planner's target runs along the current leg (from where the previous
waypoint was reached, or where the companion took over) ``waypoint_spacing_m`` ahead of
the drone; a waypoint counts as reached within its acceptance radius (the item's param2;
``goal_tolerance_m`` when 0), and is then announced (STATUSTEXT) and the autopilot's
current item set to the next one (MISSION_SET_CURRENT); the last waypoint ends the
mission (the loop's "goal reached"). What it does not fly itself:

- NAV_TAKEOFF: its altitude (above home) becomes the engage sequence's take-off when the
  companion arms and no take-off altitude was given; placed (:attr:`takeoff`), it is where a
  watching or guarding companion predicts the autopilot's climb to (:meth:`climb_route`);
- a final NAV_LAND or NAV_RETURN_TO_LAUNCH: the command sent to the autopilot once the
  vehicle has been handed back (Hold) after the last waypoint (:attr:`final_command`; flown in
  OFFBOARD, the hand-back comes a second after the last waypoint unless ``--exit-after-goal``
  says when: :meth:`companion.loop.goal_stage.GoalStage._adopt_mission_ends`);
- DO_JUMP (param1: the item seq jumped to, param2: how many times; -1: for ever, as
  ArduPilot's; 0: never): followed when the waypoint before it is reached, so a mission that
  jumps back to its first waypoint is a patrol flown until the run ends (``--duration``, a
  signal). The leg after a jump starts at the waypoint reached, as any leg;
- DO_CHANGE_SPEED (param1 0 or 1: air or ground speed; param2 m/s, -1 no change, -2 back to
  the default): the speed of the autopilot's own legs after it, as a watching or guarding
  companion predicts them (:meth:`route_speeds`; the default is ``[mission]
  autopilot_speed_mps``). The companion's own legs keep its planner's speed: for its flight
  the item is skipped (below);
- anything else (loiters, other DO_ items, a LAND or RTL that is not last): skipped, listed in
  :attr:`skipped` and said once (not yet supported).

Memory does not grow with the flight: the report keeps the latest :data:`REACHED_KEPT`
waypoints reached and counts them all (a patrol reaches one every few seconds for hours).

Pure: link time (s) comes in as an argument.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.config import GOAL_BELOW_ORIGIN_MAX_M, MissionConfig
from companion.loop.goal import Preparation, route_target
from companion.loop.goal_frames import GoalSpec, place
from companion.loop.mission_file import MissionPlan, check_items
from companion.loop.vehicle_reference import VehicleReference
from companion.errors import ConfigError
from companion.mavlink import messages
from companion.mavlink.mission_protocol import (
    RELATIVE_FRAMES, VEHICLE_MESSAGES, MissionDownload, MissionItem, MissionUpload, set_current)

logger = logging.getLogger(__name__)

#: The autopilot's messages of the mission protocol (routed to the mission while it runs).
MISSION_MESSAGES = VEHICLE_MESSAGES
_FINAL = {mavlink2.MAV_CMD_NAV_LAND: "land", mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH: "return"}
#: Waypoints reached kept for the run report (the latest; all are counted).
REACHED_KEPT = 1000
#: DO_JUMP's repeat count that never runs out (ArduPilot's convention).
JUMP_FOREVER = -1
#: DO_CHANGE_SPEED's speed types that set the horizontal speed of a multicopter (air, ground speed),
#: and its speed that returns to the default (-1, or any other value not positive, changes nothing)
_HORIZONTAL_SPEED_TYPES = (0.0, 1.0)
_SPEED_DEFAULT = -2.0


@dataclass(frozen=True)
class Waypoint:
    """A NAV_WAYPOINT placed in the local frame: its item's seq, position (NED, m), acceptance radius (m),
    and the autopilot's speed on the leg to it set by the mission's DO_CHANGE_SPEED items before it
    (m/s; None: the autopilot's default)."""

    seq: int
    position: np.ndarray
    acceptance_m: float
    speed_mps: float | None = None


@dataclass
class Jump:
    """A DO_JUMP placed after waypoint ``after`` (index into the waypoints; -1: before the first):
    to waypoint index ``to`` (the first at or after the item jumped to), ``repeat`` times
    (:data:`JUMP_FOREVER`: for ever); ``taken`` counts the jumps made."""

    seq: int
    after: int
    to: int
    repeat: int
    taken: int = 0


class MissionGoal:
    """The waypoints of a mission, flown in order (see the module docstring).

    Parameters
    ----------
    mission : MissionConfig
        ``goal_tolerance_m`` (acceptance where an item sets none), ``waypoint_spacing_m``,
        ``goal_wait_s`` (how long the origin and home are waited for).
    reference : VehicleReference
        The vehicle's origin and home (shared with the obstacle intake).
    plan : MissionPlan, optional
        The mission from a file; None downloads the vehicle's.
    upload : bool
        Upload ``plan`` to the vehicle before flying it (default); False flies it as read.
    """

    MISSION_MESSAGES = MISSION_MESSAGES

    def __init__(self, mission: MissionConfig, reference: VehicleReference, plan: MissionPlan | None = None, *,
                 upload: bool = True) -> None:
        self.mission, self.reference, self.plan = mission, reference, plan
        self.upload = upload and plan is not None
        self.items: list[MissionItem] | None = list(plan.items) if plan is not None and not self.upload else None
        self.transfer: MissionDownload | MissionUpload | None = None
        self.waypoints: list[Waypoint] = []
        self.jumps: list[Jump] = []                     #: the mission's DO_JUMPs, in item order
        self.index = 0                                  #: the waypoint flown to now
        self.next_index: int | None = None              #: the waypoint after it (None: it is the last)
        self.takeoff_alt_m: float | None = None         #: a NAV_TAKEOFF item's altitude above home
        #: a NAV_TAKEOFF before the first waypoint, placed: (its seq, its position NED m)
        self.takeoff: tuple[int, np.ndarray] | None = None
        self.final_command: int | None = None           #: a last NAV_LAND / NAV_RETURN_TO_LAUNCH
        self.skipped: list[tuple[int, int]] = []        #: (seq, command) of items not flown
        #: waypoints reached, as (link time s, item seq), in order: the latest REACHED_KEPT
        self.reached_items: deque[tuple[float, int]] = deque(maxlen=REACHED_KEPT)
        self.reached_count = 0                          #: every waypoint reached
        self.finished = False                           #: the last waypoint reached
        self.failed: str | None = None
        self.route_start: np.ndarray | None = None
        self._target: tuple[int, int] | None = None
        self._wait_from: float | None = None
        self._newly_reached: list[tuple[int, int | None]] = []   # (seq reached, seq flown to next)
        self._current_sent = False
        self._first_index = 0                           # the first waypoint flown (a DO_JUMP may skip some)
        self._final_sent = False

    # ------------------------------------------------------------------ GoalSource

    @property
    def goal(self) -> np.ndarray | None:
        return self.waypoints[self.index].position if self.waypoints else None

    def start(self, position: np.ndarray) -> None:
        if self.route_start is None:
            self.route_start = np.asarray(position, dtype=float).copy()

    def target(self, position: np.ndarray) -> np.ndarray:
        if not self.waypoints:
            return np.asarray(position, dtype=float).copy()
        for _ in range(len(self.waypoints)):   # bounded: waypoints within each other's acceptance
            if self.next_index is None or not self._within(position, self.waypoints[self.index]):
                break
            self._reach()
        goal = self.waypoints[self.index].position
        start = self.route_start if self.route_start is not None else position
        return route_target(start, goal, position, self.mission.waypoint_spacing_m)

    def reached(self, position: np.ndarray) -> bool:
        if not self.waypoints or self.next_index is not None:
            return False
        if self.finished:
            return True
        if self._within(position, self.waypoints[self.index]):
            self._newly_reached.append((self.waypoints[self.index].seq, None))
            self.finished = True
            return True
        return False

    def at_goal(self, position: np.ndarray) -> bool:
        return bool(self.waypoints) and self.next_index is None and self._within(position, self.waypoints[self.index])

    def _within(self, position: np.ndarray, wp: Waypoint) -> bool:
        return bool(np.linalg.norm(np.asarray(position) - wp.position) <= wp.acceptance_m)

    def _reach(self) -> None:
        wp = self.waypoints[self.index]
        assert self.next_index is not None
        self._newly_reached.append((wp.seq, self.waypoints[self.next_index].seq))
        self.route_start = wp.position.copy()   # the next leg starts at the waypoint, as the autopilot flies it
        self._go_to(self.next_index)

    def _go_to(self, index: int) -> None:
        """Fly to waypoint ``index`` next, and settle now which comes after it (taking a jump counts it)."""
        self.index = index
        self.next_index = self._after(index)

    def _after(self, index: int) -> int | None:
        """The waypoint flown after waypoint ``index`` (-1: the first one): the first of the
        DO_JUMPs after it that has jumps left (counted here), else the next waypoint."""
        for jump in self.jumps:
            if jump.after == index and (jump.repeat == JUMP_FOREVER or jump.taken < jump.repeat):
                jump.taken += 1
                return jump.to
        return index + 1 if index + 1 < len(self.waypoints) else None

    @property
    def current_seq(self) -> int | None:
        """The item the companion flies to (a waypoint's seq), or, once the last waypoint is reached,
        the item after it (a landing, a return; None when there is none)."""
        if not self.waypoints:
            return None
        seq = self.waypoints[self.index].seq
        if not self.finished:
            return seq
        return self._item_after(seq)

    def _item_after(self, seq: int) -> int | None:
        """The first mission item after item ``seq`` that is not a DO_JUMP (after the last waypoint:
        a LAND, an RTL), or None."""
        return next((it.seq for it in (self.items or ())[seq + 1:] if it.command != mavlink2.MAV_CMD_DO_JUMP), None)

    def resume_at(self, seq: int) -> bool:
        """Fly on from the autopilot's item ``seq`` (a guard's takeover: the autopilot flew the mission
        so far): the first waypoint at or after it becomes the one flown to, its leg starting where
        the vehicle is; the autopilot is not told (it is at that item). False when no waypoint is left."""
        index = next((k for k, w in enumerate(self.waypoints) if w.seq >= seq), None)
        if index is None:
            return False
        self._go_to(index)
        self.finished = False
        self.route_start = None       # the leg starts where the takeover finds the vehicle
        self._current_sent = True     # the autopilot's current item is already this one
        return True

    def route_from(self, current_seq: int) -> np.ndarray:
        """The waypoints the autopilot flies from its current item ``current_seq`` on (NED m, (K, 3)), as
        it flies them: the first waypoint at or after that item, then the next ones, a DO_JUMP with
        jumps left followed once (a patrol's next lap; each waypoint at most twice). Empty once the
        current item is past the last waypoint (a landing, a return: the path holds where it is)."""
        return self._route_and_speeds(current_seq, 1.0)[0]

    def autopilot_path(self, current_seq: int, position: np.ndarray, default_mps: float,
                       climb_mps: float) -> tuple[np.ndarray, np.ndarray]:
        """What the autopilot flies from its current item ``current_seq`` for a vehicle at ``position``
        (NED m): the points (K, 3) and its speed on the leg to each (m/s, (K,)). On the mission's
        NAV_TAKEOFF the climb first (:meth:`climb_route`), else the waypoints (:meth:`route_from` at
        :meth:`route_speeds`); empty past the last waypoint."""
        route, speeds = self.climb_route(current_seq, position, climb_mps, default_mps)
        if len(route):
            return route, speeds
        return self._route_and_speeds(current_seq, default_mps)

    def _route_and_speeds(self, current_seq: int, default_mps: float) -> tuple[np.ndarray, np.ndarray]:
        order = self._route_order(current_seq)
        route = np.array([self.waypoints[k].position for k in order], dtype=float).reshape(-1, 3)
        speeds = [self.waypoints[k].speed_mps for k in order]
        return route, np.array([default_mps if v is None else v for v in speeds], dtype=float)

    def route_speeds(self, current_seq: int, default_mps: float) -> np.ndarray:
        """The autopilot's speed on each leg of :meth:`route_from` (m/s, (K,)): the one its mission's
        DO_CHANGE_SPEED items set before the leg's waypoint, else ``default_mps``. (After a DO_JUMP
        the speed is that of the waypoint's first pass.)"""
        return self._route_and_speeds(current_seq, default_mps)[1]

    def climb_route(self, current_seq: int, position: np.ndarray, climb_mps: float,
                    default_mps: float) -> tuple[np.ndarray, np.ndarray]:
        """The autopilot's path ahead while it is on its NAV_TAKEOFF (item ``current_seq``), with the
        speed of each leg: up where the vehicle is (``position``, NED m) to the item's altitude at
        ``climb_mps``, then to the item's position (PX4 flies there, measured on SITL), then the
        waypoints (:meth:`route_from`, :meth:`route_speeds`). Empty (0, 3) when the current item is
        not the take-off (the caller predicts from the waypoints alone)."""
        if self.takeoff is None or current_seq != self.takeoff[0]:
            return np.empty((0, 3)), np.empty(0)
        top = self.takeoff[1]
        route, speeds = self._route_and_speeds(current_seq + 1, default_mps)
        first = float(speeds[0]) if len(speeds) else default_mps
        above = np.array([position[0], position[1], top[2]], dtype=float)
        return (np.vstack([above, top, route]).reshape(-1, 3),
                np.concatenate([[climb_mps, first], speeds]))

    def _route_order(self, current_seq: int) -> list[int]:
        start = next((k for k, w in enumerate(self.waypoints) if w.seq >= current_seq), None)
        if start is None:
            return []
        order: list[int] = []
        followed: set[int] = set()
        index: int | None = start
        while index is not None and len(order) < 2 * len(self.waypoints):
            order.append(index)
            jump = next((j for j in self.jumps if j.after == index and j.seq not in followed
                         and (j.repeat == JUMP_FOREVER or j.taken < j.repeat)), None)
            if jump is not None:
                followed.add(jump.seq)
                index = jump.to
            else:
                index = index + 1 if index + 1 < len(self.waypoints) else None
        return order

    # ------------------------------------------------------------------ preparation

    def on_message(self, t_s: float, msg) -> list:
        """The autopilot's MISSION_* messages while a transfer runs; the answers to send at once."""
        if self.transfer is None or self.transfer.over:
            return []
        out = self.transfer.on_message(t_s, msg)
        return out

    def prepare(self, t_s: float, autopilot: tuple[int, int] | None) -> Preparation:
        """Transfer, then place the mission (see the module docstring)."""
        if self.waypoints:
            return Preparation(True)
        if self.failed is not None or autopilot is None:
            return Preparation(False)
        self._target = autopilot
        if self.items is None:
            return self._transfer(t_s, autopilot)
        return self._place(t_s)

    def _transfer(self, t_s: float, autopilot: tuple[int, int]) -> Preparation:
        if self.transfer is None:
            if self.upload:
                assert self.plan is not None
                self.transfer = MissionUpload(autopilot, list(self.plan.items))
                text = f"companion: uploading mission, {len(self.plan.items)} items"
            else:
                self.transfer = MissionDownload(autopilot)
                text = "companion: downloading the vehicle's mission"
            logger.info("%s", text)
            return Preparation(False, [(mavlink2.MAV_SEVERITY_INFO, text)], send=self.transfer.start(t_s))
        send = self.transfer.step(t_s)
        if self.transfer.failed is not None:
            return self._fail(self.transfer.failed, "companion: mission transfer failed")
        if not self.transfer.done:
            return Preparation(False, send=send)
        if isinstance(self.transfer, MissionDownload):
            self.items = list(self.transfer.items)
            try:
                check_items("the vehicle's mission", self.items)
            except ConfigError as exc:
                return self._fail(str(exc), "companion: vehicle mission not flyable")
        else:
            self.items = list(self.transfer.items)
        return self._place(t_s)

    def _place(self, t_s: float) -> Preparation:
        assert self.items is not None
        needs_home = any(item.frame in RELATIVE_FRAMES for item in self.items)
        origin, home = self.reference.origin_point, self.reference.home
        if origin is None or (needs_home and home is None):
            self.reference.origin_request.wanted = origin is None
            self.reference.home_request.wanted = needs_home and home is None
            missing = " and ".join(n for n, gone in (("GPS_GLOBAL_ORIGIN", origin is None),
                                                     ("HOME_POSITION", needs_home and home is None)) if gone)
            if self._wait_from is None:
                self._wait_from = t_s
                return Preparation(False, [(mavlink2.MAV_SEVERITY_NOTICE, f"companion: mission waits for {missing}"[:50])])
            if t_s - self._wait_from >= self.mission.goal_wait_s - 1e-9:
                self.reference.origin_request.wanted = self.reference.home_request.wanted = False
                return self._fail(f"mission not placed: no {missing} from the autopilot after {self.mission.goal_wait_s:g} s",
                                  f"companion: mission not placed, no {missing}"[:50])
            return Preparation(False)
        waypoints: list[Waypoint] = []
        jumps: list[tuple[int, int, int, int]] = []   # (seq, after waypoint index, target seq, repeat)
        speed: float | None = None                      # the autopilot's leg speed set so far (None: its default)
        last = len(self.items) - 1
        for item in self.items:
            if item.command == mavlink2.MAV_CMD_NAV_WAYPOINT:
                spec = GoalSpec("geo", (item.x, item.y, item.z), "rel" if item.frame in RELATIVE_FRAMES else "amsl")
                ned = place(spec, origin, home)
                assert ned is not None
                if ned[2] > GOAL_BELOW_ORIGIN_MAX_M:
                    return self._fail(f"mission item {item.seq}: {ned[2]:.1f} m below the local origin (under the ground "
                                      f"at home)", "companion: mission item below ground")
                acceptance = item.params[1] if item.params[1] > 0.0 else self.mission.goal_tolerance_m
                waypoints.append(Waypoint(item.seq, ned, float(acceptance), speed))
            elif item.command == mavlink2.MAV_CMD_NAV_TAKEOFF and not waypoints:
                self.takeoff_alt_m = item.z if item.frame in RELATIVE_FRAMES else item.z - (home.point.alt_m if home else origin.alt_m)
                spec = GoalSpec("geo", (item.x, item.y, item.z), "rel" if item.frame in RELATIVE_FRAMES else "amsl")
                self.takeoff = (item.seq, place(spec, origin, home))
            elif item.command in _FINAL and item.seq == last:
                self.final_command = item.command
            elif item.command == mavlink2.MAV_CMD_DO_JUMP:
                jumps.append((item.seq, len(waypoints) - 1, int(item.params[0]), int(item.params[1])))
            else:
                if item.command == mavlink2.MAV_CMD_DO_CHANGE_SPEED and item.params[0] in _HORIZONTAL_SPEED_TYPES:
                    speed = (item.params[1] if item.params[1] > 0.0 else
                             None if item.params[1] == _SPEED_DEFAULT else speed)
                self.skipped.append((item.seq, item.command))
        if not waypoints:
            return self._fail("the mission has no NAV_WAYPOINT item to fly", "companion: mission has no waypoint")
        for seq, after, target, repeat in jumps:
            to = next((k for k, w in enumerate(waypoints) if w.seq >= target), None)
            if to is None:
                return self._fail(f"mission item {seq}: DO_JUMP to item {target}, after which there is no waypoint",
                                  "companion: mission DO_JUMP goes nowhere")
            self.jumps.append(Jump(seq, after, to, repeat))
        self.waypoints = waypoints
        first = self._after(-1)   # the first waypoint (or where a DO_JUMP before it goes)
        assert first is not None
        self._go_to(first)
        self._first_index = first
        said = [(mavlink2.MAV_SEVERITY_INFO, f"companion: mission of {len(waypoints)} waypoints placed")]
        logger.info("mission placed: %s", [(w.seq, np.round(w.position, 2).tolist(), w.acceptance_m) for w in waypoints])
        if self.skipped:
            logger.warning("mission items not flown (not supported yet): %s", self.skipped)
            said.append((mavlink2.MAV_SEVERITY_NOTICE, f"companion: {len(self.skipped)} mission items skipped"))
        return Preparation(True, said)

    def _fail(self, reason: str, short: str) -> Preparation:
        self.failed = reason
        logger.error("%s", reason)
        return Preparation(False, [(mavlink2.MAV_SEVERITY_WARNING, short[:50])], failed=reason)

    # ------------------------------------------------------------------ progress

    def take_outbound(self, t_s: float, engaged: bool, held: bool) -> tuple[list, list[tuple[int, str]]]:
        """What the mission sends and says at link time ``t_s``: the first waypoint flown made current
        once engaged (or where a DO_JUMP before it goes), each reached waypoint announced
        with the next made current, and the final LAND or RTL once the vehicle is held after the
        last waypoint."""
        out: list = []
        said: list[tuple[int, str]] = []
        if self._target is None or not self.waypoints:
            return out, said
        if engaged and not self._current_sent:
            self._current_sent = True
            out.append(set_current(self.waypoints[self._first_index].seq, self._target))
        for seq, nxt in self._newly_reached:
            self.reached_items.append((t_s, seq))
            self.reached_count += 1
            said.append((mavlink2.MAV_SEVERITY_INFO, f"companion: mission item {seq} reached"))
            if nxt is None:      # the last waypoint: the item after it (a LAND, an RTL)
                nxt = self._item_after(seq)
            if nxt is not None:
                out.append(set_current(nxt, self._target))
        self._newly_reached = []
        if self.finished and held and self.final_command is not None and not self._final_sent:
            self._final_sent = True
            name = _FINAL[self.final_command]
            said.append((mavlink2.MAV_SEVERITY_INFO, f"companion: mission ends, {name} (autopilot)"))
            out.append(messages.command_long(self.final_command, (), target_system=self._target[0],
                                             target_component=self._target[1]))
        return out, said

    def summary(self) -> dict:
        """For the run report: the items reached (seq, link time: the latest :data:`REACHED_KEPT`; and
        how many in all), the DO_JUMPs taken and the items not flown."""
        return {
            "mission_items_reached": [seq for _, seq in self.reached_items],
            "mission_items_reached_t_s": [t for t, _ in self.reached_items],
            "mission_items_reached_count": self.reached_count,
            "mission_jumps_taken": sum(j.taken for j in self.jumps),
            "mission_waypoints": len(self.waypoints),
            "mission_items_skipped": [seq for seq, _ in self.skipped],
            "mission_final": _FINAL.get(self.final_command) if self.final_command else None,
        }
