"""The traffic player's referee: how close the vehicle came to each played obstacle and to the goal.

Pure and clock-free: the player hands it vehicle positions (local NED metres, the
autopilot's local frame) with the time on the obstacles' scripted tracks (``motion_s``,
seconds since engagement), and it evaluates each obstacle's true position on its track at
that instant (closed form, :class:`mavsim.obstacles.ObstacleTrack`). Only samples after
engagement count: before it the obstacles wait at their start points. One referee per
source of vehicle positions (SIH's ground truth, the autopilot's own estimate).
"""

from __future__ import annotations

import math

import numpy as np

from mavsim.obstacles import ObstacleTrack
from mavsim.scenario import Scenario

__all__ = ["Referee"]


class Referee:
    """Smallest vehicle-obstacle distances and the goal, from one source of vehicle positions.

    Parameters
    ----------
    scenario : Scenario
        Its obstacles (tracks and radii), the vehicle's radius, the goal and its tolerance.
    source : str
        Where the positions come from (``"truth"``, ``"estimate"``), for the summary.
    """

    def __init__(self, scenario: Scenario, source: str) -> None:
        self.source = source
        self.names = [ob.name for ob in scenario.obstacles]
        self.tracks = [ObstacleTrack(ob) for ob in scenario.obstacles]
        self.radius_sum = [scenario.vehicle_radius_m + ob.radius_m for ob in scenario.obstacles]
        self.goal = scenario.goal_ned_m
        self.goal_tolerance_m = scenario.goal_tolerance_m
        self.samples = 0
        self.min_distance = [math.inf] * len(self.tracks)
        self.min_at_s: list[float | None] = [None] * len(self.tracks)
        self.min_goal_distance = math.inf
        self.goal_reached_s: float | None = None

    def obstacle_positions(self, motion_s: float) -> np.ndarray:
        """True obstacle positions (NED m, shape (P, 3)) at ``motion_s`` on their tracks."""
        return np.array([tr.position(motion_s) for tr in self.tracks]).reshape(-1, 3)

    def update(self, motion_s: float, position_ned_m: np.ndarray) -> None:
        """A vehicle position (NED m) at ``motion_s`` seconds after engagement (>= 0)."""
        p = np.asarray(position_ned_m, float)
        if motion_s < 0.0 or not np.all(np.isfinite(p)):
            return
        self.samples += 1
        for i, q in enumerate(self.obstacle_positions(motion_s)):
            d = float(np.linalg.norm(p - q))
            if d < self.min_distance[i]:
                self.min_distance[i], self.min_at_s[i] = d, motion_s
        if self.goal is not None:
            g = float(np.linalg.norm(p - self.goal))
            self.min_goal_distance = min(self.min_goal_distance, g)
            if self.goal_reached_s is None and g <= self.goal_tolerance_m:
                self.goal_reached_s = motion_s

    def summary(self) -> dict:
        """JSON-serialisable: per obstacle the smallest distance (m, centre to centre), the
        clearance (distance less both radii, m) and when (s after engagement); the goal."""
        def r(x: float | None, n: int = 3) -> float | None:
            return None if x is None or not math.isfinite(x) else round(float(x), n)

        obstacles = [{"name": name, "min_distance_m": r(d), "min_clearance_m": r(d - rs), "at_s": r(t, 2)}
                     for name, d, rs, t in zip(self.names, self.min_distance, self.radius_sum, self.min_at_s)]
        finite = [d for d in self.min_distance if math.isfinite(d)]
        clear = [d - rs for d, rs in zip(self.min_distance, self.radius_sum) if math.isfinite(d)]
        return {
            "source": self.source,
            "samples": self.samples,
            "min_distance_m": r(min(finite)) if finite else None,
            "min_clearance_m": r(min(clear)) if clear else None,
            "collision": bool(clear and min(clear) <= 0.0),
            "obstacles": obstacles,
            "min_goal_distance_m": r(self.min_goal_distance),
            "goal_reached": self.goal_reached_s is not None,
            "goal_reached_s": r(self.goal_reached_s, 2),
        }
