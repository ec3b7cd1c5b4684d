"""Old code against new in one run: core-seconds per campaign episode, and whether the episodes' scores changed.

Usage::

    git worktree add /tmp/old <commit>
    python -m tests.benchmarks.ab_episode /tmp/old . [--episodes 0,1,2,3] [--rounds 3]

Each round runs the episodes (antipodal family, campaign seed 1, ``hyperplane``) in one fresh
process per tree, the trees in alternating order, and reads the process's CPU time around each
episode (``time.process_time``). It prints each tree's mean core-seconds, the ratio new / old,
and a digest of each episode's score (SHA-256 of its JSON, every field but the solve times):
equal digests mean the change left every simulated number as it was. A compiled kernel, when
the tree has one, is loaded before the first episode and its core-seconds reported apart (a
campaign worker pays them once, not per episode). Timings of a shared
machine drift between runs; the ratio of one run is the figure to quote.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Callable

_CHILD = r"""
import dataclasses, hashlib, json, sys, time
sys.path.insert(0, sys.argv[1])
from companion.offline.campaign.run import EpisodeTask, run_episode
c0 = time.process_time()
try:    # a compiled kernel is loaded once per process (a campaign worker's start-up): timed apart
    from companion.core import jit
    jit.warm_up()
except ImportError:
    pass
out = [[time.process_time() - c0, ""]]
for index in [int(i) for i in sys.argv[2].split(",")]:
    task = EpisodeTask(family="antipodal", seed=1, index=index, method="hyperplane")
    c0 = time.process_time()
    result = run_episode(task)
    core = time.process_time() - c0
    if result.error:
        raise SystemExit(f"episode {index}: {result.error}")
    score = dataclasses.asdict(result.score)
    score.pop("solve_times_s", None)
    out.append([core, hashlib.sha256(json.dumps(score, sort_keys=True, default=str).encode()).hexdigest()[:12]])
print(json.dumps(out))
"""

TIMEOUT_S = 1800.0


def child_json(code: str, tree: Path, *args: str, timeout_s: float = TIMEOUT_S):
    """The JSON ``code`` prints last, run by the code in ``tree`` in a fresh interpreter (``sys.argv[1]`` is ``tree``)."""
    proc = subprocess.run([sys.executable, "-c", code, str(tree), *args], capture_output=True, text=True,
                          cwd=tree, timeout=timeout_s)
    if proc.returncode != 0:
        raise SystemExit(f"{tree}: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else proc.returncode}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def source_trees(paths: list[Path], marker: str, tool: str) -> list[Path] | None:
    """``paths`` resolved, or None (said on stderr) when one has no ``marker`` file: not a tree of this project."""
    for tree in paths:
        if not (tree / marker).is_file():
            print(f"{tool}: {tree} is not a source tree of this project (no {marker})", file=sys.stderr)
            return None
    return [tree.resolve() for tree in paths]


def alternate(trees: list[Path], rounds: int, run: Callable[[Path], object]) -> dict[Path, list]:
    """``run(tree)`` for each tree in each round, the order reversed every other round; results per tree."""
    results: dict[Path, list] = {t: [] for t in trees}
    for r in range(rounds):
        for tree in trees if r % 2 == 0 else trees[::-1]:
            results[tree].append(run(tree))
    return results


def run_tree(tree: Path, episodes: str) -> tuple[float, list[tuple[float, str]]]:
    """Start-up core-seconds, and (core-seconds, score digest) of each episode, flown by ``tree`` in a fresh process."""
    (warm, _), *episodes_run = child_json(_CHILD, tree, episodes)
    return float(warm), [(float(c), str(h)) for c, h in episodes_run]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="source tree of the old code (a git worktree)")
    ap.add_argument("new", type=Path, help="source tree of the new code")
    ap.add_argument("--episodes", default="0,1,2,3", help="episode indices (default 0,1,2,3)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    args = ap.parse_args(argv)
    trees = source_trees([args.old, args.new], "companion/__init__.py", "ab_episode")
    if trees is None:
        return 2
    results = alternate(trees, args.rounds, lambda tree: run_tree(tree, args.episodes))
    warm = {t: [start_up for start_up, _ in results[t]] for t in trees}
    runs = {t: [run for _, run in results[t]] for t in trees}
    mean = {t: sum(c for run in runs[t] for c, _ in run) / sum(len(run) for run in runs[t]) for t in trees}
    digests = {t: [h for _, h in runs[t][0]] for t in trees}
    for t, label in zip(trees, ("old", "new")):
        print(f"{label} {t}: {mean[t]:.3f} core-s per episode (+ {max(warm[t]):.2f} core-s once per process "
              f"loading compiled kernels); scores {' '.join(digests[t])}")
    print(f"new / old: {mean[trees[1]] / mean[trees[0]]:.3f}; scores "
          f"{'identical' if digests[trees[0]] == digests[trees[1]] else 'DIFFER'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
