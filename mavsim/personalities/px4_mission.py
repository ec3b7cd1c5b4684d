"""PX4's AUTO.MISSION as mavsim's PX4 personality flies it: the stored mission's items in turn.

Measured on PX4 SITL (SIH, docs/PX4_FACTS.md, "Missions"): a mission of a takeoff, waypoints,
a DO_CHANGE_SPEED and a landing, started with MAV_CMD_MISSION_START, flew to the end in
AUTO.MISSION and disarmed on the ground. What mavsim does with each item:

- NAV_TAKEOFF (22): climb where the vehicle is to the item's altitude at MPC_TKO_SPEED, then
  a leg to the item's horizontal position; reached within NAV_ACC_RAD of it and NAV_MC_ALT_RAD
  of the altitude. Positions are taken as they are: a takeoff item at latitude and longitude 0
  climbed and then flew off towards (0, 0) on PX4 (measured), and does here too.
- NAV_WAYPOINT (16): a straight leg to the item at the cruise speed (MPC_XY_CRUISE, or the
  last DO_CHANGE_SPEED), slowing with the position gain near the end; reached within the
  item's acceptance radius (param2; 0: NAV_ACC_RAD) horizontally and NAV_MC_ALT_RAD vertically
  (PX4: reached 1.9 m from a waypoint with the default 2 m, 2.9 m with param2 3 m).
- DO_CHANGE_SPEED (178): param2 > 0 m/s becomes the cruise speed, at once.
- NAV_LAND (21): a leg to the item's horizontal position, reached within NAV_ACC_RAD, then a
  descent at MPC_LAND_SPEED; the commander's landing detection disarms it, still in
  AUTO.MISSION (as PX4 did), the mission complete once on the ground.
- NAV_RETURN_TO_LAUNCH (20): the mission hands the vehicle to AUTO.RTL (not measured).
- NAV_LOITER_TIME (19): a hold of param1 seconds where it is; NAV_LOITER_UNLIM (17): a hold.
- Any other item: passed over at once.

MISSION_ITEM_REACHED names the last item done in one step: when a waypoint is followed by
DO_ items, they are done with it and the DO_ item is named (PX4 named item 2, the
DO_CHANGE_SPEED after waypoint 1, and never item 1, in both runs measured). After the last
item (not a landing) the vehicle holds where it is, the mission complete (not measured).

Positions are local NED metres about mavsim's home (its local origin); item altitudes are
relative to home in the ``*_RELATIVE_ALT`` frames and AMSL in the global ones. Pure: no
clock, the simulated time and the true vehicle state in, a velocity command out.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from mavsim.missions import MissionItem

logger = logging.getLogger(__name__)

__all__ = ["MissionFlight", "NO_MISSION", "ACTIVE", "COMPLETE"]

NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LOITER_TIME, NAV_RETURN_TO_LAUNCH, NAV_LAND, NAV_TAKEOFF = 16, 17, 19, 20, 21, 22
#: MAV_CMDs from here on are DO_ (and CONDITION_) items, not places to fly (NAV_ items are below 100)
DO_COMMANDS_FROM = 100
DO_CHANGE_SPEED = 178
#: MISSION_CURRENT ``mission_state``: no mission, not started, active, paused, complete.
NO_MISSION, NOT_STARTED, ACTIVE, COMPLETE = 1, 2, 3, 5


class MissionFlight:
    """The mission in flight: the current item, the cruise speed, the command each step.

    Parameters
    ----------
    items : the mission (:func:`mavsim.missions.local_items`), in order.
    params : the autopilot's parameter store (MPC_XY_CRUISE, MPC_TKO_SPEED, MPC_LAND_SPEED,
        NAV_ACC_RAD, NAV_MC_ALT_RAD are read as the flight goes).
    pos_gain_per_s : the position gain that slows a leg's end (m/s per m).
    first : the item to start at.
    """

    def __init__(self, items: list[MissionItem], params, pos_gain_per_s: float, first: int = 0) -> None:
        self.items = items
        self.params = params
        self.gain = float(pos_gain_per_s)
        self.current = int(first) if 0 <= first < len(items) else 0
        self.cruise_mps = float(params["MPC_XY_CRUISE"])
        self.state = ACTIVE if items else NO_MISSION
        self.reached: list[int] = []         # items done, in order, to be announced (MISSION_ITEM_REACHED)
        self.hand_over: str | None = None    # a mode the mission hands the vehicle to (AUTO.RTL)
        self.landing = False                 # NAV_LAND's descent has begun
        self._hold: np.ndarray | None = None  # where a loiter or the complete mission holds
        self._hold_until_s: float | None = None
        self._started_here: np.ndarray | None = None
        self._climbed = False

    @property
    def total(self) -> int:
        return len(self.items)

    def jump(self, seq: int) -> None:
        """Go on from item ``seq`` (MISSION_SET_CURRENT, or back in AUTO.MISSION), the item begun afresh."""
        if 0 <= seq < self.total:
            self.current = int(seq)
            self.state = ACTIVE
            self.landing = False
            self._hold, self._hold_until_s, self._started_here, self._climbed = None, None, None, False

    def command(self, now_s: float, p: np.ndarray) -> np.ndarray:
        """The velocity command (NED m/s) at ``now_s`` for the true position ``p``; advances items."""
        done = None
        for _ in range(self.total + 1):     # DO_ items and a finished item pass in the same step
            if self.state != ACTIVE:
                break
            item = self.items[self.current]
            if done is not None and item.command < DO_COMMANDS_FROM:
                self.reached.append(done)   # a NAV item next: the item before is named first, in order
                done = None
            v, finished = self._fly(item, now_s, p)
            if not finished:
                if done is not None:
                    self.reached.append(done)
                return v
            done = item.seq
            self._next()
        if done is not None:
            self.reached.append(done)
        return self._hold_command(p)

    # ------------------------------------------------------------------ items
    def _fly(self, item: MissionItem, now_s: float, p: np.ndarray) -> tuple[np.ndarray, bool]:
        cmd, prm = item.command, self.params
        alt_rad = float(prm["NAV_MC_ALT_RAD"])
        if cmd == NAV_TAKEOFF:
            if self._started_here is None:
                self._started_here = p.copy()
            target = item.position_ned_m
            if not self._climbed:
                v = self.gain * (self._started_here - p)
                climb = float(prm["MPC_TKO_SPEED"])
                v[2] = max(-climb, min(climb, self.gain * (target[2] - p[2])))
                self._climbed = abs(target[2] - p[2]) < alt_rad
                return v, False
            d = target - p
            horizontal = math.hypot(d[0], d[1])
            if horizontal < float(prm["NAV_ACC_RAD"]) and abs(d[2]) < alt_rad:
                return np.zeros(3), True
            return self._leg(d, horizontal), False
        if cmd in (NAV_WAYPOINT, NAV_LAND):
            target = self._target(item, p)
            if self.landing:
                v = self.gain * (target - p)
                v[2] = float(prm["MPC_LAND_SPEED"])
                return v, False                    # landed: the commander's landing detection ends it
            d = target - p
            horizontal = math.hypot(d[0], d[1])
            radius = item.params[1] if cmd == NAV_WAYPOINT and item.params[1] > 0 else float(prm["NAV_ACC_RAD"])
            # a landing's altitude is the ground: only its horizontal position is reached
            if horizontal < radius and (cmd == NAV_LAND or abs(d[2]) < alt_rad):
                if cmd == NAV_LAND:
                    self.landing = True
                    self.reached.append(item.seq)  # PX4 named the land item when its descent began
                    return self._fly(item, now_s, p)
                return np.zeros(3), True
            return self._leg(d, horizontal), False
        if cmd == DO_CHANGE_SPEED:
            if item.params[1] > 0:
                self.cruise_mps = float(item.params[1])
            return np.zeros(3), True
        if cmd == NAV_RETURN_TO_LAUNCH:
            self.hand_over = "AUTO.RTL"
            self.state = COMPLETE
            return np.zeros(3), False
        if cmd in (NAV_LOITER_TIME, NAV_LOITER_UNLIM):
            if self._hold is None:
                self._hold = p.copy()
                self._hold_until_s = now_s + item.params[0] if cmd == NAV_LOITER_TIME else math.inf
            if now_s >= self._hold_until_s:
                self._hold = None
                return np.zeros(3), True
            return self.gain * (self._hold - p), False
        return np.zeros(3), True                    # not flown: passed over

    def _target(self, item: MissionItem, p: np.ndarray) -> np.ndarray:
        t = item.position_ned_m.copy()
        if item.command == NAV_LAND and not self.landing:
            t[2] = p[2]                 # to the landing point at the altitude it is at
        return t

    def _leg(self, d: np.ndarray, horizontal: float) -> np.ndarray:
        speed = min(self.cruise_mps, self.gain * horizontal)
        v = np.zeros(3)
        if horizontal > 1e-9:
            v[:2] = d[:2] / horizontal * speed
        v[2] = self.gain * d[2]
        return v

    def _next(self) -> None:
        self._hold, self._hold_until_s, self._started_here, self._climbed = None, None, None, False
        if self.current + 1 < self.total:
            self.current += 1
        else:
            self.state = COMPLETE

    def _hold_command(self, p: np.ndarray) -> np.ndarray:
        if self._hold is None:
            self._hold = p.copy()
        return self.gain * (self._hold - p)
