"""``companion plan``: one trajectory optimisation with the obstacles' motion known.

This is the paper's single-obstacle evaluation (docs/METHOD.md section 4, scenario 1): the
obstacles' trajectories are taken from the scenario file's ``[[world.obstacles]]`` (which
the flying companion never reads; here, offline, they stand in for perfect prediction) and
moved by mavsim's own motion model (``start_delay_s`` and ``loop`` included),
the drone covariance is ``[sim] position_noise_cov_m2`` held over the horizon (as in the
paper) and each obstacle's is its ``measurement_cov_m2``. Static obstacles and walls come
from ``[map]``. The drone starts at ``[vehicle] start_ned_m`` at rest.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from companion.commands._argtypes import scenario_file
from companion.commands._defaults import FORMULATIONS
from companion.commands._help import PlainRawDescriptionHelpFormatter

if TYPE_CHECKING:
    from companion.core.planner import Plan, Planner, PlanRequest

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plan", help="one trajectory optimisation on a scenario file (obstacle motion known)",
                              description=__doc__, formatter_class=PlainRawDescriptionHelpFormatter)
    p.add_argument("scenario", type=scenario_file,
                   help="scenario TOML file or a shipped scenario's name, e.g. single_obstacle")
    p.add_argument("--formulation", choices=FORMULATIONS, help="override [planner] formulation")
    p.add_argument("--json", action="store_true", help="print the plan as one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="draw the paper's figure (paths, contour of touch, goal distance)")
    p.set_defaults(func=run)


def build_request(path: str | Path, formulation: str | None = None) -> tuple[Planner, PlanRequest, dict]:
    """Planner and request of ``companion plan`` for a scenario file (also used by tests).

    Scripted obstacles move by mavsim's own model (:func:`companion.offline.scenario_file.scripted_obstacles`).
    """
    import numpy as np

    from companion.core.planner import Planner, PlanRequest
    from companion.offline.scenario_file import load_both, scripted_obstacles

    overrides = {"formulation": formulation} if formulation else {}
    scenario, sim = load_both(path, **overrides)
    cfg = scenario.planner
    n, tau = cfg.horizon_steps, cfg.step_s
    times = tau * np.arange(1, n + 1)
    drone_cov = sim.sim.position_noise_cov_m2
    means, covs, radii, names = [], [], [], []
    for ob in scripted_obstacles(sim, times):
        means.append(ob.means)
        covs.append(np.broadcast_to(ob.covariance, (n, 3, 3)))
        radii.append(ob.radius_m)
        names.append(ob.name)
    for i, st in enumerate(scenario.static_obstacles):
        means.append(np.broadcast_to(st.center, (n, 3)))
        covs.append(np.broadcast_to(st.covariance, (n, 3, 3)))
        radii.append(st.radius)
        names.append(f"static{i + 1}")
    req = PlanRequest(
        position=sim.start_ned_m, velocity=np.zeros(3), drone_covs=np.broadcast_to(drone_cov, (n, 3, 3)),
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
        import numpy as np

        err = float(np.linalg.norm(plan.positions[-1] - req.target))
        print(f"{info['scenario']}: {plan.formulation} {plan.status} after {plan.iterations} SCP iterations "
              f"in {plan.solve_time_s * 1e3:.1f} ms; final distance to goal {err:.3f} m; "
              f"min contour of touch {plan.min_contour_of_touch:.4f} (c_min {planner.config.c_min})"
              + (f"; notes: {', '.join(plan.notes)}" if plan.notes else ""))
    return 0 if plan.status != "failed" else 1
