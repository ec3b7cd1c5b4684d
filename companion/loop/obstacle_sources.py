"""Obstacles that are not tracks: sources of per-step means and covariances over the horizon.

The planner takes every obstacle as a Gaussian at each step of its horizon (mean (N, 3)
metres NED, covariance (N, 3, 3) m^2) with a body radius. The tracked obstacles (filters
fed by MAVLink reports, :mod:`companion.loop.request_builder`) are predicted by the
constant-velocity model; anything else that knows where an obstacle will be goes through
an :class:`ObstacleSource`: the scenario's static obstacles today, another drone's
shared plan or a mission's no-fly volume next. A source answers for the horizon's step
times (vehicle time, s); the request builder adds its obstacles after the tracks'.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

from companion.loop.config import StaticObstacle


@dataclass(frozen=True)
class ObstacleHorizon:
    """P obstacles over N horizon steps.

    Attributes
    ----------
    means : (P, N, 3) NED m.
    covs : (P, N, 3, 3) m^2, symmetric positive definite.
    radii : (P,) body radius, m.
    may_lead : (P,) bool: whether the ``c_max`` upper bound may apply to the obstacle when it
        lies between the drone and its goal (a moving leader may; a fixed volume never).
    """

    means: np.ndarray
    covs: np.ndarray
    radii: np.ndarray
    may_lead: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "ObstacleHorizon":
        return cls(np.zeros((0, n, 3)), np.zeros((0, n, 3, 3)), np.zeros(0), np.zeros(0, dtype=bool))


class ObstacleSource(Protocol):
    """Anything that knows where obstacles will be over the planner's horizon."""

    def horizon(self, times_s: np.ndarray) -> ObstacleHorizon:
        """The obstacles at vehicle times ``times_s`` (N,), s: one row per obstacle."""


class StaticObstacles:
    """The scenario's ``[[map.static_obstacles]]``: the same Gaussian at every step, never a leader.

    Parameters
    ----------
    obstacles : the scenario's static obstacles (centre NED m, covariance m^2, radius m).
    """

    def __init__(self, obstacles: Sequence[StaticObstacle]) -> None:
        self.obstacles = tuple(obstacles)

    def horizon(self, times_s: np.ndarray) -> ObstacleHorizon:
        n = len(times_s)
        if not self.obstacles:
            return ObstacleHorizon.empty(n)
        return ObstacleHorizon(
            means=np.array([np.broadcast_to(s.center, (n, 3)) for s in self.obstacles]),
            covs=np.array([np.broadcast_to(s.covariance, (n, 3, 3)) for s in self.obstacles]),
            radii=np.array([s.radius for s in self.obstacles], dtype=float),
            may_lead=np.zeros(len(self.obstacles), dtype=bool),
        )
