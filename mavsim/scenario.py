"""Scenario files (``configs/*.toml``) as mavsim reads them.

(Over 400 lines: about a third is the key reference below; the rest is one reader and
its one typed accessor, which belong together so that each key sits beside its check.)

mavsim owns ``[sim]`` and ``[world]`` (unknown keys there are rejected, naming file,
section and key) and reads named keys of the shared sections: ``[scenario]`` (name,
description, duration_s), ``[vehicle]`` (radius_m, start_ned_m), ``[mission]``
(goal_ned_m, at most 0.5 m below the local origin, and with it the required
goal_tolerance_m: the one value both programs read; for a ``plan_file`` mission the goal is
its last NAV_WAYPOINT, read from the file for the referee) and ``[map]`` (walls, static
obstacles, for collision truth). Sections owned by the companion (``[planner]``, ``[estimator]``, the rest of
``[mission]``) are not inspected.

``[sim]`` keys (all optional)
-----------------------------
vehicle : str, default ``"lag"``
    The vehicle's velocity response: ``"lag"``, a first-order lag (the two keys below);
    or one an autopilot personality brings (:data:`mavsim.personalities.VEHICLE_PROFILES`):
    ``"px4"``, PX4's PID velocity loop against SIH's linear drag with an attitude lag
    (:mod:`mavsim.personalities.px4_response`), which responds like PX4 SITL
    (docs/VEHICLE_PROFILES.md).
velocity_time_constant_s : float, default 0.3
    Time constant of the first-order velocity response (s); ``vehicle = "lag"`` only.
accel_max_mps2 : float, default 4.0
    Bound on the norm of the vehicle acceleration (m/s^2, at most 20); ``vehicle = "lag"`` only.
physics_step_s : float, default 0.01
    Fixed physics step (s); ``advance`` may end on a shorter partial step.
position_noise_cov_m2 : 3x3, default 0.001 I
    Covariance of the Gaussian noise on reported drone positions (NED, m^2); the
    ODOMETRY pose covariance reports exactly this matrix.
position_noise_correlation_s : float, default 0
    Correlation time of that error (s): a first-order Gauss-Markov process with the
    covariance above at every instant, as an EKF's error wanders (``mavsim.noise``);
    0 draws it afresh at every instant (white).
velocity_noise_cov_m2ps2 : 3x3, default 0.001 I
    Covariance of the noise on reported drone velocities ((m/s)^2).
velocity_bias_mps : 3 numbers, default [0, 0, 0]
    Amplitude (m/s per NED axis, each at most 5) of a slowly varying error of the reported
    velocity that the velocity loop flies on, as PX4's does on its EKF's estimate: the
    vehicle flies the setpoint less the bias and reports its velocity plus the bias, while
    the reported position follows the truth (``mavsim.noise.VelocityBias``; PX4 SITL: 0.3
    to 0.5 m/s for seconds).
velocity_bias_period_s : float, default 20
    Its period (s).
estimator_resets : list of [t_s, dn, de, dd], default none
    Resets of the autopilot's estimator (at most 100): at simulated time ``t_s`` (s since boot)
    the reported position estimate (LOCAL_POSITION_NED, ODOMETRY, GLOBAL_POSITION_INT) steps by
    ``[dn, de, dd]`` (m, NED, each at most 100 m in size; the steps add up) and ODOMETRY's
    ``reset_counter`` counts one more, as PX4's EKF does when it resets its position (GPS lost
    and regained). The truth and the vehicle's motion do not jump.
gps_outages : list of [t_s, duration_s], default none
    GPS outages (at most 100, not overlapping): from simulated time ``t_s`` (s since boot) for
    ``duration_s`` (0 < d <= 600 s) the estimator dead-reckons, as PX4's EKF2 does without GPS:
    the reported position drifts at a velocity drawn per outage (``gps_outage_drift_mps`` per
    axis, 1-sigma; seeded), the horizontal variance reported in ODOMETRY grows by
    ``(gps_outage_sd_growth_mps * tau)**2`` at ``tau`` s into the outage, and GPS_RAW_INT shows
    no fix. When it ends the drift is gone at once and ODOMETRY's ``reset_counter`` counts one
    more (PX4 resets its position to the GPS). PX4's own limit on dead reckoning
    (``EKF2_NOAID_TOUT``, 5 s) ends a longer outage in its failsafe: the position invalid, the
    vehicle in ALTCTL until the GPS is back, then returning (AUTO.RTL). The ArduPilot
    personality refuses outages of 5 s or more (its EKF failsafe is not modelled).
    Measured on PX4 SITL (docs/FAULTS.md): 1.6 to 3.6 m of drift and a reported deviation
    from 0.14-0.17 m to 1.09-1.20 m over 5 s.
gps_outage_drift_mps : float, default 0.4
    The 1-sigma drift velocity of the estimate in an outage, per axis (m/s, 0 to 5).
gps_outage_sd_growth_mps : float, default 0.2
    How fast the reported horizontal standard deviation grows in an outage (m/s, 0 to 5).
gps_degradations : list of [t_s, duration_s, sd_m], default none
    Spells of a degraded GPS (at most 100, not overlapping; 0 < duration_s <= 600, 0 < sd_m <= 20):
    from ``t_s`` for ``duration_s`` the estimate the autopilot reports carries an extra horizontal
    error of standard deviation ``sd_m`` per axis (north, east; a Gauss-Markov error of
    correlation time ``gps_degradation_correlation_s``, seeded from its own stream), and the
    horizontal variance ODOMETRY reports grows by ``sd_m**2`` (an honest estimator: its
    covariance says what it knows); GPS_RAW_INT's ``h_acc`` grows with it. A noisy GPS that the
    estimator still fuses, unlike an outage: no reset, no failsafe.
gps_degradation_correlation_s : float, default 2.0
    Correlation time of a degraded GPS's error in the estimate (s, 0 to 60; 0: white).
start_airborne : bool, default ``start_ned_m[2] < 0``
    Spawn in the air, hovering. With ``false`` the start point is put on the ground.
start_armed : bool, default ``start_airborne``
    Spawn armed. Airborne and disarmed, the vehicle is held in place (as on a stand)
    until armed, so a companion can use the ground flow (select OFFBOARD, arm).
start_mode : str, default the autopilot's (PX4: ``"AUTO.LOITER"`` airborne, ``"POSCTL"`` on the ground)
    A mode of the autopilot personality (PX4: POSCTL, AUTO.LOITER, AUTO.TAKEOFF, AUTO.LAND,
    AUTO.RTL, OFFBOARD). Unset, :attr:`SimConfig.start_mode` is None and the simulator
    takes its personality's default.
start_yaw_rad : float, default 0.0
home_lat_deg, home_lon_deg, home_alt_m : float
    Geodetic position of the local origin (PX4 SITL default 47.397742, 8.545594, 488.0);
    the altitude is above mean sea level (AMSL), like GPS_GLOBAL_ORIGIN's.
geoid_separation_m : float, default 50.0
    Height of the geoid (mean sea level) above the WGS-84 ellipsoid at home, metres:
    ellipsoid height = AMSL + this. GPS_RAW_INT reports it (``alt_ellipsoid``), and
    traffic whose messages carry ellipsoid heights (UTM_GLOBAL_POSITION ``alt``,
    OPEN_DRONE_ID_LOCATION ``altitude_geodetic``) is sent with them. The default is an
    illustrative non-zero value (on Earth it lies between about -106 and +85 m) so that a
    receiver which confuses the two datums misplaces that traffic vertically.
arming_delay_s : float, default the autopilot's (PX4: 0; ArduPilot: 5 on the ground, 0 airborne)
    Arming is denied this long after boot (real PX4 needs a few seconds). For ArduPilot it is
    when its EKF has an absolute position (readiness; SITL takes about 41 s).
offboard_reject_ack : int, default 0
    COMMAND_ACK result when OFFBOARD is refused for lack of a setpoint stream (PX4
    main answers 0 and keeps the mode; older builds answer 1).
params : table, default {}
    Overrides of the autopilot's parameters (its personality's table; PX4's, e.g.
    ``{COM_OF_LOSS_T = 1.0}``).
stream_rates_hz : table, default {}
    Overrides of telemetry rates by message name, e.g. ``{ATTITUDE = 50.0}``.

``[world]`` keys
----------------
obstacle_sysid_base : int, default 101
obstacle_compid : int, default 197 (MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY, never 1)
obstacles : array of tables ``[[world.obstacles]]`` with name, radius_m, start_ned_m,
    ``velocity_ned_mps`` or (``waypoints_ned_m``, ``speed_mps``, optional ``loop``),
    measurement_cov_m2, optional measurement_correlation_s (default 0: white; > 0: the
    position error is Gauss-Markov with that correlation time and the same covariance,
    see :mod:`mavsim.noise`), optional velocity_cov_m2ps2 (velocity reported only if
    given), report_rate_hz (default 10), start_delay_s (default 0), and how the obstacle
    reaches the companion (docs/OBSTACLES.md):

    transport : ``"link"`` (default), ``"adsb"`` or ``"api"``
        ``"link"``: the obstacle's own MAVLink system on the separate obstacle link (a
        perception process, a swarm radio), sending ``message``. ``"adsb"``: the simulated
        autopilot re-streams it as ADSB_VEHICLE on its own links under its own system id, as
        PX4 does with transponder traffic (and forwards the original packet under the
        obstacle's id, so each report arrives twice). ``"api"``: the old way, ODOMETRY on the
        vehicle's API link (dangerous with a real PX4: explicit only).
    message : ``"ODOMETRY"`` (default), ``"LOCAL_POSITION_NED"``, ``"UTM_GLOBAL_POSITION"`` or
        ``"OPEN_DRONE_ID_LOCATION"`` (with ``transport = "link"``).
    clock_offset_s : float, default 0
        The sender's clock minus the vehicle's boot clock at boot (s). A clock before its
        zero wraps as its field does (uint32 ms, uint64 us).
    clock_drift : float, default 0
        Fractional rate error of the sender's clock (0.01: it runs 1 % fast), in [-0.1, 0.1].
    clock_reboot_at_s : float, optional
        The sender reboots at this simulated time: its clock starts again from 0.
    garbage_stamp_at_s : float, optional
        The first report at or after this time is stamped 0xFFFFFFFF (ODOMETRY and
        LOCAL_POSITION_NED), as a broken sender does.
    icao_address : int, default 0xA00000 + system id (ADSB)
    emitter_type : int, default 14 (ADSB_EMITTER_TYPE_UAV)
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mavsim.errors import ScenarioError
from mavsim.geo import global_to_ned
from mavsim.params import ParamTable, check_param_value
from mavsim.personalities import PERSONALITIES, VEHICLE_PROFILES

logger = logging.getLogger(__name__)

__all__ = [
    "Obstacle",
    "Scenario",
    "SimConfig",
    "StaticObstacle",
    "Wall",
    "load_scenario",
    "scenario_from_dict",
    "MODE_NAMES",
]

#: Mode names accepted by ``start_mode``: every registered personality's (the simulator
#: checks that its own personality has the mode).
MODE_NAMES = tuple(dict.fromkeys(m for p in PERSONALITIES.values() for m in p.mode_names))
#: Parameters and streams ``[sim] params`` and ``stream_rates_hz`` may name: every personality's.
_PARAMS: ParamTable = {k: v for p in reversed(PERSONALITIES.values()) for k, v in p.params.items()}
_STREAMS = tuple(dict.fromkeys(n for p in PERSONALITIES.values() for n in p.stream_rates_hz))


@dataclass(frozen=True)
class SimConfig:
    """Vehicle physics, sensor noise and autopilot behaviour settings (``[sim]``).

    ``start_mode`` None: the autopilot personality's default for ``start_airborne``."""

    vehicle: str = "lag"
    velocity_time_constant_s: float = 0.3
    accel_max_mps2: float = 4.0
    physics_step_s: float = 0.01
    position_noise_cov_m2: np.ndarray = field(default_factory=lambda: 1e-3 * np.eye(3))
    position_noise_correlation_s: float = 0.0
    velocity_noise_cov_m2ps2: np.ndarray = field(default_factory=lambda: 1e-3 * np.eye(3))
    velocity_bias_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_bias_period_s: float = 20.0
    estimator_resets: tuple[tuple[float, tuple[float, float, float]], ...] = ()
    gps_outages: tuple[tuple[float, float], ...] = ()
    gps_outage_drift_mps: float = 0.4
    gps_outage_sd_growth_mps: float = 0.2
    gps_degradations: tuple[tuple[float, float, float], ...] = ()
    gps_degradation_correlation_s: float = 2.0
    start_airborne: bool = True
    start_armed: bool = True
    start_mode: str | None = None
    start_yaw_rad: float = 0.0
    home_lat_deg: float = 47.397742
    home_lon_deg: float = 8.545594
    home_alt_m: float = 488.0
    geoid_separation_m: float = 50.0
    arming_delay_s: float | None = None
    offboard_reject_ack: int = 0
    params: dict[str, float] = field(default_factory=dict)
    stream_rates_hz: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Obstacle:
    """A scripted obstacle (``[[world.obstacles]]``); NED metres, seconds."""

    name: str
    radius_m: float
    start_ned_m: np.ndarray
    velocity_ned_mps: np.ndarray | None
    waypoints_ned_m: np.ndarray | None
    speed_mps: float
    loop: bool
    measurement_cov_m2: np.ndarray
    velocity_cov_m2ps2: np.ndarray | None
    report_rate_hz: float
    start_delay_s: float
    transport: str = "link"
    measurement_correlation_s: float = 0.0
    message: str = "ODOMETRY"
    clock_offset_s: float = 0.0
    clock_drift: float = 0.0
    icao_address: int | None = None
    emitter_type: int = 14
    clock_reboot_at_s: float | None = None
    garbage_stamp_at_s: float | None = None


