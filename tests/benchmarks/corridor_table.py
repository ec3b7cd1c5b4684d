"""The README's corridor table: ``companion demo corridor`` over seeds, with and without ``c_max``.

Runs ``companion demo corridor --seed S [--no-c-max] --json`` for every seed (lockstep:
every figure but the solve times is deterministic for a given commit) and prints one
markdown row per run kind: collisions, goal reached, time to goal (median and range),
replans with slack, smallest planned contour, the deepest ``c_min`` violation (contour and
metres, with its seed), the smallest wall and obstacle clearances, and the largest solve
p99 (wall time, moves with the machine's load).

Run: ``python -m tests.benchmarks.corridor_table [--seeds 0-7] [--workers 2] [--json PATH]``
(about 10-15 s of one core per run on the quiet 2-core development machine).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np

KINDS = (("`c_min` only", ["--no-c-max"]), ("`c_min` and `c_max`", []))
RUN_TIMEOUT_S = 600


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def run_one(seed: int, extra: list[str]) -> dict:
    """One lockstep corridor run's JSON summary."""
    cmd = [sys.executable, "-m", "companion.cli", "demo", "corridor", "--seed", str(seed), "--json", *extra]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, check=True)
    summary = json.loads(out.stdout)
    summary["seed"] = seed
    return summary


def row(label: str, runs: list[dict]) -> str:
    """One markdown row of the table for the runs of one kind."""
    goal = [r["time_to_goal_s"] for r in runs if r["goal_reached"]]
    slack = [r["replans_with_slack"] for r in runs]
    replans = [r["replans"] for r in runs]
    planned = [r["min_planned_contour"] for r in runs if r["min_planned_contour"] is not None]
    deepest = max(runs, key=lambda r: r["slack"]["largest_violation_contour"] or 0.0)
    v = deepest["slack"]
    violation = "none" if not v["largest_violation_contour"] else \
        f"{v['largest_violation_contour']:.3f} / {v['largest_violation_m']:.2f} m (seed {deepest['seed']})"
    goal_text = f"{np.median(goal):.1f} s [{min(goal):.1f}, {max(goal):.1f}]" if goal else "-"
    walls = [r["min_wall_clearance_m"] for r in runs if r["min_wall_clearance_m"] is not None]
    return (f"| {label} | {sum(r['collided'] for r in runs)} / {len(runs)} | {len(goal)} / {len(runs)} | {goal_text} "
            f"| {min(slack)} to {max(slack)} (median {np.median(slack):g}; of {min(replans)}-{max(replans)} replans) "
            f"| {min(planned):.3f} to {max(planned):.3f} | {violation} "
            f"| {min(walls):.2f} m / {min(r['min_true_clearance_m'] for r in runs):.2f} m "
            f"| {sum(r['failed_plans'] for r in runs)} | {max(r['solve_time_p99_ms'] for r in runs):.0f} ms |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=_seeds, default=_seeds("0-7"), help="seed range, e.g. 0-7")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", help="also write every run's summary here")
    args = ap.parse_args(argv)
    jobs = [(label, extra, s) for label, extra in KINDS for s in args.seeds]
    with ThreadPoolExecutor(max_workers=max(1, args.workers)) as pool:
        results = list(pool.map(lambda j: (j[0], run_one(j[2], j[1])), jobs))
    print("| run | collisions | goal reached | time to goal, median [range] | replans with slack "
          "| smallest planned contour | deepest `c_min` violation (contour / m) "
          "| smallest wall / obstacle clearance | failed plans | largest solve p99 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, _ in KINDS:
        print(row(label, [r for lab, r in results if lab == label]))
    if args.json:
        with open(args.json, "w") as f:
            json.dump([dict(r, kind=lab) for lab, r in results], f, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
