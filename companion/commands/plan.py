"""``companion plan``: one trajectory optimisation with the obstacles' motion known.

This is the paper's single-obstacle evaluation (SPEC section 7, scenario 1): the
obstacles' trajectories are taken from the scenario file's ``[[world.obstacles]]`` (which
the flying companion never reads; here, offline, they stand in for perfect prediction),
the drone covariance is ``[sim] position_noise_cov_m2`` held over the horizon (as in the
paper) and each obstacle's is its ``measurement_cov_m2``. Static obstacles and walls come
from ``[map]``. The drone starts at ``[vehicle] start_ned_m`` at rest.
"""

from __future__ import annotations

import argparse
import json
import logging
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from companion.errors import ConfigError
from companion.core.planner import FORMULATIONS, Plan, Planner, PlanRequest
from companion.loop.config import load_scenario

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plan", help="one trajectory optimisation on a scenario file (obstacle motion known)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", help="scenario TOML file, e.g. configs/single_obstacle.toml")
    p.add_argument("--formulation", choices=FORMULATIONS, help="override [planner] formulation")
    p.add_argument("--json", action="store_true", help="print the plan as one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="draw the paper's figure (paths, contour of touch, goal distance)")
    p.set_defaults(func=run)


def _cov(value: Any, where: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3, 3):
        raise ConfigError(f"{where}: expected a 3x3 covariance, got {value!r}")
    return arr


def obstacle_path(obstacle: dict, times_s: np.ndarray, where: str) -> np.ndarray:
    """Positions (N, 3) of a scripted obstacle at ``times_s``: constant velocity or waypoints at a speed."""
    start = np.asarray(obstacle.get("start_ned_m", obstacle.get("waypoints_ned_m", [[np.nan] * 3])[0]), dtype=float)
    if start.shape != (3,) or not np.all(np.isfinite(start)):
        raise ConfigError(f"{where}: start_ned_m must be three numbers")
    if "velocity_ned_mps" in obstacle:
        return start + times_s[:, None] * np.asarray(obstacle["velocity_ned_mps"], dtype=float)
    if "waypoints_ned_m" in obstacle:
        speed = float(obstacle.get("speed_mps", 0.0))
        if speed <= 0.0:
            raise ConfigError(f"{where}: waypoints_ned_m needs a positive speed_mps")
        pts = np.vstack([start, np.asarray(obstacle["waypoints_ned_m"], dtype=float).reshape(-1, 3)])
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        s = np.minimum(speed * times_s, arc[-1])          # stops at the last waypoint
        return np.stack([np.interp(s, arc, pts[:, k]) for k in range(3)], axis=1)
    return np.broadcast_to(start, (times_s.size, 3)).copy()


def build_request(path: str | Path, formulation: str | None = None) -> tuple[Planner, PlanRequest, dict]:
    """Planner and request of ``companion plan`` for a scenario file (also used by tests)."""
    overrides = {"formulation": formulation} if formulation else {}
    scenario = load_scenario(path, **overrides)
    raw = tomllib.loads(Path(path).read_text())
    cfg = scenario.planner
    n, tau = cfg.horizon_steps, cfg.step_s
    times = tau * np.arange(1, n + 1)
    start = np.asarray(raw.get("vehicle", {}).get("start_ned_m", [0.0, 0.0, 0.0]), dtype=float)
    drone_cov = _cov(raw.get("sim", {}).get("position_noise_cov_m2", 0.02 * np.eye(3)), f"{path} [sim] position_noise_cov_m2")
    means, covs, radii, names = [], [], [], []
    for i, ob in enumerate(raw.get("world", {}).get("obstacles", [])):
        where = f"{path} [[world.obstacles]] #{i + 1}"
        means.append(obstacle_path(ob, times, where))
        covs.append(np.broadcast_to(_cov(ob.get("measurement_cov_m2", drone_cov), where), (n, 3, 3)))
        radii.append(float(ob.get("radius_m", 0.5)))
        names.append(str(ob.get("name", f"obstacle{i + 1}")))
    for i, st in enumerate(scenario.static_obstacles):
        means.append(np.broadcast_to(st.center, (n, 3)))
        covs.append(np.broadcast_to(st.covariance, (n, 3, 3)))
        radii.append(st.radius)
        names.append(f"static{i + 1}")
    req = PlanRequest(
        position=start, velocity=np.zeros(3), drone_covs=np.broadcast_to(drone_cov, (n, 3, 3)),
        target=scenario.mission.goal,
        obstacle_means=np.array(means).reshape(-1, n, 3), obstacle_covs=np.array(covs).reshape(-1, n, 3, 3),
        obstacle_radii=np.array(radii), walls_normal=scenario.walls_normal, walls_offset=scenario.walls_offset,
    )
    return Planner(cfg), req, {"names": names, "scenario": scenario.name}


def plan_to_json(planner: Planner, req: PlanRequest, plan: Plan, names: list[str]) -> dict:
    """The ``--json`` object (lists of floats; NED metres, seconds)."""
    cfg = planner.config
    return {
        "status": plan.status, "iterations": plan.iterations, "solve_time_s": plan.solve_time_s,
        "formulation": plan.formulation, "notes": list(plan.notes), "slack_max": plan.slack_max, "cost": plan.cost,
        "step_s": cfg.step_s, "start": req.position.tolist(), "target": req.target.tolist(),
        "positions": plan.positions.tolist(), "velocities": plan.velocities.tolist(),
        "commands": plan.commands.tolist(), "velocity_time_constant_s": cfg.velocity_time_constant_s,
        "drone_covariances": req.drone_covs.tolist(), "drone_radius": cfg.drone_radius_m,
        "obstacles": [{"name": nm, "means": req.obstacle_means[j].tolist(), "covariances": req.obstacle_covs[j].tolist(),
                       "radius": float(req.obstacle_radii[j])} for j, nm in enumerate(names)],
        "walls": [{"normal": a.tolist(), "offset": float(b)} for a, b in zip(req.walls_normal, req.walls_offset)],
        "c_min": cfg.c_min, "c_max": cfg.c_max,
        "contour_of_touch": plan.contour_of_touch.tolist(), "eta": plan.eta.tolist(), "overlap": plan.overlap.tolist(),
        "wall_margin": plan.wall_margin.tolist(),
    }


def run(args: argparse.Namespace) -> int:
    planner, req, info = build_request(args.scenario, args.formulation)
    plan = planner.solve(req)
    if args.plot:
        from companion.plots.plan_figure import plot_plan    # matplotlib only when asked

        plot_plan(args.plot, req, plan, planner.config, title=f"{info['scenario']} ({plan.formulation})")
    if args.json:
        print(json.dumps(plan_to_json(planner, req, plan, info["names"])))
    else:
        err = float(np.linalg.norm(plan.positions[-1] - req.target))
        print(f"{info['scenario']}: {plan.formulation} {plan.status} after {plan.iterations} SCP iterations "
              f"in {plan.solve_time_s * 1e3:.1f} ms; final distance to goal {err:.3f} m; "
              f"min contour of touch {plan.min_contour_of_touch:.4f} (c_min {planner.config.c_min})"
              + (f"; notes: {', '.join(plan.notes)}" if plan.notes else ""))
    return 0 if plan.status != "failed" else 1