@dataclass(frozen=True)
class Wall:
    """Half-space ``normal . p <= offset`` is free space (unit NED normal)."""

    normal_ned: np.ndarray
    offset_m: float


@dataclass(frozen=True)
class StaticObstacle:
    """A sphere that does not move (from ``[[map.static_obstacles]]``)."""

    center_ned_m: np.ndarray
    radius_m: float


@dataclass(frozen=True)
class Scenario:
    """Everything mavsim reads from a scenario file."""

    name: str
    description: str
    duration_s: float
    vehicle_radius_m: float
    start_ned_m: np.ndarray
    goal_ned_m: np.ndarray | None
    goal_tolerance_m: float  # required with goal_ned_m (inf without a goal)
    sim: SimConfig
    obstacles: tuple[Obstacle, ...]
    walls: tuple[Wall, ...]
    static_obstacles: tuple[StaticObstacle, ...]
    obstacle_sysid_base: int = 101
    obstacle_compid: int = 197
    source: str = "<dict>"


#: How far below the local origin (NED ``z > 0``) ``[mission] goal_ned_m`` may lie, metres:
#: further down is under the ground at home. The companion reads the same key with the same
#: bound (``companion.loop.config.GOAL_BELOW_ORIGIN_MAX_M``; a test holds them equal).
GOAL_BELOW_ORIGIN_MAX_M = 0.5
#: Largest ``[sim] accel_max_mps2`` (m/s^2): about 2 g, a multirotor's (the companion's
#: planner has the same bound on its own acceleration keys).
MAX_ACCEL_MPS2 = 20.0

