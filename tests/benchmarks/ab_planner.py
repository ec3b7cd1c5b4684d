"""Old planner against new in one run: the planner benchmark's replans, and whether the plans changed.

Usage::

    git worktree add /tmp/old <commit>
    python -m tests.benchmarks.ab_planner /tmp/old . [--rounds 3]

One worker process per tree flies the planner benchmark's receding horizon
(``hyperplane``, its 8 scenes, 472 warm replans a round), the two taking turns scene by
scene (who goes first alternates), so that the machine's drift, which on a shared
machine moves a whole run by 10 to 30 % within seconds, falls on both trees alike. Per
tree and round it prints the warm replans' median and 99th percentile (ms) and the
replan time over OSQP's own solve time (sums), then the new tree's figures over the old
one's, paired by round, and a digest of every plan (SHA-256 of the velocities and exact
touch radii of all 480 plans of a round, the same in every round): equal digests mean
the change left every plan as it was, bit for bit. Compiled kernels, when a tree has
them, are loaded before the first replan. The paired ratios of one run are the figures
to quote.
"""

from __future__ import annotations

import argparse
import json
import selectors
import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.benchmarks.ab_episode import source_trees

_WORKER = r"""
import hashlib, json, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from tests.benchmarks import bench_planner as B
try:
    from companion.core import jit
    jit.warm_up()
except ImportError:
    pass
print(json.dumps(B.SCENES), flush=True)
digest = hashlib.sha256()
for line in sys.stdin:
    index = int(line)
    if index == 0:
        digest = hashlib.sha256()
    solve_s = []
    t, _, plans = B.receding_horizon("hyperplane", B.scene(index), osqp_times=solve_s)
    for plan in plans:
        digest.update(plan.velocities.tobytes())
        digest.update(np.asarray(plan.eta).tobytes())
    print(json.dumps([t[1:], solve_s[1:], digest.hexdigest()[:12]]), flush=True)
"""

#: Longest wait for one scene (or a worker's start-up), seconds.
TIMEOUT_S = 300.0


class Worker:
    """A process of one tree that flies the benchmark's scenes on request."""

    def __init__(self, tree: Path) -> None:
        self.tree = tree
        self.proc = subprocess.Popen([sys.executable, "-c", _WORKER, str(tree)], cwd=tree, text=True,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.scenes = int(self._answer())

    def _answer(self):
        """The worker's next line as JSON, within :data:`TIMEOUT_S` (SystemExit with its error otherwise)."""
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            line = self.proc.stdout.readline() if sel.select(TIMEOUT_S) else ""
        if not line:
            self.close()
            err = self.proc.stderr.read().strip().splitlines() if self.proc.stderr else []
            raise SystemExit(f"{self.tree}: {err[-1] if err else 'no answer within %.0f s' % TIMEOUT_S}")
        return json.loads(line)

    def scene(self, index: int) -> tuple[list[float], list[float], str]:
        """Warm replan times (s), OSQP's solve time of each (s), the round's plan digest so far."""
        self.proc.stdin.write(f"{index}\n")
        self.proc.stdin.flush()
        times, osqp, digest = self._answer()
        return times, osqp, digest

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=10)


def interleaved(trees: list[Path], rounds: int) -> dict[Path, list[tuple[list[float], list[float], str]]]:
    """Per tree, per round: (warm replan times, OSQP times, digest of the round's plans), scenes taken in turns."""
    workers = [Worker(t) for t in trees]
    try:
        out: dict[Path, list] = {t: [] for t in trees}
        for r in range(rounds):
            acc = {t: ([], [], "") for t in trees}
            for index in range(workers[0].scenes):
                order = workers if (r + index) % 2 == 0 else workers[::-1]
                for w in order:
                    times, osqp, digest = w.scene(index)
                    acc[w.tree][0].extend(times)
                    acc[w.tree][1].extend(osqp)
                    acc[w.tree] = (acc[w.tree][0], acc[w.tree][1], digest)
            for t in trees:
                out[t].append(acc[t])
        return out
    finally:
        for w in workers:
            w.close()


def figures(times: list[float], osqp: list[float]) -> tuple[float, float, float]:
    """Median and 99th percentile (ms) of the replans, and their time over OSQP's (sums)."""
    return 1e3 * float(np.median(times)), 1e3 * float(np.percentile(times, 99)), sum(times) / sum(osqp)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="source tree of the old code (a git worktree)")
    ap.add_argument("new", type=Path, help="source tree of the new code")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of the 8 scenes (default 3)")
    args = ap.parse_args(argv)
    trees = source_trees([args.old, args.new], "tests/benchmarks/bench_planner.py", "ab_planner")
    if trees is None:
        return 2
    runs = interleaved(trees, args.rounds)
    figs = {t: [figures(times, osqp) for times, osqp, _ in runs[t]] for t in trees}
    for t, label in zip(trees, ("old", "new")):
        print(f"{label} {t}: median {' '.join(f'{m:.2f}' for m, _, _ in figs[t])} ms; "
              f"p99 {' '.join(f'{p:.2f}' for _, p, _ in figs[t])} ms; "
              f"replan / OSQP {' '.join(f'{q:.3f}' for _, _, q in figs[t])}; plans {runs[t][0][2]}")
    old, new = figs[trees[0]], figs[trees[1]]
    for k, name in ((0, "median"), (1, "p99"), (2, "replan / OSQP")):
        paired = [n[k] / o[k] for o, n in zip(old, new)]
        print(f"new / old {name}, paired by round: {' '.join(f'{x:.3f}' for x in paired)} "
              f"(median {float(np.median(paired)):.3f})")
    same = {d for t in trees for *_, d in runs[t]}
    print(f"plans {'identical' if len(same) == 1 else 'DIFFER'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
