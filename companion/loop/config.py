"""The companion's view of a scenario file: mission, planner, estimator, map and loop settings.

The companion reads ``[scenario]``, ``[vehicle]``, ``[mission]``, ``[planner]``,
``[estimator]`` (with ``[estimator.drone]`` and ``[estimator.tracker]``), ``[map]`` and
``[companion]``. It never reads ``[[world.obstacles]]``: moving obstacles are learnt from
MAVLink, as in the field. Unknown keys in the sections it owns are errors that name the
file, the section and the key. Units: NED metres, seconds.
"""

from __future__ import annotations

import logging
import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from companion.errors import ConfigError
from companion.mavlink.offboard import OffboardConfig
from companion.core.planner.config import PlannerConfig
from estimator import DroneFilterConfig, EstimatorConfigError, TrackerConfig

logger = logging.getLogger(__name__)

_TOP_LEVEL = {"scenario", "vehicle", "mission", "planner", "estimator", "map", "companion", "sim", "world"}


def _vec3(value: Any, where: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float) if isinstance(value, (list, tuple)) else None
    if arr is None or arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{where}: expected three finite numbers (NED), got {value!r}")
    return arr


def _cov3(value: Any, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{where}: expected a 3x3 covariance matrix, got {value!r}")
    if not np.allclose(arr, arr.T, atol=1e-12) or np.any(np.linalg.eigvalsh(arr) <= 0.0):
        raise ConfigError(f"{where}: covariance must be symmetric positive definite, got {value!r}")
    return arr


def _number(value: Any, where: str, *, positive: bool = False, nonnegative: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: expected a finite number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{where}: must be > 0, got {value!r}")
    if nonnegative and value < 0:
        raise ConfigError(f"{where}: must be >= 0, got {value!r}")
    return float(value)


def _check_keys(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(allowed))})")


@dataclass(frozen=True)
class Wall:
    """Static half-space: free space is ``normal . p <= offset`` (unit NED normal, metres)."""

    normal: np.ndarray
    offset: float


@dataclass(frozen=True)
class StaticObstacle:
    """Static obstacle from the map: centre (NED, m), radius (m) and position covariance (m^2)."""

    center: np.ndarray
    radius: float
    covariance: np.ndarray


@dataclass(frozen=True)
class MissionConfig:
    """Where to go: the goal (NED, m), when it counts as reached, and waypoint spacing (m)."""

    goal: np.ndarray
    goal_tolerance_m: float = 0.3
    waypoint_spacing_m: float = 6.0


