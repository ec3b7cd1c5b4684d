"""The companion's view of a scenario file: mission, planner, estimator, map, loop and offboard settings.

The companion reads ``[scenario]``, ``[vehicle]``, ``[mission]``, ``[planner]``,
``[estimator]`` (with ``[estimator.drone]`` and ``[estimator.tracker]``), ``[map]``,
``[companion]`` and ``[offboard]``. It never uses ``[sim]`` or ``[world]`` (mavsim's:
moving obstacles are learnt from MAVLink, as in the field), but it rejects unknown keys
there too, against :data:`SIMULATOR_KEYS` (a declared copy of mavsim's schema that a test
holds equal to mavsim's own), so the companion never silently accepts a file mavsim
rejects. Every section is validated at load with :mod:`companion.validation`; errors name
the file, the section and the key. Sizes are bounded (file bytes, walls, static
obstacles; horizon and iterations in :mod:`companion.core.planner.config`). Units: NED
metres, seconds. docs/CONFIGURATION.md lists every key.
"""

from __future__ import annotations

import logging
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from companion import validation as check
from companion.errors import ConfigError
from companion.mavlink.offboard import OffboardConfig
from companion.core.planner.config import PlannerConfig
from companion.loop.goal_frames import GoalSpec
from companion.loop.mission_file import read_mission_file
from companion.loop.intake.traffic_config import TrafficConfig, traffic_from_toml
from companion.loop.fleet_config import FleetConfig
from estimator import DroneFilterConfig, EstimatorConfigError, TrackerConfig

logger = logging.getLogger(__name__)

#: Largest scenario file read (bytes): the shipped ones are a few kB.
MAX_SCENARIO_BYTES = 1 << 20
#: How far below the local origin (NED ``z > 0``: the origin is where the autopilot's
#: estimate started, on the ground at home) a goal may lie, metres: a goal lower than
#: this is under the ground there, and the vehicle would fly into it. The half metre
#: allows for uneven ground and a goal given on the ground; a mission that must end
#: below its home's ground is not supported.
GOAL_BELOW_ORIGIN_MAX_M = 0.5
#: Largest number of ``[[map.walls]]`` and ``[[map.static_obstacles]]``.
MAX_WALLS = 64
MAX_STATIC_OBSTACLES = 256

_COMPANION_SECTIONS = {"scenario", "vehicle", "mission", "planner", "estimator", "map", "companion", "offboard", "traffic",
                       "fleet"}

#: Keys of the sections mavsim owns, by section (``world.obstacles`` is each ``[[world.obstacles]]``).
#: mavsim validates their values; tests/loop/test_config.py holds this equal to mavsim's schema.
SIMULATOR_KEYS: dict[str, frozenset[str]] = {
    "sim": frozenset({
        "vehicle", "velocity_time_constant_s", "accel_max_mps2", "physics_step_s", "position_noise_cov_m2",
        "position_noise_correlation_s", "velocity_noise_cov_m2ps2", "velocity_bias_mps", "velocity_bias_period_s",
        "estimator_resets", "gps_outages", "gps_outage_drift_mps", "gps_outage_sd_growth_mps", "gps_degradations",
        "gps_degradation_correlation_s",
        "start_airborne", "start_armed", "start_mode", "start_yaw_rad",
        "home_lat_deg", "home_lon_deg", "home_alt_m", "geoid_separation_m", "arming_delay_s", "offboard_reject_ack",
        "params", "stream_rates_hz",
    }),
    "world": frozenset({"obstacles", "obstacle_sysid_base", "obstacle_compid"}),
    "world.obstacles": frozenset({
        "name", "radius_m", "start_ned_m", "velocity_ned_mps", "waypoints_ned_m", "speed_mps", "loop",
        "measurement_cov_m2", "measurement_correlation_s", "velocity_cov_m2ps2", "report_rate_hz", "start_delay_s",
        "transport", "message", "clock_offset_s", "clock_drift", "icao_address", "emitter_type",
        "clock_reboot_at_s", "garbage_stamp_at_s",
    }),
}


