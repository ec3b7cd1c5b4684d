"""The largest replan per scene family, in work units and in milliseconds, against the bound.

Flies the lockstep demos (``companion demo antipodal``; ``companion demo corridor --seed S``
with and without ``c_max`` for S in 0..7), a small antipodal campaign and the antipodal demo
with hostile obstacle traffic (:mod:`tests.support.hostile_scenes`: 200 extra systems beside
the route, 20 ids on a 6 m ring across it, one obstacle reporting a 1e30 m^2 covariance), records every
replan's work (:attr:`companion.core.planner.Plan.work`) and wall time, and prints one
row per scene family: replans, largest work, largest and 99th-percentile time, the
budget (``replan_work_budget``), how many replans the budget bound, and the replan
period the largest replan must stay under. Wall times are from ``time.perf_counter`` on
whatever the machine is doing (shared machines inflate them; work units do not move).

Run: ``python -m tests.benchmarks.worst_replan [--seeds 0-7] [--episodes 4] [--json PATH] [--markdown]``
(about 2 core-minutes per corridor flight on a quiet 2-core machine). Not part of
``make bench`` (too long); :mod:`tests.benchmarks.bench_budget` runs a short version
(antipodal and corridor seed 0).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.core.planner import Planner
from companion.core.planner.budget import QP_SOLVE_WORK
from tests.support.hostile_scenes import SCENES, hostile_antipodal

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@dataclass
class FamilyStats:
    """Replans of one scene family."""

    family: str
    work: list[int] = field(default_factory=list)
    times_s: list[float] = field(default_factory=list)
    budget_bound: int = 0
    statuses: dict = field(default_factory=dict)
    budget: int = 0
    replan_period_s: float = 0.0
    flights: int = 0
    collided: int = 0
    goal_reached: int = 0
    min_clearance_m: float = float("inf")

    def row(self) -> dict:
        w, t = np.asarray(self.work), np.asarray(self.times_s) * 1e3
        return {"family": self.family, "replans": int(w.size), "work_max": int(w.max(initial=0)),
                "work_p99": float(np.percentile(w, 99)) if w.size else 0.0,
                "ms_max": float(t.max(initial=0.0)), "ms_p99": float(np.percentile(t, 99)) if t.size else 0.0,
                "ms_median": float(np.median(t)) if t.size else 0.0,
                "budget": self.budget, "budget_bound": self.budget_bound, "statuses": self.statuses,
                "replan_period_ms": 1e3 * self.replan_period_s,
                "flights": self.flights, "collided": self.collided, "goal_reached": self.goal_reached,
                "min_clearance_m": self.min_clearance_m,
                "per_replan": [[int(a), round(float(b), 3)] for a, b in zip(w, t)]}


class _Recorder:
    """Wraps ``Planner.solve`` for the duration of a run and files every plan under a family."""

    def __init__(self) -> None:
        self.current: FamilyStats | None = None
        self._orig = Planner.solve

    def __enter__(self) -> _Recorder:
        recorder, orig = self, self._orig

        def solve(planner, request, warm_start=None):
            t0 = time.perf_counter()
            plan = orig(planner, request, warm_start)
            dt = time.perf_counter() - t0
            s = recorder.current
            if s is not None:
                s.work.append(plan.work)
                s.times_s.append(dt)
                s.budget = planner.config.replan_work_budget
                s.replan_period_s = planner.config.replan_period_s
                s.statuses[plan.status] = s.statuses.get(plan.status, 0) + 1
                s.budget_bound += any(n.startswith("work_budget") for n in plan.notes)
            return plan

        Planner.solve = solve
        return self

    def __exit__(self, *exc) -> None:
        Planner.solve = self._orig


def _fly(stats: FamilyStats, path: Path, seed: int, **overrides) -> None:
    from companion.offline.harness import run_lockstep

    summary = run_lockstep(path, seed=seed, **overrides).summary()
    stats.flights += 1
    stats.collided += bool(summary.get("collided"))
    stats.goal_reached += bool(summary.get("goal_reached"))
    stats.min_clearance_m = min(stats.min_clearance_m, float(summary.get("min_true_clearance_m", float("inf"))))


def measure(seeds: list[int], episodes: int, families: list[str], budget: int | None = None) -> list[dict]:
    from companion.offline.campaign import generate_scenario, write_scenario

    rows = []
    extra = {} if budget is None else {"replan_work_budget": budget}
    with _Recorder() as rec:
        if "antipodal" in families:
            rec.current = FamilyStats("antipodal demo (seed 0)")
            _fly(rec.current, CONFIGS / "antipodal.toml", 0, **extra)
            rows.append(rec.current.row())
        if "corridor" in families:
            rec.current = FamilyStats(f"corridor demo, c_max (seeds {seeds[0]}..{seeds[-1]})")
            for s in seeds:
                _fly(rec.current, CONFIGS / "corridor.toml", s, **extra)
            rows.append(rec.current.row())
        if "corridor-no-cmax" in families:
            rec.current = FamilyStats(f"corridor demo, --no-c-max (seeds {seeds[0]}..{seeds[-1]})")
            for s in seeds:
                _fly(rec.current, CONFIGS / "corridor.toml", s, c_max=None, **extra)
            rows.append(rec.current.row())
        for scene in SCENES:  # hostile obstacle traffic added to the antipodal demo (tests/support/hostile_scenes.py)
            if f"hostile-{scene}" in families:
                rec.current = FamilyStats(f"antipodal + hostile {scene} (seed 0)")
                with tempfile.TemporaryDirectory(prefix="worst-replan-") as tmp:
                    _fly(rec.current, hostile_antipodal(scene, Path(tmp)), 0, **extra)
                rows.append(rec.current.row())
        if "campaign" in families and episodes:
            rec.current = FamilyStats(f"antipodal campaign, hyperplane ({episodes} episodes, seed 1)")
            with tempfile.TemporaryDirectory(prefix="worst-replan-") as tmp:
                for index in range(episodes):
                    data = generate_scenario("antipodal", 1, index)
                    path = write_scenario(data, Path(tmp) / f"episode{index}.toml")
                    _fly(rec.current, path, 1000 + index, **extra)
            rows.append(rec.current.row())
        rec.current = None
    return rows


def format_table(rows: list[dict]) -> str:
    head = (f"{'scene family':<44} {'replans':>7} {'work max':>9} {'work p99':>9} {'ms max':>8} {'ms p99':>8} "
            f"{'ms med':>7} {'budget':>7} {'bound':>5} {'period ms':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['family']:<44} {r['replans']:>7} {r['work_max']:>9} {r['work_p99']:>9.0f} {r['ms_max']:>8.1f} "
                     f"{r['ms_p99']:>8.1f} {r['ms_median']:>7.1f} {r['budget']:>7} {r['budget_bound']:>5} "
                     f"{r['replan_period_ms']:>9.0f}")
    lines.append("")
    for r in rows:
        lines.append(f"{r['family']}: {r['flights']} flights, {r['goal_reached']} reached the goal, "
                     f"{r['collided']} collided, min true clearance {r['min_clearance_m']:.3f} m; statuses {r['statuses']}")
    lines.append(f"work = ADMM iterations of all QPs of a replan + {QP_SOLVE_WORK} per QP solve; "
                 "'bound' = replans the budget cut short")
    return "\n".join(lines)


def format_markdown(rows: list[dict]) -> str:
    """The table as markdown: largest replan per scene family against the work budget."""
    lines = ["| scene family | flights | replans | work max | work p99 | budget | cut by budget | ms max | ms p99 | ms median "
             "| goal / collided |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['family']} | {r['flights']} | {r['replans']} | {r['work_max']} | {r['work_p99']:.0f} | {r['budget']} "
                     f"| {r['budget_bound']} | {r['ms_max']:.1f} | {r['ms_p99']:.1f} | {r['ms_median']:.1f} "
                     f"| {r['goal_reached']} / {r['collided']} |")
    lines.append(f"\nwork = ADMM iterations of all QPs of a replan + {QP_SOLVE_WORK} per QP solve; the bound is the "
                 "budget (`replan_work_budget`); wall times from `time.perf_counter` on the machine as loaded.")
    return "\n".join(lines)


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-", 1)
        return list(range(int(a), int(b) + 1))
    return [int(x) for x in text.split(",")]


def main(argv: list[str]) -> int:
    logging.basicConfig(level=logging.ERROR)
    p = argparse.ArgumentParser(prog="python -m tests.benchmarks.worst_replan", description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=_seeds, default=list(range(8)), help="corridor seeds, e.g. 0-7 or 0,3")
    p.add_argument("--episodes", type=int, default=4, help="antipodal campaign episodes (hyperplane)")
    p.add_argument("--families", default="antipodal,corridor,corridor-no-cmax,campaign,"
                   + ",".join(f"hostile-{scene}" for scene in SCENES))
    p.add_argument("--markdown", action="store_true", help="also print the table as markdown")
    p.add_argument("--budget", type=int, help="override replan_work_budget (e.g. a huge one to see the unbounded work)")
    p.add_argument("--json", type=Path, help="also write the rows as JSON")
    args = p.parse_args(argv)
    rows = measure(args.seeds, args.episodes, args.families.split(","), args.budget)
    print(format_table(rows))
    if args.markdown:
        print()
        print(format_markdown(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