#: Largest scenario file read (bytes), waypoints per obstacle, walls and static obstacles.
MAX_SCENARIO_BYTES = 1 << 20
MAX_WAYPOINTS = 10_000
MAX_MAP_ITEMS = 256

SIM_KEYS = {
    "vehicle", "velocity_time_constant_s", "accel_max_mps2", "physics_step_s", "position_noise_cov_m2", "position_noise_correlation_s",
    "velocity_bias_mps", "velocity_bias_period_s", "estimator_resets",
    "gps_outages", "gps_outage_drift_mps", "gps_outage_sd_growth_mps", "gps_degradations", "gps_degradation_correlation_s",
    "velocity_noise_cov_m2ps2", "start_airborne", "start_armed", "start_mode", "start_yaw_rad",
    "home_lat_deg", "home_lon_deg", "home_alt_m", "geoid_separation_m", "arming_delay_s", "offboard_reject_ack",
    "params", "stream_rates_hz",
}
WORLD_KEYS = {"obstacles", "obstacle_sysid_base", "obstacle_compid"}
OBSTACLE_KEYS = {
    "name", "radius_m", "start_ned_m", "velocity_ned_mps", "waypoints_ned_m", "speed_mps", "loop",
    "measurement_cov_m2", "measurement_correlation_s", "velocity_cov_m2ps2", "report_rate_hz", "start_delay_s",
    "transport", "message", "clock_offset_s", "clock_drift", "icao_address", "emitter_type",
    "clock_reboot_at_s", "garbage_stamp_at_s",
}
#: Obstacle transports and the messages a ``"link"`` obstacle can send.
TRANSPORTS = ("link", "adsb", "api")
LINK_MESSAGES = ("ODOMETRY", "LOCAL_POSITION_NED", "UTM_GLOBAL_POSITION", "OPEN_DRONE_ID_LOCATION")