def read_scenario_toml(path: str | Path) -> dict[str, Any]:
    """The parsed TOML of a scenario file (at most :data:`MAX_SCENARIO_BYTES`, UTF-8).

    Raises
    ------
    ConfigError
        Missing, a directory, unreadable, too large, not UTF-8 or not TOML (names the file).
    """
    path = Path(path)
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_SCENARIO_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{path}: scenario file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a scenario file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read scenario file: {exc.strerror or exc}") from None
    if len(raw) > MAX_SCENARIO_BYTES:
        raise ConfigError(f"{path}: scenario file larger than {MAX_SCENARIO_BYTES} bytes")
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte offset {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


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
    """Where to go (``[mission]``): the goal, when it counts as reached, and waypoint spacing (m).

    The goal is given in one frame (:mod:`companion.loop.goal_frames`), or as a mission (``plan_file``),
    or not at all when ``fly --goal`` or ``--mission`` says where to fly:
    ``goal_ned_m`` (local NED, m), ``goal_home_m`` (north, east, up metres from home) or
    ``goal_geo`` (latitude, longitude degrees, altitude m; ``goal_geo_altitude`` says
    whether that is AMSL or relative to home). A goal in the local frame may not lie more
    than :data:`GOAL_BELOW_ORIGIN_MAX_M` below the local origin (``z <= 0.5``; NED, z down);
    the others are checked the same way once placed. ``goal_wait_s`` is how long a goal
    that needs the vehicle's origin or home waits for them before the run gives up.
    ``fence_file``: a ``.plan`` whose geofence the planner keeps the drone in
    (:mod:`companion.loop.fence_source`; default: the ``plan_file``'s own fence, if it has one).

    ``goal_tolerance_m`` has no default: mavsim reads the same key for its truth
    (time to goal), so the scenario file is its one source.
    ``autopilot_speed_mps``: the speed at which the autopilot flies its own mission legs (m/s;
    PX4's ``MPC_XY_CRUISE``, 5 by default; ArduCopter's ``WPNAV_SPEED`` / 100): the companion
    predicts the autopilot's path with it while watching (``[offboard] takeover = "watch"``),
    on every leg the mission's own DO_CHANGE_SPEED items leave at the default.
    ``autopilot_climb_mps``: the autopilot's take-off climb rate (m/s; PX4's ``MPC_TKO_SPEED``,
    1.5 by default; ArduCopter's ``WPNAV_SPEED_UP`` / 100): while the autopilot is on its
    mission's NAV_TAKEOFF, its path is predicted as a climb where it is, then the leg to the item.
    """

    goal_ned_m: np.ndarray | None
    goal_tolerance_m: float
    waypoint_spacing_m: float = 6.0
    goal_home_m: np.ndarray | None = None
    goal_geo: np.ndarray | None = None
    goal_geo_altitude: str = "amsl"
    goal_wait_s: float = 30.0
    plan_file: str | None = None
    plan_upload: bool = True
    fence_file: str | None = None
    autopilot_speed_mps: float = 5.0
    autopilot_climb_mps: float = 1.5

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        given = [k for k in ("goal_ned_m", "goal_home_m", "goal_geo", "plan_file") if getattr(self, k) is not None]
        if len(given) > 1:   # (none: the goal comes from elsewhere, fly --goal or --mission; see scenario_from_dict)
            raise ConfigError(f"give one of goal_ned_m, goal_home_m, goal_geo, plan_file (given: {', '.join(given)})")
        set_("plan_upload", check.boolean("plan_upload", self.plan_upload))
        if self.plan_file is not None:
            set_("plan_file", check.text("plan_file", self.plan_file, max_len=4096))
        if self.fence_file is not None:
            set_("fence_file", check.text("fence_file", self.fence_file, max_len=4096))
        for key in (k for k in given if k != "plan_file"):
            set_(key, check.vector3(key, getattr(self, key)))
        if self.goal_ned_m is not None and self.goal_ned_m[2] > GOAL_BELOW_ORIGIN_MAX_M:
            raise ConfigError(f"goal_ned_m = {self.goal_ned_m.tolist()!r} is {self.goal_ned_m[2]:g} m below the local "
                              f"origin (NED: z is down, so z > 0 is under the ground at home); z must be at most "
                              f"{GOAL_BELOW_ORIGIN_MAX_M:g} (e.g. -5 for 5 m up)")
        set_("goal_geo_altitude", check.choice("goal_geo_altitude", self.goal_geo_altitude, ("amsl", "rel")))
        set_("goal_tolerance_m", check.number("goal_tolerance_m", self.goal_tolerance_m, positive=True, hi=1000.0))
        set_("waypoint_spacing_m", check.number("waypoint_spacing_m", self.waypoint_spacing_m, positive=True, hi=1e4))
        set_("goal_wait_s", check.number("goal_wait_s", self.goal_wait_s, positive=True, hi=3600.0))
        set_("autopilot_speed_mps", check.number("autopilot_speed_mps", self.autopilot_speed_mps, positive=True, hi=100.0))
        set_("autopilot_climb_mps", check.number("autopilot_climb_mps", self.autopilot_climb_mps, positive=True, hi=50.0))
        if self.plan_file is None and given:
            self.goal_spec  # the frame's own checks (latitude range, distance)

    @property
    def goal(self) -> np.ndarray | None:
        """The goal position in the local frame (NED, m) when given there, else None (placed in flight)."""
        return self.goal_ned_m

    @property
    def goal_spec(self) -> GoalSpec:
        """The goal as given, in its frame (not for a ``plan_file`` mission, nor with no goal given)."""
        if self.goal_ned_m is None and self.goal_home_m is None and self.goal_geo is None:
            raise ConfigError("[mission] has no goal (goal_ned_m, goal_home_m or goal_geo)")
        if self.goal_ned_m is not None:
            return GoalSpec("ned", tuple(self.goal_ned_m))
        if self.goal_home_m is not None:
            return GoalSpec("home", tuple(self.goal_home_m))
        return GoalSpec("geo", tuple(self.goal_geo), self.goal_geo_altitude)


@dataclass(frozen=True)
class LoopConfig:
    """Settings of the companion's control loop (``[companion]``).

    Attributes
    ----------
    setpoint_rate_hz : rate of SET_POSITION_TARGET_LOCAL_NED while streaming, Hz, in [10, 100].
    estimate_timeout_s : drone estimate older than this is stale: brake (s, > 0, <= 60).
    obstacle_radius_m : body radius assumed for tracked obstacles (MAVLink does not carry one), m.
    drone_covariance : where the drone's planning covariance comes from, held over the horizon
        (the autopilot closes the loop, so open-loop growth does not apply):
        ``"reported"`` (default) uses the autopilot's own estimate covariance from
        ``ODOMETRY`` (PX4's EKF has already filtered; its errors are correlated in time,
        so re-filtering them as independent measurements would be overconfident), and
        the filter's covariance while none is reported; ``"estimate"`` always uses the
        companion filter's covariance; ``"predicted"`` uses its open-loop prediction.
    tracking_margin_m2 : isotropic covariance added to the drone's in the planner's safety rows only
        (:attr:`~companion.core.planner.request.PlanRequest.margin_cov`), m^2, in [0, 100]: how far the
        vehicle strays from a plan before the next replan starts from where it really is
        (measured against PX4: 0.1 to 0.27 m, docs/PX4.md). Not in the goal cost's metric and
        not in the realised contour of touch, which is judged on the estimate alone. A fleet
        peer's announced plan carries it too (the peer strays from its plan as much).
    max_constrained_tracks : most obstacle tracks one replan constrains, in [1, 64]; the riskiest
        are chosen (:mod:`companion.loop.track_selection`), the rest counted and reported.
    max_plan_age_s : link seconds after its request past which a plan is no longer flown
        (the stream brakes within the acceleration bound until a newer plan arrives), in (0, 10].
    brake_accel_mps2 : the stream's own braking (no valid plan, a plan too old or run out, a
        stale estimate), m/s^2 per axis, in (0, 20]; None (default) brakes within ``[planner]
        accel_max_mps2``. A vehicle that holds its last velocity when the stream stops
        (ArduCopter: ``GUID_TIMEOUT``) may need a firmer brake than the planner's comfort bound.

    plan_lead_max_s : longest lead a real-time plan starts ahead of its request, s, in [0, 1]
        (0: from the request's state, as in lockstep); the lead follows the recent plans'
        arrival delays (:meth:`companion.loop.app.Companion.plan_lead_s`).
    timesync_hz : rate of the TIMESYNC requests that measure the autopilot's clock, Hz, in [0, 50];
        0 maps it from pose arrival times only (:mod:`companion.loop.vehicle_clock`).
    vehicle_clock : how the autopilot's clock is mapped onto link time: ``"arrivals"`` (default)
        the pose arrivals of the last 0.5 s less the latency TIMESYNC measures
        (:mod:`companion.loop.vehicle_clock`); ``"timesync_line"`` as companions before
        8 December 2026 did, to replay their logs exactly (:mod:`companion.loop.vehicle_clock_line`).
    drift_window_s : window over which the autopilot's position estimate is compared with its
        own velocity (:class:`estimator.drift.PositionDrift`), s, in [0, 10]; 0 (default) off.
        When on, the planner plans in the estimate's position rate: ``V_0`` is the velocity
        estimate plus the drift, and each streamed velocity is the plan's minus the drift,
        so that the estimate moves as planned (offset-free tracking of an EKF that corrects
        its position without its velocity; measured on PX4 SITL up to 0.5 m/s, docs/PX4.md).
        Not applied while the estimate is stale (the loop brakes to zero).
    response_state : where each plan's response model starts its internal states (the velocity
        loop's error integral and the acceleration, :class:`~companion.core.planner.vehicle_model.AxisResponse`):
        ``"steady"`` (default) at their steady state at ``V_0``; ``"observed"`` from a Kalman filter
        on the model fed with the velocity estimates and the setpoints sent
        (:class:`~companion.core.planner.response_observer.ResponseObserver`). Needs
        ``[planner] vehicle_response`` and ``setpoint_kind = "velocity"``.
    position_sd_warn_m : the autopilot's reported position is uncertain (a GPS outage) when its
        largest standard deviation reaches this, m, in (0, 100]: said once by STATUSTEXT while
        engaged, and once when back below 0.7 of it (:mod:`companion.loop.position_quality`).
        Only a reported covariance (PX4's ODOMETRY) is judged. Default 0.5 m: PX4 SITL reports
        0.14-0.21 m with GPS, 1.1-1.2 m after 5 s without.
    setpoint_kind : ``"velocity"`` (default) streams the plan's velocity commands;
        ``"position_velocity"`` streams the plan's position with its velocity as feed-forward
        while tracking a plan (PX4's position loop removes the slow tail of its velocity response).

    OFFBOARD engagement is the ``[offboard]`` table (:class:`companion.mavlink.offboard.OffboardConfig`).
    """

    setpoint_rate_hz: float = 20.0
    estimate_timeout_s: float = 0.5
    obstacle_radius_m: float = 0.5
    drone_covariance: str = "reported"
    tracking_margin_m2: float = 0.0
    initial_velocity: str = "plan"
    max_plan_age_s: float = 1.0
    brake_accel_mps2: float | None = None
    max_constrained_tracks: int = 8
    setpoint_kind: str = "velocity"
    timesync_hz: float = 2.0
    vehicle_clock: str = "arrivals"
    plan_lead_max_s: float = 0.25
    drift_window_s: float = 0.0
    response_state: str = "steady"
    position_sd_warn_m: float = 0.5

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("setpoint_rate_hz", check.number("setpoint_rate_hz", self.setpoint_rate_hz, lo=10.0, hi=100.0))
        set_("estimate_timeout_s", check.number("estimate_timeout_s", self.estimate_timeout_s, positive=True, hi=60.0))
        set_("obstacle_radius_m", check.number("obstacle_radius_m", self.obstacle_radius_m, lo=0.0, hi=100.0))
        check.choice("drone_covariance", self.drone_covariance, ("reported", "estimate", "predicted"))
        set_("tracking_margin_m2", check.number("tracking_margin_m2", self.tracking_margin_m2, lo=0.0, hi=100.0))
        check.choice("setpoint_kind", self.setpoint_kind, ("velocity", "position_velocity"))
        check.choice("initial_velocity", self.initial_velocity, ("plan", "estimate"))
        check.choice("response_state", self.response_state, ("steady", "observed"))
        check.choice("vehicle_clock", self.vehicle_clock, ("arrivals", "timesync_line"))
        if self.response_state == "observed" and self.setpoint_kind != "velocity":
            raise ConfigError(f"response_state = 'observed' needs setpoint_kind = 'velocity' (the observer "
                              f"models the autopilot's velocity loop), got {self.setpoint_kind!r}")
        set_("max_plan_age_s", check.number("max_plan_age_s", self.max_plan_age_s, positive=True, hi=10.0))
        if self.brake_accel_mps2 is not None:
            set_("brake_accel_mps2", check.number("brake_accel_mps2", self.brake_accel_mps2, positive=True, hi=20.0))
        set_("plan_lead_max_s", check.number("plan_lead_max_s", self.plan_lead_max_s, lo=0.0, hi=1.0))
        set_("timesync_hz", check.number("timesync_hz", self.timesync_hz, lo=0.0, hi=50.0))
        set_("drift_window_s", check.number("drift_window_s", self.drift_window_s, lo=0.0, hi=10.0))
        set_("position_sd_warn_m", check.number("position_sd_warn_m", self.position_sd_warn_m, positive=True, hi=100.0))
        set_("max_constrained_tracks", check.integer("max_constrained_tracks", self.max_constrained_tracks, lo=1, hi=64))


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
    companion: LoopConfig  # the [companion] table
    offboard: OffboardConfig = field(default_factory=OffboardConfig)
    walls: tuple[Wall, ...] = field(default_factory=tuple)
    static_obstacles: tuple[StaticObstacle, ...] = field(default_factory=tuple)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)
    fleet: FleetConfig = field(default_factory=FleetConfig)

    @property
    def walls_normal(self) -> np.ndarray:
        return np.array([w.normal for w in self.walls]).reshape(-1, 3)

    @property
    def walls_offset(self) -> np.ndarray:
        return np.array([w.offset for w in self.walls], dtype=float)


