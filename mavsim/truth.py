"""Ground truth: collisions, minimum distances, goal reached, and the run summary.

A collision is a contact interval during which the true centre distance is below the
sum of radii (moving and static obstacles) or the drone sphere crosses a wall
(``normal . p + r > offset``). Checked every physics step.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from mavsim.scenario import Scenario

logger = logging.getLogger(__name__)

__all__ = ["Truth", "TruthRecorder", "TRACE_PERIOD_S", "TRACE_MAX_ROWS"]

#: The truth trace's sample period, s (``mavsim --truth-trace``).
TRACE_PERIOD_S = 0.1
#: The truth trace keeps the last this many samples (an hour at 10 Hz): bounded for ``--forever``.
TRACE_MAX_ROWS = 36_000


@dataclass(frozen=True)
class Truth:
    """True state at one instant (NED metres, m/s, seconds since boot)."""

    t_s: float
    drone_position_ned_m: np.ndarray
    drone_velocity_ned_mps: np.ndarray
    drone_yaw_rad: float
    on_ground: bool
    armed: bool
    mode: str
    obstacle_positions_ned_m: dict[str, np.ndarray] = field(default_factory=dict)
    obstacle_velocities_ned_mps: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class _Contact:
    kind: str
    name: str
    t_start_s: float
    t_end_s: float | None
    min_distance_m: float


class TruthRecorder:
    """Accumulates safety and mission metrics over a run, and a trace of the true positions.

    The trace (:meth:`trace_rows`) samples the drone's and each obstacle's true position every
    :data:`TRACE_PERIOD_S` of simulated time, the last :data:`TRACE_MAX_ROWS` kept.
    """

    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario
        self._trace: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=TRACE_MAX_ROWS)
        self._next_trace_s = 0.0
        r = scenario.vehicle_radius_m
        self.names = [o.name for o in scenario.obstacles]
        self.radius_sum = np.array([r + o.radius_m for o in scenario.obstacles])
        self.min_dist = np.full(len(self.names), math.inf)
        self.min_dist_t = np.zeros(len(self.names))
        self.static_c = np.array([s.center_ned_m for s in scenario.static_obstacles]).reshape(-1, 3)
        self.static_rs = np.array([r + s.radius_m for s in scenario.static_obstacles])
        self.static_min = np.full(len(self.static_rs), math.inf)
        self.wall_n = np.array([w.normal_ned for w in scenario.walls]).reshape(-1, 3)
        self.wall_b = np.array([w.offset_m for w in scenario.walls])
        self.wall_min = np.full(len(self.wall_b), math.inf)  # min clearance (offset - n.p - r)
        self._static_names = [f"static{i}" for i in range(len(self.static_rs))]
        self._wall_names = [f"wall{i}" for i in range(len(self.wall_b))]
        self.contacts: list[_Contact] = []
        self._open: dict[tuple[str, str], _Contact] = {}
        self.goal_reached_t_s: float | None = None
        self.min_goal_dist = math.inf
        self.path_length_m = 0.0
        self._last_p: np.ndarray | None = None
        self.t_s = 0.0

    def update(self, t_s: float, p: np.ndarray, obstacle_pos: np.ndarray) -> None:
        """Record the true drone position ``p`` (3,) and obstacle positions (M, 3) at ``t_s``."""
        self.t_s = t_s
        if t_s >= self._next_trace_s - 1e-9:
            self._next_trace_s = t_s + TRACE_PERIOD_S
            self._trace.append((t_s, np.array(p, dtype=float), np.array(obstacle_pos, dtype=float).reshape(-1, 3)))
        if self._last_p is not None:
            step = p - self._last_p
            self.path_length_m += math.sqrt(float(step @ step))
        self._last_p = p
        if len(self.names):
            diff = obstacle_pos - p
            d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
            closer = d < self.min_dist
            if closer.any():
                self.min_dist = np.where(closer, d, self.min_dist)
                self.min_dist_t = np.where(closer, t_s, self.min_dist_t)
            self._contacts("obstacle", self.names, d, d < self.radius_sum, t_s)
        if len(self.static_rs):
            d = np.linalg.norm(self.static_c - p, axis=1)
            self.static_min = np.minimum(self.static_min, d)
            self._contacts("static", self._static_names, d, d < self.static_rs, t_s)
        if len(self.wall_b):
            clearance = self.wall_b - self.wall_n @ p - self.sc.vehicle_radius_m
            self.wall_min = np.minimum(self.wall_min, clearance)
            self._contacts("wall", self._wall_names, clearance, clearance < 0, t_s)
        if self.sc.goal_ned_m is not None:
            e = p - self.sc.goal_ned_m
            g = math.sqrt(float(e @ e))
            self.min_goal_dist = min(self.min_goal_dist, g)
            if self.goal_reached_t_s is None and g <= self.sc.goal_tolerance_m:
                self.goal_reached_t_s = t_s
                logger.info("t=%.2f goal reached", t_s)

    def _contacts(self, kind: str, names: list[str], dist: np.ndarray, hit: np.ndarray, t_s: float) -> None:
        if not self._open and not hit.any():    # no contact open, none now (nearly every step)
            return
        for i in np.flatnonzero(hit):
            key = (kind, names[i])
            c = self._open.get(key)
            if c is None:
                c = _Contact(kind, names[i], t_s, None, float(dist[i]))
                self._open[key] = c
                self.contacts.append(c)
                logger.warning("t=%.2f collision with %s %s (distance %.3f m)", t_s, kind, names[i], dist[i])
            c.min_distance_m = min(c.min_distance_m, float(dist[i]))
        for key in [k for k in self._open if k[0] == kind and not hit[names.index(k[1])]]:
            self._open.pop(key).t_end_s = t_s

    def trace_rows(self) -> list[dict]:
        """The truth trace, one JSON-serialisable dict a sample: ``t_s`` (s since boot),
        ``drone_ned_m`` and ``obstacles_ned_m`` (name -> NED m), oldest first."""
        return [{"t_s": round(t, 4), "drone_ned_m": [round(float(x), 4) for x in p],
                 "obstacles_ned_m": {n: [round(float(x), 4) for x in q] for n, q in zip(self.names, obs)}}
                for t, p, obs in self._trace]

    def summary(self) -> dict:
        """JSON-serialisable metrics (plain floats, None for 'never')."""
        def f(x: float) -> float | None:
            return None if not math.isfinite(x) else float(x)

        return {
            "collided": bool(self.contacts),
            "collisions": [
                {"kind": c.kind, "with": c.name, "t_start_s": c.t_start_s, "t_end_s": c.t_end_s,
                 "min_distance_m": c.min_distance_m} for c in self.contacts
            ],
            "min_distance_m": {n: f(d) for n, d in zip(self.names, self.min_dist)},
            "min_clearance_m": {n: f(d - rs) for n, d, rs in zip(self.names, self.min_dist, self.radius_sum)},
            "min_distance_time_s": {n: float(t) for n, t in zip(self.names, self.min_dist_t)},
            "min_static_clearance_m": [f(d - rs) for d, rs in zip(self.static_min, self.static_rs)],
            "min_wall_clearance_m": [f(c) for c in self.wall_min],
            "goal_reached": self.goal_reached_t_s is not None,
            "time_to_goal_s": self.goal_reached_t_s,
            "min_goal_distance_m": f(self.min_goal_dist),
            "path_length_m": self.path_length_m,
        }