@dataclass(frozen=True)
class LoopConfig:
    """Settings of the companion's control loop (``[companion]``).

    Attributes
    ----------
    setpoint_rate_hz : rate of SET_POSITION_TARGET_LOCAL_NED while streaming (>= 10 Hz).
    estimate_timeout_s : drone estimate older than this is stale: brake.
    obstacle_radius_m : body radius assumed for tracked obstacles (MAVLink does not carry one).
    drone_covariance : where the drone's planning covariance comes from, held over the horizon
        (the autopilot closes the loop, so open-loop growth does not apply):
        ``"reported"`` (default) uses the autopilot's own estimate covariance from
        ``ODOMETRY`` (PX4's EKF has already filtered; its errors are correlated in time,
        so re-filtering them as independent measurements would be overconfident), and
        the filter's covariance while none is reported; ``"estimate"`` always uses the
        companion filter's covariance; ``"predicted"`` uses its open-loop prediction.
    drone_cov_floor_m2 : isotropic floor added to the drone's planning covariance.
    max_constrained_tracks : most obstacle tracks one replan constrains; the riskiest are
        chosen (:mod:`companion.loop.track_selection`), the rest counted and reported.
    max_plan_age_s : link seconds after its request past which a plan is no longer flown
        (the stream brakes within the acceleration bound until a newer plan arrives).

    prestream_s, retry_period_s, max_retries, reengage : OFFBOARD engagement (see ``companion.mavlink.offboard``).
    setpoint_kind : ``"velocity"`` (default) streams the plan's velocity commands;
        ``"position_velocity"`` streams the plan's position with its velocity as feed-forward
        while tracking a plan (PX4's position loop removes the slow tail of its velocity response).
    """

    setpoint_rate_hz: float = 20.0
    estimate_timeout_s: float = 0.5
    obstacle_radius_m: float = 0.5
    drone_covariance: str = "reported"
    drone_cov_floor_m2: float = 0.0
    max_plan_age_s: float = 1.0
    max_constrained_tracks: int = 8
    prestream_s: float = 1.0
    retry_period_s: float = 1.0
    max_retries: int = 5
    reengage: bool = False
    setpoint_kind: str = "velocity"

    def offboard_config(self, **overrides: object) -> OffboardConfig:
        """The engagement settings of this loop, with ``overrides`` (e.g. ``arm``, ``takeoff_alt_m``)."""
        base = dict(prestream_s=self.prestream_s, retry_period_s=self.retry_period_s, max_retries=self.max_retries, reengage=self.reengage)
        return OffboardConfig(**{**base, **overrides})

    def __post_init__(self) -> None:
        if not self.setpoint_rate_hz >= 10.0:
            raise ConfigError(f"[companion] setpoint_rate_hz must be >= 10 Hz (PX4 needs > 2 Hz), got {self.setpoint_rate_hz!r}")
        if self.setpoint_kind not in ("velocity", "position_velocity"):
            raise ConfigError(f"[companion] setpoint_kind must be 'velocity' or 'position_velocity', got {self.setpoint_kind!r}")
        if not (isinstance(self.max_plan_age_s, (int, float)) and math.isfinite(self.max_plan_age_s) and self.max_plan_age_s > 0.0):
            raise ConfigError(f"[companion] max_plan_age_s must be finite seconds > 0, got {self.max_plan_age_s!r}")
        if isinstance(self.max_constrained_tracks, bool) or not isinstance(self.max_constrained_tracks, int) or not 1 <= self.max_constrained_tracks <= 64:
            raise ConfigError(f"[companion] max_constrained_tracks must be an integer in 1..64, got {self.max_constrained_tracks!r}")
        if self.drone_covariance not in ("reported", "estimate", "predicted"):
            raise ConfigError(f"[companion] drone_covariance must be 'reported', 'estimate' or 'predicted', got {self.drone_covariance!r}")


@dataclass(frozen=True)
class CompanionScenario:
    """Everything the companion takes from a scenario file."""

    path: Path
    name: str
    description: str
    duration_s: float
    drone_radius_m: float
    mission: MissionConfig
    planner: PlannerConfig
    drone_filter: DroneFilterConfig
    tracker: TrackerConfig
    loop: LoopConfig
    walls: tuple[Wall, ...] = field(default_factory=tuple)
    static_obstacles: tuple[StaticObstacle, ...] = field(default_factory=tuple)

    @property
    def walls_normal(self) -> np.ndarray:
        return np.array([w.normal for w in self.walls]).reshape(-1, 3)

    @property
    def walls_offset(self) -> np.ndarray:
        return np.array([w.offset for w in self.walls], dtype=float)