def load_scenario(path: str | Path, *, goal_elsewhere: bool = False, **planner_overrides: Any) -> CompanionScenario:
    """Read the companion's sections of a scenario TOML file (see :func:`scenario_from_dict`).

    Raises
    ------
    ConfigError
        The file cannot be read or parsed, or a section has a bad value or an unknown
        key (the message names the file, section and key).
    """
    return scenario_from_dict(read_scenario_toml(path), Path(path), goal_elsewhere=goal_elsewhere, **planner_overrides)


def _section(data: Mapping[str, Any], name: str, where: str) -> Mapping[str, Any]:
    return check.table(f"{where} [{name}]", data.get(name, {}))


def _check_simulator_keys(data: Mapping[str, Any], path: Path) -> None:
    """Unknown keys of mavsim's sections, by the declared schema (mavsim checks the values)."""
    check.check_keys(f"{path} [sim]", _section(data, "sim", str(path)), SIMULATOR_KEYS["sim"])
    world = _section(data, "world", str(path))
    check.check_keys(f"{path} [world]", world, SIMULATOR_KEYS["world"])
    obstacles = check.array_of_tables(f"{path} [[world.obstacles]]", world.get("obstacles", []), max_len=254)
    for i, ob in enumerate(obstacles):
        check.check_keys(f"{path} [[world.obstacles]] #{i + 1}", ob, SIMULATOR_KEYS["world.obstacles"])


