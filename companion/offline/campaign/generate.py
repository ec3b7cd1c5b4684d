"""Randomised encounters: episode ``index`` of a campaign with ``seed``, as a scenario dict.

Reproducibility: episode ``i`` of a campaign with seed ``S`` is drawn from
``np.random.default_rng([S, i])`` and its simulator (and link-loss) seed from
``np.random.default_rng([S, i, 1])``, so any episode can be re-run by its index alone, on
any machine. The encounter is one complete scenario (the tables of a scenario TOML file)
that both ``mavsim`` and the companion read; the companion learns the obstacles only over
MAVLink.

Families (NED metres, seconds; the drone starts at ``[0, 0, -5]``):

``antipodal``
    The paper's scenario 2, randomised: a circle of radius 10-13 m, the drone flies to the
    antipodal point, 1-5 obstacles start on the circle (at least 45 deg from the drone)
    and fly through the centre (+-0.5 m) timed to arrive near when the drone does.
``crossing``
    1-5 obstacles cross a straight 20-28 m route at 30-150 deg, timed to meet the drone.
``corridor``
    A 6-8 m wide corridor (two walls along the route); leaders ahead flying slower in
    the same direction and oncoming obstacles.
``random``
    Obstacles from anywhere 8-16 m around the route's midpoint, aimed at a random point
    near the route, at 0.3-3 m/s.

Every family: obstacle radii 0.3-0.6 m (the companion assumes the largest, 0.6 m: MAVLink
carries no radius), drone radius 0.3-0.6 m, constant obstacle velocities (speed <= 3
m/s), measurement covariances and the drone's position noise drawn with random
eigenvalues, anisotropic and rotated in 60 % of draws; obstacles spawn at least 6 m from
the drone and apart from each other. Planner as in the antipodal scenario: N = 28,
tau = 0.3 s, accel 0.5 m/s^2, speed 3 m/s, sensing range 10 m.
"""

from __future__ import annotations

import functools
import logging
import math
from typing import Any, Callable

import numpy as np
from scipy.spatial.transform import Rotation

from companion.errors import InputError

logger = logging.getLogger(__name__)

FAMILIES = ("antipodal", "crossing", "corridor", "random")
METHODS = ("hyperplane", "paper", "deterministic", "bhattacharyya")

ALTITUDE_M = -5.0
RADIUS_RANGE_M = (0.3, 0.6)
SPEED_MAX_MPS = 3.0
SPAWN_CLEARANCE_M = 6.0          # obstacles start at least this far from the drone
MEAS_VAR_RANGE_M2 = (0.005, 0.06)  # eigenvalues of obstacle measurement covariances
DRONE_VAR_RANGE_M2 = (0.005, 0.04)  # eigenvalues of the drone's position noise
ANISOTROPIC_SHARE = 0.6
SENSING_RANGE_M = 10.0
#: Velocity lag of the simulated vehicle, which the planner models too, seconds.
VELOCITY_TIME_CONSTANT_S = 0.3
#: mavsim's vehicle profiles (``[sim] vehicle``) a campaign can fly.
VEHICLES = ("lag", "px4", "ardupilot")
#: For each mavsim vehicle profile but ``lag``, the shipped scenario whose ``[planner]
#: vehicle_response`` the planner uses against it: identified from a mavsim log by ``companion
#: identify`` (never copied from mavsim's settings), so the test world does not agree with the
#: planner by construction.
PROFILE_SCENARIOS = {"px4": "antipodal_px4sim.toml", "ardupilot": "antipodal_ardupilotsim.toml"}
#: The autopilot mavsim imitates (its personality, ``mavsim.personalities``) for each vehicle profile
#: that is not PX4's: the ArduPilot profile flies mavsim's ArduPilot personality, so the companion
#: engages it as it does ArduCopter (GUIDED, requested streams), not PX4's OFFBOARD.
PROFILE_AUTOPILOTS = {"ardupilot": "ardupilot"}
DEFAULT_DURATION_S = 40.0
#: Longest episode, simulated seconds: an encounter is over in a minute or two; a longer
#: one is a typo (``--duration 1e308``), and every run would fail or fly for hours.
MAX_DURATION_S = 3600.0
#: The honest noise model's correlation time, seconds (``--noise-correlation``): PX4's EKF2
#: position estimate follows GNSS at low frequency (the IMU only smooths it between fixes),
#: so its error wanders as a single-frequency receiver's does; measured autocorrelations of
#: such errors bend at about a minute (multipath, atmosphere, orbits). Obstacles that report
#: their own GNSS position (ADS-B, Remote ID, a swarm radio) have the same kind of error.
EKF_CORRELATION_S = 60.0
QUIET_STREAMS_HZ = {"ATTITUDE": 5.0, "GLOBAL_POSITION_INT": 5.0, "LOCAL_POSITION_NED": 5.0}
#: Time (s) the drone needs to take over before it moves (prestream + OFFBOARD), and its
#: typical cruise speed (m/s) toward a far waypoint; used only to time encounters.
ENGAGE_S, CRUISE_MPS = 3.2, 1.75


