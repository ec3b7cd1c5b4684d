"""Monte Carlo safety campaign: randomised encounters flown in lockstep, per planner method.

Does the chance constraint keep its promise? Under the constraint the probability of a
collision with one obstacle at one step is at most ``Phi(-r_min)`` (SPEC section 2,
``r_min = sqrt(chi2_3.ppf(c_min))``). A campaign draws encounters from a seed, flies each
one with every method (``hyperplane``, ``paper``, ``deterministic``, ``bhattacharyya``)
through the real MAVLink path (:func:`companion.offline.harness.run_lockstep`) and counts what
the simulator's truth says happened.

Reproducibility: episode ``i`` of a campaign with seed ``S`` is drawn from
``np.random.default_rng([S, i])`` and its simulator (and link-loss) seed from
``np.random.default_rng([S, i, 1])``, so any episode can be re-run by its index alone.
The encounter is written as one complete scenario TOML that both ``mavsim`` and the
companion read; the companion learns the obstacles only over MAVLink.

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

import hashlib
import logging
import math
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import beta, chi2, norm

from companion.errors import InputError
from companion.offline.harness import run_lockstep  # imports mavsim (the harness exception of the dependency rule)
from companion.core.overlap import touch_radius

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
DEFAULT_DURATION_S = 40.0
STOP_AFTER_GOAL_S = 0.5
#: (step, obstacle) pairs whose realised contour of touch is below this are *near*: the
#: collision constraint is close to active there (far pairs sit at c = 1.0).
ACTIVE_CONTOUR = 0.99
#: chi2_3 95 % quantile: a consistent filter's NEES exceeds it in 5 % of steps.
NEES_95 = 7.814727903251178
QUIET_STREAMS_HZ = {"ATTITUDE": 5.0, "GLOBAL_POSITION_INT": 5.0, "LOCAL_POSITION_NED": 5.0}
#: Time (s) the drone needs to take over before it moves (prestream + OFFBOARD), and its
#: typical cruise speed (m/s) toward a far waypoint; used only to time encounters.
ENGAGE_S, CRUISE_MPS = 3.2, 1.75


# --------------------------------------------------------------------------- TOML writer


def _toml_value(v: Any, where: str) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            raise InputError(f"TOML writer: {where} is not finite ({v!r})")
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x, where) for x in v) + "]"
    raise InputError(f"TOML writer: {where} has unsupported type {type(v).__name__}")


def to_toml(data: dict) -> str:
    """Serialise the subset of TOML scenarios use: tables, arrays of tables, scalars, nested lists.

    A list of dicts becomes an array of tables (``[[a.b]]``); a dict becomes a table.
    Plain keys in a table come before its sub-tables, as TOML requires.
    """
    lines: list[str] = []

    def emit(table: dict, prefix: str, header: str | None) -> None:
        plain = {k: v for k, v in table.items() if not _is_table(v) and not _is_table_array(v)}
        if header is not None and (plain or not any(_is_table(v) or _is_table_array(v) for v in table.values())):
            lines.append(header)
            for k, v in plain.items():
                lines.append(f"{k} = {_toml_value(v, prefix + k)}")
            lines.append("")
        elif plain:  # top-level keys (no header)
            lines.extend(f"{k} = {_toml_value(v, prefix + k)}" for k, v in plain.items())
            lines.append("")
        for k, v in table.items():
            name = prefix + k
            if _is_table(v):
                emit(v, name + ".", f"[{name}]")
            elif _is_table_array(v):
                for item in v:
                    emit(item, name + ".", f"[[{name}]]")

    emit(data, "", None)
    return "\n".join(lines).rstrip() + "\n"


def _is_table(v: Any) -> bool:
    return isinstance(v, dict)


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, dict) for x in v)


# --------------------------------------------------------------------------- episodes


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
                      duration_s: float = DEFAULT_DURATION_S) -> dict:
    """Draw episode ``index`` of a ``family`` campaign with ``seed`` as a scenario dict (TOML tables).

    The same ``(family, seed, index)`` always gives the same dict. The planner's
    ``formulation`` is left at ``hyperplane``; the campaign overrides it per method.
    """
    if family not in FAMILIES:
        raise InputError(f"unknown campaign family {family!r} (known: {', '.join(FAMILIES)})")
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
    if walls:
        data["map"] = {"walls": walls}
    return data


def write_scenario(data: dict, path: str | Path) -> Path:
    """Write a scenario dict as TOML; returns the path."""
    path = Path(path)
    path.write_text(to_toml(data))
    return path


# --------------------------------------------------------------------------- one run


@dataclass(frozen=True)
class EpisodeTask:
    """One (episode, method) run of a campaign; picklable for the process pool."""

    family: str
    seed: int
    index: int
    method: str
    c_min: float = 0.90
    duration_s: float = DEFAULT_DURATION_S


def run_episode(task: EpisodeTask, *, keep_records: bool = False) -> dict:
    """Generate, fly and score one episode with one method; never raises (errors are reported).

    Returns a JSON-serialisable dict (plus ``solve_times_s``, a list, for pooling).
    With ``keep_records`` the :class:`~companion.offline.harness.RunResult` is returned under ``"run"``.
    """
    base = {"episode": task.index, "method": task.method, "family": task.family, "seed": task.seed,
            "sim_seed": episode_sim_seed(task.seed, task.index)}
    t0 = time.perf_counter()
    try:
        data = generate_scenario(task.family, task.seed, task.index, c_min=task.c_min, duration_s=task.duration_s)
        with tempfile.TemporaryDirectory(prefix="campaign-") as tmp:
            path = write_scenario(data, Path(tmp) / f"{data['scenario']['name']}.toml")
            run = run_lockstep(path, seed=base["sim_seed"], stop_after_goal_s=STOP_AFTER_GOAL_S, formulation=task.method)
        out = {**base, **score_run(run, data), "wall_time_s": time.perf_counter() - t0}
        if keep_records:
            out["run"] = run
        return out
    except Exception as exc:  # one bad episode must not end a campaign of hundreds
        logger.exception("episode %d method %s failed", task.index, task.method)
        return {**base, "error": f"{type(exc).__name__}: {exc}", "wall_time_s": time.perf_counter() - t0}


def score_run(run: Any, data: dict) -> dict:
    """Per-episode metrics from a :class:`~companion.offline.harness.RunResult` and its scenario dict.

    Steps are replans on the ``replan_period_s`` grid (after a failed plan the companion
    replans at every setpoint tick; those extra replans are not counted twice). An
    obstacle is *in range* at a step when its true centre distance is within sensing
    range; a *step collision* is an in-range obstacle whose true distance is below the
    sum of the physical radii. The realised contour of touch (from the estimates,
    ``ReplanRecord.realised_contour``) is counted for tracked obstacles within range.
    """
    truth = run.truth
    comp = run.companion
    records = comp.records
    replan_truth = run.extra["replan_truth"]
    if len(replan_truth) != len(records):
        raise RuntimeError(f"truth at replans ({len(replan_truth)}) does not match replans ({len(records)})")
    planner = data["planner"]
    period, c_min, sensing = planner["replan_period_s"], planner["c_min"], planner["sensing_range_m"]
    step = planner.get("step_s", period)
    obstacles = data["world"]["obstacles"]
    names = [o["name"] for o in obstacles]
    radius_sum = data["vehicle"]["radius_m"] + np.array([o["radius_m"] for o in obstacles])

    sysid_base = data["world"].get("obstacle_sysid_base", 101)
    steps = pair_steps = pair_hits = contour_pairs = contour_below = steps_below = 0
    active_pairs = active_hits = 0
    bound_sum = 0.0
    min_contour = math.inf
    drone_nees: list[float] = []
    rel_nees: list[float] = []
    model_err: list[float] = []
    prev = None  # (t, true drone position, planned displacement over the first step)
    last_t = -math.inf
    for rec, (_, p_true, obs_true) in zip(records, replan_truth):
        if rec.t_link_s < last_t + period - 1e-6:
            continue
        if prev is not None and abs(rec.t_link_s - prev[0] - step) < 1e-6:
            # model mismatch: true displacement over one step against the planner's tau * V_1
            model_err.append(float(np.linalg.norm((p_true - prev[1]) - prev[2])))
        prev = (rec.t_link_s, p_true, None if rec.status == "failed" else rec.plan_positions[0] - rec.drone_position)
        if prev[2] is None:
            prev = None
        last_t = rec.t_link_s
        steps += 1
        e = rec.drone_position - p_true
        drone_nees.append(float(e @ np.linalg.solve(rec.drone_cov, e)))   # e' S^-1 e ~ chi2_3 if consistent
        if names:
            d = np.linalg.norm(np.array([obs_true[n] for n in names]) - p_true, axis=1)
            in_range = d <= sensing
            pair_steps += int(in_range.sum())
            pair_hits += int((in_range & (d < radius_sum)).sum())
        below_here = False
        for key, ct in rec.realised_contour.items():
            rel_est = rec.obstacle_positions[key] - rec.drone_position
            if np.linalg.norm(rel_est) > sensing:
                continue
            contour_pairs += 1
            min_contour = min(min_contour, ct)
            # Phi(-r) with r = sqrt(chi2_3.ppf(c)): 1/2 for c = 0 (ellipsoids overlap), 0 for c = 1
            bound_sum += float(norm.cdf(-math.sqrt(chi2.ppf(min(max(ct, 0.0), 1.0), 3))))
            if ct < c_min:
                contour_below += 1
                below_here = True
            j = key[0] - sysid_base
            if 0 <= j < len(names):
                rel_true = obs_true[names[j]] - p_true
                err = rel_est - rel_true
                rel_nees.append(float(err @ np.linalg.solve(rec.drone_cov + rec.obstacle_covs[key], err)))
                if ct < ACTIVE_CONTOUR:
                    active_pairs += 1
                    active_hits += int(np.linalg.norm(rel_true) < radius_sum[j])
        steps_below += below_here
    statuses = [r.status for r in records]
    commands = np.array([r.command for r in records]).reshape(-1, 3)
    obstacle_collisions = [c for c in truth.get("collisions", []) if c.get("kind") == "obstacle"]
    # continuous-time view of the same quantity: seconds in contact (truth checks every physics step)
    contact_s = sum((c["t_end_s"] if c.get("t_end_s") is not None else run.sim_time_s) - c["t_start_s"]
                    for c in obstacle_collisions)
    return {
        "n_obstacles": len(names),
        "collided": bool(truth.get("collided")),
        "obstacle_collision": bool(obstacle_collisions),
        "collisions": len(truth.get("collisions", [])),
        "min_true_clearance_m": min((v for v in truth.get("min_clearance_m", {}).values() if v is not None), default=None),
        "goal_reached": bool(truth.get("goal_reached")),
        "time_to_goal_s": truth.get("time_to_goal_s"),
        "steps": steps,
        "pair_steps_in_range": pair_steps,
        "pair_step_collisions": pair_hits,
        "pair_time_in_range_s": pair_steps * period,
        "contact_time_s": float(contact_s),
        "contour_pairs": contour_pairs,
        "contour_pairs_below_c_min": contour_below,
        "steps_below_c_min": steps_below,
        "min_realised_contour": None if not math.isfinite(min_contour) else float(min_contour),
        "active_pairs": active_pairs,
        "active_pair_collisions": active_hits,
        "predicted_collisions_bound": bound_sum,
        "drone_nees": drone_nees,
        "relative_nees": rel_nees,
        "model_step_error_m": model_err,
        "replans": len(records),
        "failed_plans": statuses.count("failed"),
        "slack_plans": statuses.count("slack"),
        "slack_max": max((r.slack_max for r in records if r.status != "failed"), default=0.0),  # failed: inf
        "solve_times_s": [float(r.solve_time_s) for r in records],
        "sim_time_s": float(run.sim_time_s),
        "commands_sha256": hashlib.sha256(np.ascontiguousarray(commands).tobytes()).hexdigest(),
        "truth": {k: truth[k] for k in ("collided", "collisions", "min_distance_m", "goal_reached",
                                        "time_to_goal_s", "path_length_m") if k in truth},
    }


# --------------------------------------------------------------------------- statistics


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) two-sided interval for a binomial proportion ``k / n``.

    ``lower = Beta(a/2; k, n-k+1)``, ``upper = Beta(1-a/2; k+1, n-k)`` with ``a = 1 - confidence``;
    ``lower = 0`` when ``k = 0`` and ``upper = 1`` when ``k = n``.
    """
    if n < 0 or not 0 <= k <= n:
        raise InputError(f"clopper_pearson needs 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 0.0, 1.0
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def collision_bound(c_min: float, dim: int = 3) -> float:
    """Per-step, per-obstacle collision bound ``Phi(-r_min)`` of SPEC section 2."""
    return float(norm.cdf(-float(touch_radius(c_min, dim))))


def summarise(results: list[dict], methods: tuple[str, ...] | list[str], c_min: float) -> dict:
    """Aggregate per-episode results into one summary per method (JSON-serialisable)."""
    bound = collision_bound(c_min)
    out = {}
    for m in methods:
        rows = [r for r in results if r["method"] == m and "error" not in r]
        errors = sum(1 for r in results if r["method"] == m and "error" in r)
        n = len(rows)
        k = sum(r["collided"] for r in rows)
        k_obs = sum(r["obstacle_collision"] for r in rows)
        pair_steps = sum(r["pair_steps_in_range"] for r in rows)
        pair_hits = sum(r["pair_step_collisions"] for r in rows)
        contour_pairs = sum(r["contour_pairs"] for r in rows)
        steps = sum(r["steps"] for r in rows)
        solve = np.array([t for r in rows for t in r["solve_times_s"]])
        d_nees = np.array([x for r in rows for x in r["drone_nees"]])
        r_nees = np.array([x for r in rows for x in r["relative_nees"]])
        model_err = np.array([x for r in rows for x in r["model_step_error_m"]])
        active = sum(r["active_pairs"] for r in rows)
        active_hits = sum(r["active_pair_collisions"] for r in rows)
        ttg = [r["time_to_goal_s"] for r in rows if r["goal_reached"] and r["time_to_goal_s"] is not None]
        replans = sum(r["replans"] for r in rows)
        out[m] = {
            "episodes": n,
            "errors": errors,
            "collisions": k,
            "collision_rate": k / n if n else None,
            "collision_ci95": clopper_pearson(k, n),
            "obstacle_collisions": k_obs,
            "pair_steps_in_range": pair_steps,
            "pair_step_collisions": pair_hits,
            "pair_step_frequency": pair_hits / pair_steps if pair_steps else None,
            "pair_step_ci95": clopper_pearson(pair_hits, pair_steps),
            "bound_phi_minus_r_min": bound,
            "contact_time_s": sum(r["contact_time_s"] for r in rows),
            "contact_time_share": (sum(r["contact_time_s"] for r in rows) / pair_time) if (pair_time := sum(r["pair_time_in_range_s"] for r in rows)) else None,
            "active_pairs": active,
            "active_pair_collisions": active_hits,
            "active_pair_frequency": active_hits / active if active else None,
            "active_pair_ci95": clopper_pearson(active_hits, active),
            "predicted_collisions_bound": sum(r["predicted_collisions_bound"] for r in rows),
            "drone_nees_mean": float(d_nees.mean()) if d_nees.size else None,
            "drone_nees_share_above_chi2_95": float((d_nees > NEES_95).mean()) if d_nees.size else None,
            "relative_nees_mean": float(r_nees.mean()) if r_nees.size else None,
            "relative_nees_share_above_chi2_95": float((r_nees > NEES_95).mean()) if r_nees.size else None,
            "model_step_error_median_m": float(np.median(model_err)) if model_err.size else None,
            "model_step_error_p95_m": float(np.percentile(model_err, 95)) if model_err.size else None,
            "model_step_error_max_m": float(model_err.max()) if model_err.size else None,
            "contour_pairs": contour_pairs,
            "share_pairs_below_c_min": sum(r["contour_pairs_below_c_min"] for r in rows) / contour_pairs if contour_pairs else None,
            "steps": steps,
            "share_steps_below_c_min": sum(r["steps_below_c_min"] for r in rows) / steps if steps else None,
            "goal_reached": sum(r["goal_reached"] for r in rows),
            "goal_rate": sum(r["goal_reached"] for r in rows) / n if n else None,
            "time_to_goal_median_s": float(np.median(ttg)) if ttg else None,
            "time_to_goal_mean_s": float(np.mean(ttg)) if ttg else None,
            "replans": replans,
            "failed_plans": sum(r["failed_plans"] for r in rows),
            "failed_share": sum(r["failed_plans"] for r in rows) / replans if replans else None,
            "episodes_with_failure": sum(r["failed_plans"] > 0 for r in rows),
            "slack_plans": sum(r["slack_plans"] for r in rows),
            "episodes_with_slack": sum(r["slack_plans"] > 0 for r in rows),
            "slack_max": max((r["slack_max"] for r in rows), default=0.0),
            "solve_time_median_ms": float(np.median(solve) * 1e3) if solve.size else None,
            "solve_time_p99_ms": float(np.percentile(solve, 99) * 1e3) if solve.size else None,
            "min_realised_contour": [r["min_realised_contour"] for r in rows],
        }
    return out


# --------------------------------------------------------------------------- campaign


def _finite(obj: Any) -> Any:
    """``obj`` with non-finite floats replaced by ``None`` (strict JSON has no inf or NaN)."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


#: Per-step lists in an episode row, pooled into the summary and left out of the JSON rows.
_POOLED_KEYS = ("solve_times_s", "drone_nees", "relative_nees", "model_step_error_m", "run")


@dataclass(frozen=True)
class CampaignResult:
    """Everything a campaign measured: per-episode rows and per-method summaries."""

    family: str
    seed: int
    episodes: tuple[int, ...]
    methods: tuple[str, ...]
    c_min: float
    duration_s: float
    results: list
    summary: dict
    wall_time_s: float
    workers: int

    def to_json(self) -> dict:
        """JSON-serialisable form (per-episode solve times are pooled into the summary)."""
        rows = [{k: v for k, v in r.items() if k not in _POOLED_KEYS} for r in self.results]
        return _finite({
            "family": self.family, "seed": self.seed, "episodes": list(self.episodes),
            "methods": list(self.methods), "c_min": self.c_min, "duration_s": self.duration_s,
            "r_min": float(touch_radius(self.c_min, 3)), "bound_phi_minus_r_min": collision_bound(self.c_min),
            "workers": self.workers, "wall_time_s": self.wall_time_s, "cpu_count": os.cpu_count(),
            "summary": self.summary, "results": rows,
        })

    def plot(self, directory: str | Path) -> list[Path]:
        """Draw the campaign figures into ``directory`` (see :mod:`companion.plots.campaign_figures`)."""
        from companion.plots.campaign_figures import plot_campaign

        return plot_campaign(self.summary, directory, c_min=self.c_min, title=f"{self.family} campaign, seed {self.seed}")


def run_campaign(family: str, episodes: list[int] | range, methods: list[str] | tuple[str, ...], seed: int, *,
                 workers: int | None = None, c_min: float = 0.90, duration_s: float = DEFAULT_DURATION_S,
                 progress: bool | None = None) -> CampaignResult:
    """Fly ``episodes`` (indices) of a ``family`` campaign with every method; in parallel over ``workers``.

    ``progress`` (default: stderr is a terminal) prints a one-line counter to stderr.
    """
    if family not in FAMILIES:
        raise InputError(f"unknown campaign family {family!r} (known: {', '.join(FAMILIES)})")
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise InputError(f"unknown method(s) {', '.join(unknown) or '(none given)'} (known: {', '.join(METHODS)})")
    workers = workers or os.cpu_count() or 1
    progress = sys.stderr.isatty() if progress is None else progress
    tasks = [EpisodeTask(family, seed, i, m, c_min, duration_s) for i in episodes for m in methods]
    t0 = time.perf_counter()
    results: list[dict] = []

    def tick() -> None:
        if progress:
            bad = sum(1 for r in results if r.get("collided"))
            sys.stderr.write(f"\rcampaign {family}: {len(results)}/{len(tasks)} runs, "
                             f"{bad} with collision, {time.perf_counter() - t0:.0f} s ")
            sys.stderr.flush()

    if workers == 1:
        for task in tasks:
            results.append(run_episode(task))
            tick()
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(run_episode, task) for task in tasks]
            for fut in as_completed(futures):
                results.append(fut.result())
                tick()
    if progress:
        sys.stderr.write("\n")
    order = {m: j for j, m in enumerate(methods)}
    results.sort(key=lambda r: (r["episode"], order[r["method"]]))
    return CampaignResult(family, seed, tuple(episodes), tuple(methods), c_min, duration_s, results,
                          summarise(results, methods, c_min), time.perf_counter() - t0, workers)


def _fmt(x: Any, spec: str) -> str:
    if x is None:
        width = "".join(ch for ch in spec.split(".")[0] if ch.isdigit())
        return format("-", f">{width}") if width else "-"
    return format(x, spec)


def format_table(result: CampaignResult) -> str:
    """The terminal table: one row per method."""
    bound = collision_bound(result.c_min)
    head = (f"{'method':<14}{'eps':>5}{'coll':>5}  {'rate [95% CI]':<22}{'step freq [95% CI]':<28}"
            f"{'<c_min':>8}{'goal':>7}{'t_goal':>8}{'failed':>8}{'slack':>7}{'solve med/p99 ms':>18}")
    lines = [f"campaign {result.family}, seed {result.seed}, {len(result.episodes)} episodes, c_min = {result.c_min:.2f}: "
             f"bound Phi(-r_min) = {bound:.4g} per step and obstacle (r_min = {float(touch_radius(result.c_min, 3)):.4f})",
             head, "-" * len(head)]
    for m, s in result.summary.items():
        lo, hi = s["collision_ci95"]
        plo, phi = s["pair_step_ci95"]
        rate = f"{_fmt(s['collision_rate'], '.3f')} [{lo:.3f}, {hi:.3f}]"
        step = f"{_fmt(s['pair_step_frequency'], '.2e')} [{plo:.1e}, {phi:.1e}]"
        lines.append(
            f"{m:<14}{s['episodes']:>5}{s['collisions']:>5}  {rate:<22}{step:<28}"
            f"{_fmt(s['share_pairs_below_c_min'], '8.4f')}{_fmt(s['goal_rate'], '7.3f')}{_fmt(s['time_to_goal_median_s'], '8.1f')}"
            f"{_fmt(s['failed_share'], '8.4f')}{s['episodes_with_slack']:>7}"
            f"{_fmt(s['solve_time_median_ms'], '9.1f')}/{_fmt(s['solve_time_p99_ms'], '<8.1f')}"
        )
    lines.append("")
    lines.append(f"{'method':<14}{'near pairs':>11}{'hits':>6}  {'near freq [95% CI]':<28}{'E[coll] bound':>14}{'observed':>9}{'contact share':>14}"
                 f"{'NEES drone':>11}{'>95%':>7}{'NEES rel':>10}{'>95%':>7}{'step err med/p95 m':>20}")
    for m, s in result.summary.items():
        alo, ahi = s["active_pair_ci95"]
        near = f"{_fmt(s['active_pair_frequency'], '.2e')} [{alo:.1e}, {ahi:.1e}]"
        lines.append(
            f"{m:<14}{s['active_pairs']:>11}{s['active_pair_collisions']:>6}  {near:<28}{s['predicted_collisions_bound']:>14.2f}"
            f"{s['pair_step_collisions']:>9}{_fmt(s['contact_time_share'], '14.2e')}{_fmt(s['drone_nees_mean'], '11.2f')}{_fmt(s['drone_nees_share_above_chi2_95'], '7.3f')}"
            f"{_fmt(s['relative_nees_mean'], '10.2f')}{_fmt(s['relative_nees_share_above_chi2_95'], '7.3f')}"
            f"{_fmt(s['model_step_error_median_m'], '12.3f')}/{_fmt(s['model_step_error_p95_m'], '<7.3f')}"
        )
    lines.append(f"(near: (step, obstacle) pairs with realised contour < {ACTIVE_CONTOUR}; E[coll] bound: sum over pairs of "
                 f"Phi(-r(realised contour)); contact share: seconds in true contact per in-range obstacle-second; NEES: 3 and 5 % above the chi2_3 95 % quantile if the filters are consistent; "
                 f"step err: true displacement over one step minus tau * V_1)")
    lines.append(f"(step freq: true collisions per step and in-range obstacle; <c_min: share of in-range (step, obstacle) "
                 f"pairs whose realised contour of touch fell below c_min; failed: share of replans; slack: episodes "
                 f"with slack; {result.wall_time_s:.0f} s on {result.workers} worker(s))")
    errors = sum(s["errors"] for s in result.summary.values())
    if errors:
        lines.append(f"{errors} run(s) ended with an error (see the JSON file)")
    return "\n".join(lines)
