"""Old planner against new in one run: the planner benchmark's replans, and whether the plans changed.

Usage::

    git worktree add /tmp/old <commit>
    python -m tests.benchmarks.ab_planner /tmp/old . [--rounds 3]

Each round flies the planner benchmark's receding horizon (``hyperplane``, its 8 scenes,
472 warm replans) in one fresh process per tree, the trees in alternating order, and
prints per tree and round the warm replans' median and 99th percentile (ms), the replan
time over OSQP's own solve time (sums), and a digest of every plan (SHA-256 of the
velocities and exact touch radii of all 480 plans): equal digests mean the change left
every plan as it was, bit for bit. Compiled kernels, when a tree has them, are loaded
before the first replan. The ratio of one run is the figure to quote: a shared machine's
speed drifts between runs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tests.benchmarks.ab_episode import alternate, child_json, source_trees

_CHILD = r"""
import hashlib, json, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from tests.benchmarks import bench_planner as B
try:
    from companion.core import jit
    jit.warm_up()
except ImportError:
    pass
times, osqp, digest = [], [], hashlib.sha256()
for index in range(B.SCENES):
    solve_s = []
    t, _, plans = B.receding_horizon("hyperplane", B.scene(index), osqp_times=solve_s)
    times += t[1:]
    osqp += solve_s[1:]
    for plan in plans:
        digest.update(plan.velocities.tobytes())
        digest.update(np.asarray(plan.eta).tobytes())
print(json.dumps([1e3 * float(np.median(times)), 1e3 * float(np.percentile(times, 99)), sum(times) / sum(osqp),
                  digest.hexdigest()[:12]]))
"""

TIMEOUT_S = 900.0


def run_tree(tree: Path) -> tuple[float, float, float, str]:
    """(median ms, p99 ms, replan / OSQP time, plans digest) of the benchmark flown by the code in ``tree``."""
    median, p99, ratio, digest = child_json(_CHILD, tree, timeout_s=TIMEOUT_S)
    return float(median), float(p99), float(ratio), str(digest)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="source tree of the old code (a git worktree)")
    ap.add_argument("new", type=Path, help="source tree of the new code")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    args = ap.parse_args(argv)
    trees = source_trees([args.old, args.new], "tests/benchmarks/bench_planner.py", "ab_planner")
    if trees is None:
        return 2
    runs = alternate(trees, args.rounds, run_tree)
    for t, label in zip(trees, ("old", "new")):
        rounds = runs[t]
        print(f"{label} {t}: median {' '.join(f'{m:.2f}' for m, _, _, _ in rounds)} ms; "
              f"p99 {' '.join(f'{p:.2f}' for _, p, _, _ in rounds)} ms; "
              f"replan / OSQP {' '.join(f'{q:.2f}' for _, _, q, _ in rounds)}; plans {rounds[0][3]}")
    same = {d for t in trees for *_, d in runs[t]}
    med = {t: sum(m for m, *_ in runs[t]) / args.rounds for t in trees}
    print(f"new / old median: {med[trees[1]] / med[trees[0]]:.3f}; plans {'identical' if len(same) == 1 else 'DIFFER'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
