"""Whole replans with another QP solver in place of OSQP (issue 40, item 1: a first look).

    PYTHONPATH=$PWD python -m tests.benchmarks.qp_replan [--solvers piqp,piqp-update,qpalm,clarabel] [--scenes 8]

Flies the planner benchmark's scenes (:mod:`tests.benchmarks.bench_planner`: N = 40, three
obstacles, two walls, ``hyperplane``, 60 replans, receding horizon) once with the planner
as it is (OSQP) and once per candidate, the solvers taking turns scene by scene. A
candidate stands in for :class:`companion.core.planner.osqp_qp.OsqpQp` through a small
adapter of this module (the planner is not changed: the adapter replaces the class in
``qp_step`` for the run): it keeps the QP's data, and per solve builds the solver's input
and sets it up anew (:mod:`tests.benchmarks.qp_study`'s conversions; the split of
``l = u`` rows into equalities changes between the hard and the least-violation QPs), so
the times here include work an integrated backend would partly save (``piqp-update``
keeps one PIQP per pattern and only updates its data when the pattern repeats). Then the
corridor (``configs/corridor.toml``, ``--seeds``, default 3, ``c_max``) is flown in lockstep once per
backend and seed (``--lockstep ''`` skips it), every replan timed (``Planner.solve``). The adapter returns
no duals (zeros; only OSQP's next replan used them) and no iteration count, so the work
budget charges only its fixed 150 units per QP and never binds. The replans' plans differ
from OSQP's (other iterates within the tolerances): the statuses and the distance left to
the goal say whether they are as good.
"""

from __future__ import annotations

import argparse
import sys
import time

from pathlib import Path

import numpy as np
import scipy.sparse as sp

from companion.core.planner import qp_step
from companion.core.planner.osqp_qp import MAX_ITER, OsqpQp, QpSolution
from companion.core.planner.qp_record import RecordedQp
from tests.benchmarks import bench_planner, qp_study

ROOT = Path(__file__).resolve().parents[2]


def adapter(solver_cls: type) -> type:
    """A class with :class:`OsqpQp`'s interface that solves with ``solver_cls`` (a :class:`qp_study.Solver`)."""

    class Adapter:
        def __init__(self, layout, p_data, q, a_data, l, u, *, eps, eps_rel, polish, rho) -> None:  # noqa: ARG002
            self.layout = layout
            self._p = layout.p_matrix(np.array(p_data, dtype=float))
            self._a = layout.a_matrix_csc(np.array(a_data, dtype=float))
            self._p_full = sp.csr_matrix(self._p + sp.triu(self._p, k=1).T)
            self.q, self.l, self.u = np.array(q, dtype=float), np.array(l, dtype=float), np.array(u, dtype=float)
            self.eps, self.eps_rel = eps, eps_rel
            self.x_warm, self.y_warm = np.zeros(layout.n), np.zeros(layout.m)
            self.solver = solver_cls()

        def p_times(self, x):
            return self._p_full @ x

        def update(self, *, p_data=None, q=None, a_data=None, l=None, u=None) -> None:
            if p_data is not None:
                self._p = self.layout.p_matrix(np.array(p_data, dtype=float))
                self._p_full = sp.csr_matrix(self._p + sp.triu(self._p, k=1).T)
            if a_data is not None:
                self._a = self.layout.a_matrix_csc(np.array(a_data, dtype=float))
            for name, value in (("q", q), ("l", l), ("u", u)):
                if value is not None:
                    setattr(self, name, np.array(value, dtype=float))

        def warm_start(self, x=None, y=None) -> None:
            if x is not None:
                self.x_warm = np.array(x, dtype=float)
            if y is not None:
                self.y_warm = np.array(y, dtype=float)

        def solve(self, max_iter: int = MAX_ITER) -> QpSolution:
            meta = {"eps_abs": self.eps, "eps_rel": self.eps_rel, "max_iter": int(max_iter), "rho": 0.4,
                    "polish": False, "shape": 0, "scene": ""}
            qp = RecordedQp(P=self._p, q=self.q, A=self._a, l=self.l, u=self.u, x_warm=self.x_warm,
                            y_warm=self.y_warm, x=self.x_warm, y=self.y_warm, meta=meta)
            t0 = time.perf_counter()
            try:
                x, status, ok, _ = self.solver.run(self.solver.prepare(qp))
            except Exception as e:  # noqa: BLE001
                x, status, ok = None, f"error: {e}", False
            t = time.perf_counter() - t0
            if x is None or not np.isfinite(x).all():
                x, ok = np.full(self.layout.n, np.nan), False
            self.x_warm = x          # the next solve starts here, as OSQP's would
            objective = 0.5 * float(x @ self.p_times(x)) + float(self.q @ x) if ok else np.nan
            return QpSolution(x=x, y=np.zeros(self.layout.m), objective=objective, status=str(status), usable=ok,
                              accurate=ok, iterations=0, solve_time_s=t)

    Adapter.__name__ = f"{solver_cls.__name__}Adapter"
    return Adapter