def _map(data: Mapping[str, Any], path: Path) -> tuple[tuple[Wall, ...], tuple[StaticObstacle, ...]]:
    map_t = dict(_section(data, "map", str(path)))
    walls_t = check.array_of_tables(f"{path} [[map.walls]]", map_t.pop("walls", []), max_len=MAX_WALLS)
    statics_t = check.array_of_tables(f"{path} [[map.static_obstacles]]", map_t.pop("static_obstacles", []),
                                      max_len=MAX_STATIC_OBSTACLES)
    check.check_keys(f"{path} [map]", map_t, set())
    walls, statics = [], []
    for i, w in enumerate(walls_t):
        where = f"{path} [[map.walls]] #{i + 1}"
        check.check_keys(where, w, {"normal_ned", "offset_m"})
        try:
            normal = check.vector3("normal_ned", w.get("normal_ned"))
            offset = check.number("offset_m", w.get("offset_m"), lo=-1e6, hi=1e6)
            norm = float(np.linalg.norm(normal))
            if norm == 0.0:
                raise ConfigError("normal_ned must not be zero")
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        walls.append(Wall(normal / norm, offset / norm))
    for i, st in enumerate(statics_t):
        where = f"{path} [[map.static_obstacles]] #{i + 1}"
        check.check_keys(where, st, {"center_ned_m", "radius_m", "covariance_m2"})
        try:
            statics.append(StaticObstacle(
                center=check.vector3("center_ned_m", st.get("center_ned_m")),
                radius=check.number("radius_m", st.get("radius_m", 0.5), lo=0.0, hi=1000.0),
                covariance=check.covariance3("covariance_m2", st.get("covariance_m2", np.eye(3).tolist())),
            ))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    return tuple(walls), tuple(statics)