@functools.cache
def _profile_scenario(vehicle: str) -> dict:
    """The tables of ``vehicle``'s entry in :data:`PROFILE_SCENARIOS`, read once (callers copy what they hand out)."""
    import tomllib
    from importlib import resources

    text = resources.files("companion.scenarios").joinpath(PROFILE_SCENARIOS[vehicle]).read_text(encoding="utf-8")
    return tomllib.loads(text)


def profile_response(vehicle: str) -> dict[str, dict[str, float]]:
    """The planner's ``vehicle_response`` table for mavsim's profile ``vehicle`` (from :data:`PROFILE_SCENARIOS`)."""
    table = _profile_scenario(vehicle)["planner"]["vehicle_response"]
    return {name: dict(axis) for name, axis in table.items()}


def profile_response_state(vehicle: str) -> str | None:
    """Where the plans start the response's internal state against mavsim's profile ``vehicle``
    (``[companion] response_state`` of its :data:`PROFILE_SCENARIOS` entry); None for ``lag``."""
    if vehicle not in PROFILE_SCENARIOS:
        return None
    return str(_profile_scenario(vehicle).get("companion", {}).get("response_state", "steady"))


def profile_autopilot(vehicle: str) -> str | None:
    """The autopilot mavsim imitates against the vehicle profile ``vehicle`` (:data:`PROFILE_AUTOPILOTS`);
    None: mavsim's default (PX4)."""
    return PROFILE_AUTOPILOTS.get(vehicle)


def episode_rng(seed: int, index: int) -> np.random.Generator:
    """The generator that draws episode ``index`` of a campaign with ``seed``."""
    return np.random.default_rng([seed, index])


def episode_sim_seed(seed: int, index: int) -> int:
    """Simulator (and link-loss) seed of episode ``index``: derived from ``(seed, index)``."""
    return int(np.random.default_rng([seed, index, 1]).integers(0, 2**31 - 1))


def random_covariance(rng: np.random.Generator, lo: float, hi: float) -> np.ndarray:
    """A 3x3 SPD covariance (m^2): log-uniform eigenvalues in [lo, hi], randomly rotated
    (anisotropic) in ``ANISOTROPIC_SHARE`` of draws, else isotropic."""
    if rng.random() < ANISOTROPIC_SHARE:
        eig = np.exp(rng.uniform(math.log(lo), math.log(hi), 3))
        rot = Rotation.random(random_state=rng).as_matrix()
        cov = rot @ np.diag(eig) @ rot.T          # S = R diag(l) R'
    else:
        cov = math.exp(rng.uniform(math.log(lo), math.log(hi))) * np.eye(3)
    return 0.5 * (cov + cov.T)


def _horizontal(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle), 0.0])


def _drone_eta(distance_m: float) -> float:
    """Rough time (s after boot) for the drone to fly ``distance_m`` along its route."""
    return ENGAGE_S + distance_m / CRUISE_MPS