def run_scene(index: int, backend: type) -> tuple[list[float], list]:
    saved = qp_step.OsqpQp
    qp_step.OsqpQp = backend
    try:
        times, _, plans = bench_planner.receding_horizon("hyperplane", bench_planner.scene(index))
    finally:
        qp_step.OsqpQp = saved
    return times, plans


def run_lockstep_flight(scenario: str, seed: int, backend: type) -> tuple[list[float], dict]:
    """Replan wall times (s, ``Planner.solve``) of one lockstep flight with ``backend``, and its summary."""
    from companion.core.planner import scp
    from companion.offline.harness import run_lockstep

    times: list[float] = []
    solve = scp.Planner.solve

    def timed(self, request, warm_start=None):
        t0 = time.perf_counter()
        plan = solve(self, request, warm_start)
        times.append(time.perf_counter() - t0)
        return plan

    saved = qp_step.OsqpQp
    qp_step.OsqpQp, scp.Planner.solve = backend, timed
    try:
        result = run_lockstep(ROOT / scenario, seed=seed)
    finally:
        qp_step.OsqpQp, scp.Planner.solve = saved, solve
    return times, result.summary()


def lockstep_table(backends: dict, scenario: str, seeds: list[int]) -> None:
    """Every replan of one lockstep flight per backend and seed, pooled over the seeds per backend."""
    rows: dict = {name: ([], []) for name in backends}
    for seed in seeds:
        for name, backend in backends.items():
            times, summary = run_lockstep_flight(scenario, seed, backend)
            rows[name][0].extend(times)
            rows[name][1].append(summary)
            print(f"  {scenario} seed {seed} with {name} done", file=sys.stderr, flush=True)
    base = np.asarray(rows["osqp (planner)"][0])
    print(f"\n{scenario} seeds {', '.join(map(str, seeds))}, lockstep, every replan of the flights (each backend "
          "flies its own flights)\n")
    print("| backend | replans | median ms | p99 ms | largest ms | median / OSQP | p99 / OSQP | goal reached | "
          "collisions | least true clearance m |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, (times, summaries) in rows.items():
        t = np.asarray(times) * 1e3
        goals = sum(bool(s.get("goal_reached")) for s in summaries)
        collisions = sum(int(s.get("collisions") or 0) for s in summaries)
        clearance = min(float(s.get("min_true_clearance_m", np.nan)) for s in summaries)
        print(f"| {name} | {len(t)} | {np.median(t):.2f} | {np.percentile(t, 99):.2f} | {t.max():.2f} | "
              f"{np.median(times) / np.median(base):.2f} | {np.percentile(times, 99) / np.percentile(base, 99):.2f} | "
              f"{goals} of {len(summaries)} | {collisions} | {clearance:.3f} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solvers", default="piqp,piqp-update,qpalm,clarabel")
    ap.add_argument("--scenes", type=int, default=bench_planner.SCENES)
    ap.add_argument("--lockstep", default="configs/corridor.toml",
                    help="also fly this scenario in lockstep with each backend ('' for none)")
    ap.add_argument("--seeds", default="3", help="corridor seeds, comma-separated")
    args = ap.parse_args(argv)
    backends = {"osqp (planner)": OsqpQp}
    for name in args.solvers.split(","):
        backends[name] = adapter(qp_study.CANDIDATES[name])
    warm = {k: [] for k in backends}
    plans = {k: [] for k in backends}
    ends = {k: [] for k in backends}
    for index in range(args.scenes):
        for name, backend in backends.items():
            times, scene_plans = run_scene(index, backend)
            warm[name].extend(times[1:])
            plans[name].extend(scene_plans)
            ends[name].append(float(np.linalg.norm(scene_plans[-1].positions[0] - bench_planner.GOAL)))
        print(f"  scene {index} done", file=sys.stderr, flush=True)
    if args.scenes:
        base_med, base_p99 = np.median(warm["osqp (planner)"]), np.percentile(warm["osqp (planner)"], 99)
        print(f"{len(warm['osqp (planner)'])} warm replans over {args.scenes} scenes (N = 40, P = 3, W = 2, hyperplane)\n")
        print("| backend | replan median ms | p99 ms | largest ms | median / OSQP | p99 / OSQP | status optimal/slack/failed "
              "| SCP iterations mean | min planned contour | end to goal m (median) |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for name in backends:
            t = np.asarray(warm[name]) * 1e3
            st = [sum(p.status == s for p in plans[name]) for s in ("optimal", "slack", "failed")]
            cmin = min(p.min_contour_of_touch for p in plans[name])
            print(f"| {name} | {np.median(t):.2f} | {np.percentile(t, 99):.2f} | {t.max():.2f} | "
                  f"{np.median(warm[name]) / base_med:.2f} | {np.percentile(warm[name], 99) / base_p99:.2f} | "
                  f"{'/'.join(map(str, st))} | {np.mean([p.iterations for p in plans[name]]):.2f} | {cmin:.3f} | "
                  f"{np.median(ends[name]):.2f} |")
    if args.lockstep:
        lockstep_table(backends, args.lockstep, [int(k) for k in args.seeds.split(",")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