def scenario_from_dict(data: Mapping[str, Any], path: str | Path = "<dict>", *, goal_elsewhere: bool = False,
                       **planner_overrides: Any) -> CompanionScenario:
    """The companion's scenario from parsed TOML (``path`` names the file, or the source, in errors).

    Parameters
    ----------
    data : the parsed file (:func:`read_scenario_toml`, or a generated scenario).
    path : where it came from (a file, or e.g. ``"<scenario name>"``).
    goal_elsewhere : the goal comes from elsewhere (``fly --goal`` or ``--mission``): ``[mission]``
        may then have none of its own.
    **planner_overrides : values that replace ``[planner]`` keys (e.g. ``formulation``).
    """
    path = Path(path)
    where = str(path)
    check.table(where, data)
    unknown = sorted(set(data) - _COMPANION_SECTIONS - set(SIMULATOR_KEYS))
    if unknown:
        raise ConfigError(f"{path}: unknown section(s) {', '.join(unknown)}")
    _check_simulator_keys(data, path)

    sc = _section(data, "scenario", where)
    check.check_keys(f"{path} [scenario]", sc, {"name", "description", "duration_s"})
    try:
        name = check.text("name", sc.get("name", path.stem), max_len=200)
        description = check.text("description", sc.get("description", ""))
        duration_s = check.number("duration_s", sc.get("duration_s", 60.0), positive=True, hi=86_400.0)
    except ConfigError as exc:
        raise ConfigError(f"{path} [scenario]: {exc}") from None
    vehicle = _section(data, "vehicle", where)
    check.check_keys(f"{path} [vehicle]", vehicle, {"radius_m", "start_ned_m"})
    try:
        drone_radius = check.number("radius_m", vehicle.get("radius_m", 0.5), positive=True, hi=100.0)
        if "start_ned_m" in vehicle:
            check.vector3("start_ned_m", vehicle["start_ned_m"])
    except ConfigError as exc:
        raise ConfigError(f"{path} [vehicle]: {exc}") from None

    mission_t = _section(data, "mission", where)
    if "goal_tolerance_m" not in mission_t:
        raise ConfigError(f"{path} [mission]: goal_tolerance_m is required")
    if not goal_elsewhere and not any(k in mission_t for k in ("goal_ned_m", "goal_home_m", "goal_geo", "plan_file")):
        raise ConfigError(f"{path} [mission]: goal_ned_m is required (or goal_home_m, goal_geo, plan_file; "
                          "or fly --goal or --mission)")
    mission_t = {"goal_ned_m": None, **mission_t}
    for key in ("plan_file", "fence_file"):
        if isinstance(mission_t.get(key), str) and not (key == "fence_file" and mission_t[key] == "vehicle"):
            # relative to the scenario file, and read now: errors at load
            plan = Path(mission_t[key]).expanduser()
            if not plan.is_absolute() and path.parent.is_dir() and not str(path).startswith("<"):
                plan = path.parent / plan
            mission_t[key] = str(plan)
            read = read_mission_file(plan, fence_only=key == "fence_file")
            if key == "fence_file" and not read.polygons and not read.circles:
                raise ConfigError(f"{path} [mission]: fence_file {plan}: no geofence in it (geoFence polygons or circles)")
    mission = check.build_section(MissionConfig, mission_t, f"{path} [mission]")

    overrides = {"drone_radius_m": drone_radius, **planner_overrides}
    planner = PlannerConfig.from_toml_table(_section(data, "planner", where), source=f"{path} [planner]", **overrides)

    est = dict(_section(data, "estimator", where))
    drone_t, tracker_t = est.pop("drone", {}), est.pop("tracker", {})
    check.check_keys(f"{path} [estimator]", est, {"drone", "tracker"})
    try:
        drone_filter = DroneFilterConfig.from_mapping(check.table(f"{path} [estimator.drone]", drone_t),
                                                      where=f"{path} [estimator.drone]")
        tracker = TrackerConfig.from_mapping(check.table(f"{path} [estimator.tracker]", tracker_t),
                                             where=f"{path} [estimator.tracker]")
    except EstimatorConfigError as exc:
        raise ConfigError(str(exc)) from None

    loop = check.build_section(LoopConfig, _section(data, "companion", where), f"{path} [companion]")
    if loop.response_state == "observed" and planner.vehicle_response is None:
        raise ConfigError(f"{path} [companion]: response_state = 'observed' needs [planner] vehicle_response "
                          f"(the velocity lag has no internal state to observe)")
    offboard = check.build_section(OffboardConfig, _section(data, "offboard", where), f"{path} [offboard]")
    walls, statics = _map(data, path)
    return CompanionScenario(
        path=path, name=name, description=description, duration_s=duration_s, drone_radius_m=drone_radius,
        mission=mission, planner=planner, drone_filter=drone_filter, tracker=tracker, companion=loop,
        offboard=offboard, walls=walls, static_obstacles=statics,
        traffic=traffic_from_toml(_section(data, "traffic", where), f"{path} [traffic]"),
        fleet=check.build_section(FleetConfig, _section(data, "fleet", where), f"{path} [fleet]"),
    )