class _Section:
    """Typed access to one table with errors naming file, section and key."""

    def __init__(self, source: str, name: str, table: Any, allowed: set[str] | None = None) -> None:
        if not isinstance(table, dict):
            raise ScenarioError(f"{source}: [{name}] must be a table, got {type(table).__name__}")
        self.source, self.name, self.table = source, name, table
        if allowed is not None:
            for key in table:
                if key not in allowed:
                    raise ScenarioError(
                        f"{source}: [{name}] unknown key {key!r} (allowed: {', '.join(sorted(allowed))})"
                    )

    def err(self, key: str, what: str) -> ScenarioError:
        return ScenarioError(f"{self.source}: [{self.name}] {key}: {what}")

    def has(self, key: str) -> bool:
        return key in self.table

    def number(self, key: str, default: float | None = None, *, lo: float | None = None,
               hi: float | None = None, positive: bool = False) -> float:
        if key not in self.table:
            if default is None:
                raise self.err(key, "missing")
            return float(default)
        v = self.table[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(key, f"must be a finite number, got {v!r}")
        v = float(v)
        if positive and v <= 0:
            raise self.err(key, f"must be > 0, got {v}")
        if lo is not None and v < lo:
            raise self.err(key, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            raise self.err(key, f"must be <= {hi}, got {v}")
        return v

    def integer(self, key: str, default: int, *, lo: int, hi: int) -> int:
        v = self.table.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise self.err(key, f"must be an integer in [{lo}, {hi}], got {v!r}")
        return v

    def boolean(self, key: str, default: bool) -> bool:
        v = self.table.get(key, default)
        if not isinstance(v, bool):
            raise self.err(key, f"must be true or false, got {v!r}")
        return v

    def string(self, key: str, default: str | None = None) -> str:
        if key not in self.table:
            if default is None:
                raise self.err(key, "missing")
            return default
        v = self.table[key]
        if not isinstance(v, str):
            raise self.err(key, f"must be a string, got {v!r}")
        return v

    def _array(self, key: str, default: Any, shape: tuple[int, ...], what: str, finite_what: str) -> np.ndarray:
        """A finite array of ``shape`` (named ``what`` / ``finite_what`` in errors), or ``default`` when absent."""
        if key not in self.table:
            if default is None:
                raise self.err(key, "missing")
            return np.array(default, dtype=float)
        try:
            a = np.array(self.table[key], dtype=float)
        except (TypeError, ValueError) as exc:
            raise self.err(key, f"must be {what}: {exc}") from None
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise self.err(key, f"must be {finite_what}, got {self.table[key]!r}")
        return a

    def vector3(self, key: str, default: Any = None) -> np.ndarray:
        return self._array(key, default, (3,), "3 numbers", "3 finite numbers")

    def covariance(self, key: str, default: Any = None) -> np.ndarray:
        a = self._array(key, default, (3, 3), "a 3x3 matrix", "a finite 3x3 matrix")
        if key not in self.table:
            return a
        if not np.allclose(a, a.T, atol=1e-12):
            raise self.err(key, "must be symmetric")
        if np.linalg.eigvalsh(a).min() < -1e-12:
            raise self.err(key, "must be positive semi-definite")
        return a

    def table_of_numbers(self, key: str) -> dict[str, float]:
        v = self.table.get(key, {})
        if not isinstance(v, dict):
            raise self.err(key, "must be a table")
        out = {}
        for k, x in v.items():
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise self.err(f"{key}.{k}", f"must be a finite number, got {x!r}")
            out[k] = float(x)
        return out


def _velocity_bias(s: _Section) -> np.ndarray:
    """``velocity_bias_mps``: 3 finite numbers, each at most 5 m/s in size."""
    rate = s.vector3("velocity_bias_mps", np.zeros(3))
    if np.abs(rate).max() > 5.0:
        raise s.err("velocity_bias_mps", "each amplitude must be at most 5 m/s in size")
    return rate


def _timed_rows(s: _Section, key: str, columns: str) -> np.ndarray | None:
    """``key``: at most 100 rows ``[columns]`` of finite numbers, the first a time; sorted by it
    (None when the key is absent)."""
    if not s.has(key):
        return None
    raw, width = s.table[key], len(columns.split(","))
    try:
        a = np.array(raw, dtype=float).reshape(-1, width) if isinstance(raw, list) and raw else None
    except (TypeError, ValueError):
        a = None
    if a is None or len(a) != len(raw) or not np.all(np.isfinite(a)) or len(a) > 100:
        raise s.err(key, f"must be a list of at most 100 rows [{columns}] of finite numbers, got {raw!r}")
    return a[np.argsort(a[:, 0], kind="stable")]


def _estimator_resets(s: _Section) -> tuple[tuple[float, tuple[float, float, float]], ...]:
    """``estimator_resets``: rows ``[t_s, dn, de, dd]``, t_s >= 0, steps at most 100 m; sorted by time."""
    a = _timed_rows(s, "estimator_resets", "t_s, dn, de, dd")
    if a is None:
        return ()
    if np.any(a[:, 0] < 0.0) or np.any(np.abs(a[:, 1:]) > 100.0):
        raise s.err("estimator_resets", "each t_s must be >= 0 and each step at most 100 m in size")
    return tuple((float(r[0]), (float(r[1]), float(r[2]), float(r[3]))) for r in a)


#: Longest GPS outage a scenario may hold (s). PX4 fails safe after EKF2_NOAID_TOUT (5 s by
#: default) of it; a personality whose failsafe is not modelled refuses outages from its
#: ``gps_outage_max_s`` on.
GPS_OUTAGE_MAX_S = 600.0


def _gps_outages(s: _Section) -> tuple[tuple[float, float], ...]:
    """``gps_outages``: rows ``[t_s, duration_s]``, t_s >= 0, 0 < duration_s <= 600, not overlapping; sorted."""
    a = _timed_rows(s, "gps_outages", "t_s, duration_s")
    if a is None:
        return ()
    if np.any(a[:, 0] < 0.0) or np.any(a[:, 1] <= 0.0) or np.any(a[:, 1] > GPS_OUTAGE_MAX_S):
        raise s.err("gps_outages", f"each t_s must be >= 0 and each duration_s in (0, {GPS_OUTAGE_MAX_S:g}] s")
    if np.any(a[1:, 0] < a[:-1, 0] + a[:-1, 1]):
        raise s.err("gps_outages", "outages must not overlap")
    return tuple((float(r[0]), float(r[1])) for r in a)


def _gps_degradations(s: _Section) -> tuple[tuple[float, float, float], ...]:
    """``gps_degradations``: rows ``[t_s, duration_s, sd_m]``, t_s >= 0, 0 < duration_s <= 600,
    0 < sd_m <= 20, not overlapping; sorted."""
    a = _timed_rows(s, "gps_degradations", "t_s, duration_s, sd_m")
    if a is None:
        return ()
    if np.any(a[:, 0] < 0.0) or np.any(a[:, 1] <= 0.0) or np.any(a[:, 1] > GPS_OUTAGE_MAX_S) \
            or np.any(a[:, 2] <= 0.0) or np.any(a[:, 2] > 20.0):
        raise s.err("gps_degradations", f"each t_s must be >= 0, each duration_s in (0, {GPS_OUTAGE_MAX_S:g}] s "
                    "and each sd_m in (0, 20] m")
    if np.any(a[1:, 0] < a[:-1, 0] + a[:-1, 1]):
        raise s.err("gps_degradations", "spells must not overlap")
    return tuple((float(r[0]), float(r[1]), float(r[2])) for r in a)


def _sim_config(src: str, raw: Any, start_z: float) -> SimConfig:
    s = _Section(src, "sim", raw, SIM_KEYS)
    airborne = s.boolean("start_airborne", start_z < 0)
    mode = s.string("start_mode") if s.has("start_mode") else None
    if mode is not None and mode not in MODE_NAMES:
        raise s.err("start_mode", f"must be one of {', '.join(MODE_NAMES)}, got {mode!r}")
    params = s.table_of_numbers("params")
    for name, value in params.items():
        if name not in _PARAMS:
            raise s.err(f"params.{name}", f"unknown parameter (known: {', '.join(sorted(_PARAMS))})")
        problem = check_param_value(_PARAMS, name, value)
        if problem:
            raise s.err(f"params.{name}", problem)
    rates = s.table_of_numbers("stream_rates_hz")
    for name, rate in rates.items():
        if name not in _STREAMS:
            raise s.err(f"stream_rates_hz.{name}", f"unknown stream (known: {', '.join(_STREAMS)})")
        if not 0.0 <= rate <= 1000.0:
            raise s.err(f"stream_rates_hz.{name}", f"must be in [0, 1000] Hz, got {rate}")
    vehicle = s.string("vehicle", "lag")
    if vehicle not in VEHICLE_PROFILES:
        raise s.err("vehicle", f"must be one of {', '.join(VEHICLE_PROFILES)}, got {vehicle!r}")
    if vehicle != "lag":
        for key in ("velocity_time_constant_s", "accel_max_mps2"):
            if s.has(key):
                raise s.err(key, f"applies to vehicle = \"lag\" only, not {vehicle!r}")
    return SimConfig(
        vehicle=vehicle,
        velocity_time_constant_s=s.number("velocity_time_constant_s", 0.3, positive=True),
        accel_max_mps2=s.number("accel_max_mps2", 4.0, positive=True, hi=MAX_ACCEL_MPS2),
        physics_step_s=s.number("physics_step_s", 0.01, lo=1e-4, hi=0.1),
        position_noise_cov_m2=s.covariance("position_noise_cov_m2", 1e-3 * np.eye(3)),
        position_noise_correlation_s=s.number("position_noise_correlation_s", 0.0, lo=0.0, hi=3600.0),
        velocity_noise_cov_m2ps2=s.covariance("velocity_noise_cov_m2ps2", 1e-3 * np.eye(3)),
        velocity_bias_mps=_velocity_bias(s),
        velocity_bias_period_s=s.number("velocity_bias_period_s", 20.0, positive=True, hi=3600.0),
        estimator_resets=_estimator_resets(s),
        gps_outages=_gps_outages(s),
        gps_outage_drift_mps=s.number("gps_outage_drift_mps", 0.4, lo=0.0, hi=5.0),
        gps_outage_sd_growth_mps=s.number("gps_outage_sd_growth_mps", 0.2, lo=0.0, hi=5.0),
        gps_degradations=_gps_degradations(s),
        gps_degradation_correlation_s=s.number("gps_degradation_correlation_s", 2.0, lo=0.0, hi=60.0),
        start_airborne=airborne,
        start_armed=s.boolean("start_armed", airborne),
        start_mode=mode,
        start_yaw_rad=s.number("start_yaw_rad", 0.0),
        home_lat_deg=s.number("home_lat_deg", 47.397742, lo=-89.0, hi=89.0),
        home_lon_deg=s.number("home_lon_deg", 8.545594, lo=-180.0, hi=180.0),
        home_alt_m=s.number("home_alt_m", 488.0, lo=-500.0, hi=9000.0),
        geoid_separation_m=s.number("geoid_separation_m", 50.0, lo=-120.0, hi=120.0),
        arming_delay_s=s.number("arming_delay_s", lo=0.0, hi=60.0) if s.has("arming_delay_s") else None,
        offboard_reject_ack=s.integer("offboard_reject_ack", 0, lo=0, hi=4),
        params=params,
        stream_rates_hz=rates,
    )


def _obstacle(src: str, index: int, raw: Any) -> Obstacle:
    s = _Section(src, f"world.obstacles[{index}]", raw, OBSTACLE_KEYS)
    has_v, has_w = s.has("velocity_ned_mps"), s.has("waypoints_ned_m")
    if has_v == has_w:
        raise s.err("velocity_ned_mps", "give exactly one of velocity_ned_mps or waypoints_ned_m")
    waypoints = None
    if has_w:
        try:
            waypoints = np.array(s.table["waypoints_ned_m"], dtype=float)
        except (TypeError, ValueError) as exc:
            raise s.err("waypoints_ned_m", f"must be a list of 3-vectors: {exc}") from None
        if waypoints.ndim != 2 or waypoints.shape[1] != 3 or len(waypoints) == 0 or not np.all(np.isfinite(waypoints)):
            raise s.err("waypoints_ned_m", "must be a non-empty list of finite 3-vectors")
        if len(waypoints) > MAX_WAYPOINTS:
            raise s.err("waypoints_ned_m", f"{len(waypoints)} waypoints, at most {MAX_WAYPOINTS} allowed")
        if not s.has("speed_mps"):
            raise s.err("speed_mps", "missing (needed with waypoints_ned_m)")
    elif s.has("speed_mps") or s.has("loop"):
        raise s.err("speed_mps", "speed_mps and loop go with waypoints_ned_m only")
    vel_cov = s.covariance("velocity_cov_m2ps2") if s.has("velocity_cov_m2ps2") else None
    transport = s.string("transport", "link")
    if transport not in TRANSPORTS:
        raise s.err("transport", f"must be one of {', '.join(TRANSPORTS)}, got {transport!r}")
    message = s.string("message", "ODOMETRY")
    if message not in LINK_MESSAGES or (transport != "link" and s.has("message")):
        raise s.err("message", f"must be one of {', '.join(LINK_MESSAGES)}, with transport = \"link\" only; got {message!r}")
    return Obstacle(
        name=s.string("name", f"obs{index + 1}"),
        radius_m=s.number("radius_m", 0.5, lo=0.0),
        start_ned_m=s.vector3("start_ned_m"),
        velocity_ned_mps=s.vector3("velocity_ned_mps") if has_v else None,
        waypoints_ned_m=waypoints,
        speed_mps=s.number("speed_mps", 1.0, positive=True) if has_w else 0.0,
        loop=s.boolean("loop", False),
        measurement_cov_m2=s.covariance("measurement_cov_m2", 1e-3 * np.eye(3)),
        measurement_correlation_s=s.number("measurement_correlation_s", 0.0, lo=0.0, hi=3600.0),
        velocity_cov_m2ps2=vel_cov,
        report_rate_hz=s.number("report_rate_hz", 10.0, lo=0.1, hi=200.0),
        start_delay_s=s.number("start_delay_s", 0.0, lo=0.0),
        transport=transport,
        message=message,
        clock_offset_s=s.number("clock_offset_s", 0.0, lo=-1e6, hi=1e6),
        clock_drift=s.number("clock_drift", 0.0, lo=-0.1, hi=0.1),
        icao_address=s.integer("icao_address", 0, lo=1, hi=0xFFFFFF) if s.has("icao_address") else None,
        emitter_type=s.integer("emitter_type", 14, lo=0, hi=19),
        clock_reboot_at_s=s.number("clock_reboot_at_s", lo=0.0) if s.has("clock_reboot_at_s") else None,
        garbage_stamp_at_s=s.number("garbage_stamp_at_s", lo=0.0) if s.has("garbage_stamp_at_s") else None,
    )


def scenario_from_dict(data: dict[str, Any], source: str = "<dict>") -> Scenario:
    """Build a :class:`Scenario` from parsed TOML (``tomllib.load`` output).

    Raises
    ------
    ScenarioError
        On a bad section, key or value; the message names ``source``, section and key.
    """
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: top level must be a table")
    sc = _Section(source, "scenario", data.get("scenario", {}))
    veh = _Section(source, "vehicle", data.get("vehicle", {}))
    mission = _Section(source, "mission", data.get("mission", {}))
    if mission.has("goal_ned_m") and not mission.has("goal_tolerance_m"):
        raise mission.err("goal_tolerance_m", "missing (required with goal_ned_m; the companion reads the same key)")
    start = veh.vector3("start_ned_m", [0.0, 0.0, 0.0])
    sim = _sim_config(source, data.get("sim", {}), float(start[2]))
    if not sim.start_airborne:
        start = np.array([start[0], start[1], 0.0])
    elif start[2] >= 0:
        raise veh.err("start_ned_m", "start_airborne = true needs z < 0 (NED, z down)")
    world = _Section(source, "world", data.get("world", {}), WORLD_KEYS)
    raw_obs = world.table.get("obstacles", [])
    if not isinstance(raw_obs, list):
        raise world.err("obstacles", "must be an array of tables [[world.obstacles]]")
    if len(raw_obs) > 254:
        raise world.err("obstacles", f"{len(raw_obs)} obstacles, at most 254 allowed (one system id each)")
    obstacles = tuple(_obstacle(source, i, o) for i, o in enumerate(raw_obs))
    names = [o.name for o in obstacles]
    if len(set(names)) != len(names):
        raise world.err("obstacles", f"obstacle names must be unique, got {names}")
    sysid_base = world.integer("obstacle_sysid_base", 101, lo=2, hi=255)
    if sysid_base + len(obstacles) - 1 > 255:
        raise world.err("obstacle_sysid_base", "too many obstacles for the system id range")
    compid = world.integer("obstacle_compid", 197, lo=2, hi=255)
    mp = _Section(source, "map", data.get("map", {}))
    for key in ("walls", "static_obstacles"):
        items = mp.table.get(key, [])
        if not isinstance(items, list) or len(items) > MAX_MAP_ITEMS:
            raise mp.err(key, f"must be an array of at most {MAX_MAP_ITEMS} tables")
    walls = []
    for i, w in enumerate(mp.table.get("walls", [])):
        ws = _Section(source, f"map.walls[{i}]", w)
        n = ws.vector3("normal_ned")
        norm = float(np.linalg.norm(n))
        if norm < 1e-9:
            raise ws.err("normal_ned", "must be non-zero")
        walls.append(Wall(normal_ned=n / norm, offset_m=ws.number("offset_m") / norm))
    statics = []
    for i, o in enumerate(mp.table.get("static_obstacles", [])):
        os_ = _Section(source, f"map.static_obstacles[{i}]", o)
        statics.append(StaticObstacle(os_.vector3("center_ned_m"), os_.number("radius_m", lo=0.0)))
    goal = mission.vector3("goal_ned_m") if mission.has("goal_ned_m") else None
    if goal is None and mission.has("plan_file"):
        goal = _mission_end(mission, source, sim)
    if goal is not None and goal[2] > GOAL_BELOW_ORIGIN_MAX_M:
        raise mission.err("goal_ned_m", f"z = {goal[2]:g} is below the ground at the local origin (NED, z down); "
                                        f"must be at most {GOAL_BELOW_ORIGIN_MAX_M:g} (e.g. -5 for 5 m up)")
    return Scenario(
        name=sc.string("name", Path(source).stem if source != "<dict>" else "scenario"),
        description=sc.string("description", ""),
        duration_s=sc.number("duration_s", 60.0, positive=True),
        vehicle_radius_m=veh.number("radius_m", 0.5, lo=0.0),
        start_ned_m=start,
        goal_ned_m=goal,
        goal_tolerance_m=mission.number("goal_tolerance_m", 0.3, positive=True) if goal is not None else math.inf,
        sim=sim,
        obstacles=obstacles,
        walls=tuple(walls),
        static_obstacles=tuple(statics),
        obstacle_sysid_base=sysid_base,
        obstacle_compid=compid,
        source=source,
    )


#: Largest mission file mavsim reads for the truth's goal (bytes).
_MAX_PLAN_BYTES = 4 * 1024 * 1024


def _mission_end(mission: _Section, source: str, sim: SimConfig) -> np.ndarray | None:
    """The truth's goal of a ``[mission] plan_file`` mission: its last NAV_WAYPOINT (16) in the
    local frame about home (a QGroundControl ``.plan``, or ``QGC WPL 110``; altitude relative
    to home in frame 3, AMSL in frame 0). None when the file has no waypoint; the companion
    checks the file itself, this reads only what the referee needs."""
    import json

    raw = mission.string("plan_file", "")
    path = Path(raw).expanduser()
    if not path.is_absolute() and not source.startswith("<"):
        path = Path(source).parent / path
    try:
        with path.open("rb") as f:
            text = f.read(_MAX_PLAN_BYTES + 1).decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise mission.err("plan_file", f"cannot read {path}: {exc}") from None
    rows = []   # (frame, command, lat, lon, alt)
    try:
        if text.lstrip().startswith("QGC WPL"):
            for line in text.splitlines()[1:]:
                f = line.split("\t")
                if len(f) >= 12:
                    rows.append((int(f[2]), int(f[3]), float(f[8]), float(f[9]), float(f[10])))
        else:
            for item in json.loads(text)["mission"]["items"]:
                p = item["params"]
                rows.append((int(item["frame"]), int(item["command"]), float(p[4]), float(p[5]), float(p[6])))
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise mission.err("plan_file", f"{path}: not a mission file mavsim can read ({exc})") from None
    waypoints = [r for r in rows if r[1] == 16 and r[0] in (0, 3, 5, 6)]
    if not waypoints:
        return None
    frame, _, lat, lon, alt = waypoints[-1]
    amsl = alt if frame in (0, 5) else sim.home_alt_m + alt
    return np.array(global_to_ned(lat, lon, amsl, sim.home_lat_deg, sim.home_lon_deg, sim.home_alt_m))


def shipped_scenario_names() -> list[str]:
    """The names of the scenarios shipped with the wheel (``configs/*.toml``, installed as the
    package ``companion.scenarios``); empty when that package is not installed."""
    from importlib import resources

    try:
        folder = resources.files("companion.scenarios")
    except ModuleNotFoundError:
        return []
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def shipped_scenario(text: str) -> Path | None:
    """The file of the shipped scenario named ``text`` (``antipodal`` or ``antipodal.toml``), or None:
    ``mavsim --scenario NAME`` resolves names as every ``companion`` command does."""
    from importlib import resources

    name = text[:-5] if text.endswith(".toml") else text
    if "/" in text or name not in shipped_scenario_names():
        return None
    return Path(str(resources.files("companion.scenarios") / f"{name}.toml"))


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (a path, or a shipped scenario's name).

    Raises
    ------
    ScenarioError
        If the file cannot be read or parsed, or a section, key or value is bad.
    """
    p = Path(path)
    if not p.exists():
        p = shipped_scenario(str(path)) or p
    try:
        with p.open("rb") as f:
            raw = f.read(MAX_SCENARIO_BYTES + 1)
    except IsADirectoryError:
        raise ScenarioError(f"{p}: is a directory, not a scenario file") from None
    except FileNotFoundError:
        names = ", ".join(shipped_scenario_names())
        raise ScenarioError(f"{p}: no such scenario file, and not a shipped scenario ({names})") from None
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read scenario file: {exc.strerror or exc}") from None
    if len(raw) > MAX_SCENARIO_BYTES:
        raise ScenarioError(f"{p}: scenario file larger than {MAX_SCENARIO_BYTES} bytes")
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{p}: not a UTF-8 text file (byte offset {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from None
    return scenario_from_dict(data, str(p))


def on_the_ground(scenario: Scenario) -> Scenario:
    """``scenario`` started as PX4 SITL boots: on the ground below its start point (z = 0, NED
    metres), disarmed, in the autopilot's ground start mode (PX4: POSCTL), so a companion arms
    and takes off (``mavsim --on-ground``)."""
    start = np.array([scenario.start_ned_m[0], scenario.start_ned_m[1], 0.0])
    sim = dataclasses.replace(scenario.sim, start_airborne=False, start_armed=False, start_mode=None)
    return dataclasses.replace(scenario, start_ned_m=start, sim=sim)


def default_scenario() -> Scenario:
    """A scenario with no obstacles, the vehicle on the ground at the origin."""
    return scenario_from_dict({"scenario": {"name": "default"}})