def _place(rng: np.random.Generator, draw: Callable[[], tuple[np.ndarray, np.ndarray]], radius: float,
           start: np.ndarray, placed: list[tuple[np.ndarray, float]], tries: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Redraw ``(start, velocity)`` until the body spawns >= 6 m from the drone and apart from the others."""
    for _ in range(tries):
        p0, v = draw()
        if np.linalg.norm(p0[:2] - start[:2]) < SPAWN_CLEARANCE_M:
            continue
        if any(np.linalg.norm(p0 - q) < radius + r + 0.5 for q, r in placed):
            continue
        return p0, v
    raise RuntimeError("could not place an obstacle after 200 draws (campaign geometry too tight)")


def generate_scenario(family: str, seed: int, index: int, *, c_min: float = 0.90,
                      duration_s: float = DEFAULT_DURATION_S, noise_correlation_s: float = 0.0,
                      vehicle: str = "lag") -> dict:
    """Draw episode ``index`` of a ``family`` campaign with ``seed`` as a scenario dict (TOML tables).

    The same ``(family, seed, index)`` always gives the same dict. The planner's
    ``formulation`` is left at ``hyperplane``; the campaign overrides it per method.
    ``noise_correlation_s`` > 0 makes mavsim's drone position error and every obstacle's
    measurement error Gauss-Markov processes with that correlation time (``mavsim.noise``;
    same covariances, reported as before: the honest noise model, see
    :data:`EKF_CORRELATION_S`); 0 keeps them white and the dict as it always was.
    ``vehicle`` is mavsim's profile: ``"lag"`` (the 0.3 s lag the planner models too) or
    ``"px4"`` (PX4's velocity loop; the planner gets the response identified for it, from
    :data:`PX4_PROFILE_SCENARIO`). The encounter drawn is the same for both.
    """
    if family not in FAMILIES:
        raise InputError(f"unknown campaign family {family!r} (known: {', '.join(FAMILIES)})")
    if vehicle not in VEHICLES:
        raise InputError(f"unknown vehicle profile {vehicle!r} (known: {', '.join(VEHICLES)})")
    rng = episode_rng(seed, index)
    start = np.array([0.0, 0.0, ALTITUDE_M])
    heading = rng.uniform(0.0, 2 * math.pi)
    u = _horizontal(heading)
    perp = np.array([-u[1], u[0], 0.0])
    drone_radius = rng.uniform(*RADIUS_RANGE_M)
    n_obs = int(rng.integers(1, 6))
    radii = rng.uniform(*RADIUS_RANGE_M, n_obs)
    placed: list[tuple[np.ndarray, float]] = []
    walls: list[dict] = []
    z_jitter = lambda: np.array([0.0, 0.0, rng.uniform(-0.25, 0.25)])  # noqa: E731

    if family == "antipodal":
        radius_c = rng.uniform(10.0, 13.0)
        centre = start + radius_c * u
        goal = start + 2 * radius_c * u
        spacing = 2 * radius_c

        def draw() -> tuple[np.ndarray, np.ndarray]:
            phi = heading + math.pi + rng.uniform(math.radians(45), math.radians(315))
            p0 = centre + radius_c * _horizontal(phi) + z_jitter()
            through = centre + rng.uniform(-0.5, 0.5) * np.cross(_horizontal(phi), [0.0, 0.0, 1.0])
            eta = _drone_eta(radius_c) + rng.uniform(-2.0, 2.0)
            d = through - p0
            d[2] = 0.0
            speed = float(np.clip(np.linalg.norm(d) / max(eta, 1.0), 0.8, 2.5))
            return p0, speed * d / np.linalg.norm(d)
    elif family == "crossing":
        length = rng.uniform(20.0, 28.0)
        goal = start + length * u
        spacing = min(length, 24.0)

        def draw() -> tuple[np.ndarray, np.ndarray]:
            s = rng.uniform(0.25, 0.75) * length
            cross = start + s * u
            angle = heading + rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(30), math.radians(150))
            speed = rng.uniform(0.5, 2.5)
            eta = max(_drone_eta(s) + rng.uniform(-1.5, 1.5), 2.0)
            d = _horizontal(angle)
            return cross - speed * eta * d + z_jitter(), speed * d
    elif family == "corridor":
        length = rng.uniform(20.0, 28.0)
        goal = start + length * u
        spacing = 8.0
        width = rng.uniform(6.0, 8.0)
        c = float(perp @ start)
        walls = [
            {"normal_ned": perp.tolist(), "offset_m": c + width / 2},
            {"normal_ned": (-perp).tolist(), "offset_m": -c + width / 2},
        ]
        r_max = RADIUS_RANGE_M[1]

        def draw() -> tuple[np.ndarray, np.ndarray]:
            lateral = rng.uniform(-1.0, 1.0) * (width / 2 - r_max - 0.8)
            if rng.random() < 0.4:   # leader: ahead, same direction, slower
                along, v = rng.uniform(7.0, 14.0), rng.uniform(0.5, 1.2) * u
            else:                    # oncoming
                along, v = rng.uniform(0.6 * length, length + 8.0), -rng.uniform(0.5, 1.5) * u
            return start + along * u + lateral * perp + z_jitter(), v
    else:  # random
        length = rng.uniform(18.0, 28.0)
        goal = start + length * u
        spacing = min(length, 24.0)
        mid = start + 0.5 * length * u

        def draw() -> tuple[np.ndarray, np.ndarray]:
            p0 = mid + rng.uniform(8.0, 16.0) * _horizontal(rng.uniform(0, 2 * math.pi)) + z_jitter()
            aim = start + rng.uniform(0.2, 0.8) * length * u + rng.normal(0.0, 1.5) * perp
            d = aim - p0
            d[2] = 0.0
            return p0, rng.uniform(0.3, SPEED_MAX_MPS) * d / np.linalg.norm(d)

    obstacles = []
    for k in range(n_obs):
        p0, v = _place(rng, draw, float(radii[k]), start, placed)
        placed.append((p0, float(radii[k])))
        obstacles.append({
            "name": f"obs{k + 1}",
            "radius_m": float(radii[k]),
            "start_ned_m": p0.tolist(),
            "velocity_ned_mps": v.tolist(),
            "measurement_cov_m2": random_covariance(rng, *MEAS_VAR_RANGE_M2).tolist(),
            "report_rate_hz": 10.0,
        })
    drone_noise = random_covariance(rng, *DRONE_VAR_RANGE_M2)
    vel_var = math.exp(rng.uniform(math.log(0.003), math.log(0.02)))

    data: dict[str, Any] = {
        "scenario": {
            "name": f"{family}-{seed}-{index}",
            "description": f"campaign {family}, seed {seed}, episode {index}: {n_obs} obstacle(s)",
            "duration_s": float(duration_s),
        },
        "vehicle": {"radius_m": float(drone_radius), "start_ned_m": start.tolist()},
        "mission": {"goal_ned_m": goal.tolist(), "goal_tolerance_m": 0.3, "waypoint_spacing_m": float(spacing)},
        "planner": {
            "formulation": "hyperplane",
            "horizon_steps": 28,
            "step_s": 0.3,
            "replan_period_s": 0.3,
            "c_min": float(c_min),
            "velocity_max_mps": [SPEED_MAX_MPS, SPEED_MAX_MPS, 1.0],
            "accel_max_mps2": [0.5, 0.5, 0.5],
            "velocity_time_constant_s": VELOCITY_TIME_CONSTANT_S,
            "sensing_range_m": SENSING_RANGE_M,
        },
        "estimator": {"drone": {"accel_noise_psd_m2ps3": 0.5}, "tracker": {"accel_noise_psd_m2ps3": 0.01}},
        "companion": {"setpoint_rate_hz": 20.0, "obstacle_radius_m": RADIUS_RANGE_M[1]},
        "sim": {
            "velocity_time_constant_s": VELOCITY_TIME_CONSTANT_S,
            "accel_max_mps2": 4.0,
            "position_noise_cov_m2": drone_noise.tolist(),
            "velocity_noise_cov_m2ps2": (vel_var * np.eye(3)).tolist(),
            # Streams the companion does not use, slowed as on a companion link's stream
            # profile (ODOMETRY, HEARTBEAT and status stay at PX4's rates): cuts parse cost.
            "stream_rates_hz": dict(QUIET_STREAMS_HZ),
        },
        "world": {"obstacles": obstacles},
    }
    if noise_correlation_s > 0.0:
        data["sim"]["position_noise_correlation_s"] = float(noise_correlation_s)
        for ob in obstacles:
            ob["measurement_correlation_s"] = float(noise_correlation_s)
        # the companion is configured for its sources, as an operator would for GNSS-positioned traffic
        data.setdefault("estimator", {}).setdefault("tracker", {})["report_correlation_s"] = float(noise_correlation_s)
    if vehicle in PROFILE_SCENARIOS:
        del data["planner"]["velocity_time_constant_s"], data["sim"]["velocity_time_constant_s"]
        del data["sim"]["accel_max_mps2"]
        data["sim"]["vehicle"] = vehicle
        data["planner"]["vehicle_response"] = profile_response(vehicle)
        data["companion"]["response_state"] = profile_response_state(vehicle)
    if walls:
        data["map"] = {"walls": walls}
    return data
