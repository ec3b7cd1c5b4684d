"""The planner's QP backends side by side: OSQP (the default) and PIQP (``[planner] solver``).

Issue 40's must-show for ``make bench``: the replan's median and p99 with each backend in
one run (ratio to OSQP), the replan over the backend's own solve time, and the price of a
PIQP iteration in the work budget's units.

- **Planner benchmark scenes** (``bench_planner``: N = 40, three obstacles, two walls,
  ``hyperplane``; 8 scenes of 60 replans, the warm ones counted): the backends take turns
  scene by scene, each flying its own receding horizon.
- **Corridor** (``configs/corridor.toml``, ``c_max``, lockstep, seed 0): the hard QPs and
  the least-violation path, one flight per backend.
- **Work unit**: over the replans of both sets, the wall time of a replan fitted by least
  squares as ``a + b * QPs + c * solver iterations`` per backend; ``c_piqp / c_osqp`` is
  what one PIQP iteration costs in ADMM iterations on this machine, beside the constant
  the budget charges (:data:`companion.core.planner.piqp_qp.WORK_PER_ITERATION`).

Wall clock on a shared 2-core machine: only the ratios measured in the same run carry over.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from companion.core.planner import Planner, budget, osqp_qp, piqp_qp, scp
from tests.benchmarks import bench_planner as bp
from tests.benchmarks.solver_clock import SolverClock

ROOT = Path(__file__).resolve().parents[2]
BACKENDS = ("osqp", "piqp")
CORRIDOR_SEEDS = (0, 1, 2)


#: PIQP's iterations of every QP solved in this process's benchmark (for the work unit's note).
PIQP_ITERATIONS: list[int] = []
_CLASSES = (osqp_qp.OsqpQp, piqp_qp.PiqpQp)


def _scene(solver: str, index: int) -> tuple[list[float], list[float], list]:
    """Warm replans of benchmark scene ``index`` with ``solver``: wall times, own solve times (s), plans."""
    planner = Planner(dataclasses.replace(bp.config("hyperplane"), solver=solver))
    obstacles = bp.scene(index)
    position, velocity = np.array([0.0, 0.0, -5.0]), np.zeros(3)
    planner.solve(bp.request(0.0, position, velocity, obstacles))       # set-up for this shape (not timed)
    times, own, plans, previous = [], [], [], None
    for k in range(bp.REPLANS):
        req = bp.request(k * bp.TAU, position, velocity, obstacles)
        with SolverClock(_CLASSES) as clock:
            t0 = time.perf_counter()
            plan = planner.solve(req, warm_start=previous)
            dt = time.perf_counter() - t0
        PIQP_ITERATIONS.extend(clock.iterations[piqp_qp.PiqpQp])
        if previous is not None:
            times.append(dt)
            own.append(clock.total_s)
            plans.append(plan)
        previous = plan
        position, velocity = plan.positions[0].copy(), plan.velocities[0].copy()
    return times, own, plans


def _corridor(solver: str, seed: int) -> tuple[list[float], list, dict]:
    """Replan wall times (s) and plans of one lockstep corridor flight with ``solver``, and its summary."""
    from companion.offline.harness import run_lockstep
    times, plans = [], []
    solve = scp.Planner.solve

    def timed(self, request, warm_start=None):
        t0 = time.perf_counter()
        plan = solve(self, request, warm_start)
        times.append(time.perf_counter() - t0)
        plans.append(plan)
        return plan

    scp.Planner.solve = timed
    try:
        with SolverClock(_CLASSES) as clock:
            result = run_lockstep(ROOT / "configs" / "corridor.toml", seed=seed, solver=solver)
        PIQP_ITERATIONS.extend(clock.iterations[piqp_qp.PiqpQp])
    finally:
        scp.Planner.solve = solve
    return times, plans, result.summary()


def _unit_cost(times: list[float], plans: list, unit: int) -> float:
    """Seconds per solver iteration: least squares of replan time on (1, QPs, iterations)."""
    iters = np.array([p.admm_iterations for p in plans], dtype=float)
    qps = (np.array([p.work for p in plans], dtype=float) - unit * iters) / budget.QP_SOLVE_WORK
    design = np.column_stack([np.ones_like(iters), qps, iters])
    coef, *_ = np.linalg.lstsq(design, np.asarray(times), rcond=None)
    return float(coef[2])


def _stats(times) -> tuple[float, float, float]:
    t = np.asarray(times) * 1e3
    return float(np.median(t)), float(np.percentile(t, 99)), float(t.max())


def run() -> list[dict]:
    rows: list[dict] = []
    bench = {s: ([], [], []) for s in BACKENDS}
    for index in range(bp.SCENES):          # the backends take turns scene by scene
        for solver in BACKENDS:
            times, own, plans = _scene(solver, index)
            for store, new in zip(bench[solver], (times, own, plans)):
                store.extend(new)
    corridor = {s: ([], [], []) for s in BACKENDS}
    for seed in CORRIDOR_SEEDS:
        for solver in BACKENDS:
            times, plans, summary = _corridor(solver, seed)
            corridor[solver][0].extend(times)
            corridor[solver][1].extend(plans)
            corridor[solver][2].append(summary)
    base = {name: _stats(sets[s][0]) for name, sets, s in (("bench", bench, "osqp"), ("corridor", corridor, "osqp"))}
    for solver in BACKENDS:
        times, own, plans = bench[solver]
        med, p99, largest = _stats(times)
        statuses = {k: sum(p.status == k for p in plans) for k in ("optimal", "slack", "failed")}
        rows.append({"name": f"benchmark replan median, {solver}", "value": med, "unit": "ms",
                     "peer": f"osqp {base['bench'][0]:.2f} ms", "ratio": med / base["bench"][0],
                     "note": f"{len(times)} warm replans, 8 scenes; largest {largest:.2f} ms; statuses {statuses}; "
                             f"min planned contour {min(p.min_contour_of_touch for p in plans):.4f}"})
        rows.append({"name": f"benchmark replan p99, {solver}", "value": p99, "unit": "ms",
                     "peer": f"osqp {base['bench'][1]:.2f} ms", "ratio": p99 / base["bench"][1], "target": 1.5})
        own_ratio = float(np.sum(times) / np.sum(own))
        rows.append({"name": f"benchmark replan / own solve time, {solver}", "value": own_ratio, "unit": "x",
                     "target": 1.5, "note": "sums over the warm replans; the backend's solve calls only"})
        ctimes, cplans, summaries = corridor[solver]
        cmed, cp99, clargest = _stats(ctimes)
        bound = sum(any(n.startswith("work_budget") for n in p.notes) for p in cplans)
        rows.append({"name": f"corridor replan median, {solver}", "value": cmed, "unit": "ms",
                     "peer": f"osqp {base['corridor'][0]:.2f} ms", "ratio": cmed / base["corridor"][0],
                     "note": f"{len(ctimes)} replans, seed(s) {', '.join(map(str, CORRIDOR_SEEDS))}; largest "
                             f"{clargest:.1f} ms; budget bound {bound}; goal "
                             f"{sum(bool(s.get('goal_reached')) for s in summaries)} of {len(summaries)}; "
                             f"collisions {sum(int(s.get('collisions') or 0) for s in summaries)}"})
        rows.append({"name": f"corridor replan p99, {solver}", "value": cp99, "unit": "ms",
                     "peer": f"osqp {base['corridor'][1]:.1f} ms", "ratio": cp99 / base["corridor"][1]})
    cost = {}
    for solver in BACKENDS:
        unit = 1 if solver == "osqp" else piqp_qp.WORK_PER_ITERATION
        cost[solver] = _unit_cost(bench[solver][0] + corridor[solver][0], bench[solver][2] + corridor[solver][1], unit)
    measured = cost["piqp"] / cost["osqp"]
    rows.append({"name": "PIQP iteration in ADMM iterations (fitted)", "value": measured, "unit": "x",
                 "peer": f"budget charges {piqp_qp.WORK_PER_ITERATION}", "ratio": measured / piqp_qp.WORK_PER_ITERATION,
                 "note": f"replan time ~ a + b QPs + c iterations per backend: OSQP {1e6 * cost['osqp']:.1f} us, "
                         f"PIQP {1e6 * cost['piqp']:.1f} us an iteration; PIQP iterations a QP: median "
                         f"{np.median(PIQP_ITERATIONS):.0f}, largest {max(PIQP_ITERATIONS)} of {len(PIQP_ITERATIONS)} QPs"})
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