def load_scenario(path: str | Path, **planner_overrides: Any) -> CompanionScenario:
    """Read the companion's sections of a scenario TOML file.

    Parameters
    ----------
    path : path of the TOML file.
    **planner_overrides : values that replace ``[planner]`` keys (e.g. ``formulation``).

    Raises
    ------
    ConfigError
        The file is missing or not TOML, or a section the companion owns has an unknown
        key or a bad value (the message names the file, section and key).
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: scenario file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return scenario_from_dict(data, str(path), **planner_overrides)


def scenario_from_dict(data: dict[str, Any], source: str = "<dict>", **planner_overrides: Any) -> CompanionScenario:
    """The companion's sections of a parsed scenario (``tomllib`` output; ``source`` names it in errors).

    Raises
    ------
    ConfigError
        As :func:`load_scenario`, naming ``source`` instead of a file.
    """
    path = Path(source)
    unknown = sorted(set(data) - _TOP_LEVEL)
    if unknown:
        raise ConfigError(f"{path}: unknown section(s) {', '.join(unknown)}")

    sc = data.get("scenario", {})
    _check_keys(sc, {"name", "description", "duration_s"}, f"{path} [scenario]")
    vehicle = data.get("vehicle", {})
    _check_keys(vehicle, {"radius_m", "start_ned_m"}, f"{path} [vehicle]")
    drone_radius = _number(vehicle.get("radius_m", 0.5), f"{path} [vehicle] radius_m", positive=True)

    mission_t = data.get("mission")
    if mission_t is None or "goal_ned_m" not in mission_t:
        raise ConfigError(f"{path} [mission]: goal_ned_m is required")
    _check_keys(mission_t, {f.name for f in fields(MissionConfig)} - {"goal"} | {"goal_ned_m"}, f"{path} [mission]")
    mission = MissionConfig(
        goal=_vec3(mission_t["goal_ned_m"], f"{path} [mission] goal_ned_m"),
        goal_tolerance_m=_number(mission_t.get("goal_tolerance_m", 0.3), f"{path} [mission] goal_tolerance_m", positive=True),
        waypoint_spacing_m=_number(mission_t.get("waypoint_spacing_m", 6.0), f"{path} [mission] waypoint_spacing_m", positive=True),
    )

    overrides = {"drone_radius_m": drone_radius, **planner_overrides}
    planner = PlannerConfig.from_toml_table(data.get("planner", {}), source=f"{path} [planner]", **overrides)

    est = dict(data.get("estimator", {}))
    drone_t, tracker_t = est.pop("drone", {}), est.pop("tracker", {})
    _check_keys(est, set(), f"{path} [estimator]")
    try:
        drone_filter = DroneFilterConfig.from_mapping(drone_t, where=f"{path} [estimator.drone]")
        tracker = TrackerConfig.from_mapping(tracker_t, where=f"{path} [estimator.tracker]")
    except EstimatorConfigError as exc:
        raise ConfigError(str(exc)) from None

    loop_t = data.get("companion", {})
    _check_keys(loop_t, {f.name for f in fields(LoopConfig)}, f"{path} [companion]")
    try:
        loop = LoopConfig(**loop_t)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path} [companion]: {exc}") from None

    map_t = dict(data.get("map", {}))
    walls_t, statics_t = map_t.pop("walls", []), map_t.pop("static_obstacles", [])
    _check_keys(map_t, set(), f"{path} [map]")
    walls = []
    for i, w in enumerate(walls_t):
        where = f"{path} [[map.walls]] #{i + 1}"
        _check_keys(w, {"normal_ned", "offset_m"}, where)
        normal = _vec3(w.get("normal_ned"), f"{where} normal_ned")
        norm = float(np.linalg.norm(normal))
        if norm == 0.0:
            raise ConfigError(f"{where} normal_ned must not be zero")
        walls.append(Wall(normal / norm, _number(w.get("offset_m"), f"{where} offset_m") / norm))
    statics = []
    for i, s in enumerate(statics_t):
        where = f"{path} [[map.static_obstacles]] #{i + 1}"
        _check_keys(s, {"center_ned_m", "radius_m", "covariance_m2"}, where)
        statics.append(
            StaticObstacle(
                center=_vec3(s.get("center_ned_m"), f"{where} center_ned_m"),
                radius=_number(s.get("radius_m", 0.5), f"{where} radius_m", nonnegative=True),
                covariance=_cov3(s.get("covariance_m2", np.eye(3).tolist()), f"{where} covariance_m2"),
            )
        )
    return CompanionScenario(
        path=path,
        name=str(sc.get("name", path.stem)),
        description=str(sc.get("description", "")),
        duration_s=_number(sc.get("duration_s", 60.0), f"{path} [scenario] duration_s", positive=True),
        drone_radius_m=drone_radius,
        mission=mission,
        planner=planner,
        drone_filter=drone_filter,
        tracker=tracker,
        loop=loop,
        walls=tuple(walls),
        static_obstacles=tuple(statics),
    )
