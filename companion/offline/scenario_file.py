"""A scenario file as both programs read it, and the scripted obstacles' motion from mavsim's model.

Like :mod:`companion.offline.harness`, this module may import ``mavsim`` (the dependency
rule's offline exception). The commands that need the simulator's sections (``demo``,
``plan``, ``fly``) read the file through :func:`load_both`, so the companion accepts a file
only if mavsim accepts it too, and ``companion plan`` predicts scripted obstacles with
mavsim's own motion model (:class:`mavsim.obstacles.ObstacleTrack`: constant velocity or
waypoints, ``start_delay_s`` and ``loop`` included) instead of a copy of it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.errors import ConfigError
from companion.loop.config import CompanionScenario, read_scenario_toml, scenario_from_dict
from mavsim.errors import ScenarioError
from mavsim.obstacles import ObstacleTrack
from mavsim.scenario import Scenario as SimScenario
from mavsim.scenario import scenario_from_dict as sim_scenario_from_dict

logger = logging.getLogger(__name__)


def load_both(path: str | Path, *, goal_elsewhere: bool = False,
              **planner_overrides: Any) -> tuple[CompanionScenario, SimScenario]:
    """The companion's and mavsim's view of one scenario file, each fully validated
    (``goal_elsewhere``: see :func:`~companion.loop.config.scenario_from_dict`).

    Raises
    ------
    ConfigError
        Either program rejects the file (the message names the file, section and key).
    """
    data = read_scenario_toml(path)
    companion = scenario_from_dict(data, path, goal_elsewhere=goal_elsewhere, **planner_overrides)
    try:
        sim = sim_scenario_from_dict(data, str(path))
    except ScenarioError as exc:
        raise ConfigError(str(exc)) from None
    return companion, sim


@dataclass(frozen=True)
class ScriptedObstacle:
    """One ``[[world.obstacles]]`` entry predicted over a horizon (NED metres, seconds)."""

    name: str
    means: np.ndarray          # (N, 3) true positions at the horizon's times
    covariance: np.ndarray     # (3, 3) its measurement covariance, m^2
    radius_m: float


def scripted_obstacles(sim: SimScenario, times_s: np.ndarray) -> list[ScriptedObstacle]:
    """Every scripted obstacle's positions at ``times_s`` (s since the start), by mavsim's motion model."""
    out = []
    for ob in sim.obstacles:
        track = ObstacleTrack(ob)
        means = np.array([track.state(float(t))[0] for t in times_s]).reshape(-1, 3)
        out.append(ScriptedObstacle(ob.name, means, ob.measurement_cov_m2, ob.radius_m))
    return out
