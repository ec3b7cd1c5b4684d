"""Old ``minmax`` against new in one process: the 10k-pair call of ``make bench``, alternating, and whether its bits changed.

Usage::

    git worktree add /tmp/old <commit>
    python -m tests.benchmarks.ab_minmax /tmp/old . [--calls 150] [--pairs 10000]

Both trees' ``companion`` packages are imported into this one process, one after the
other (each keeps its own modules and its own compiled kernels, which numba caches beside
each tree's files), and ``overlap.minmax`` of each is called on the benchmark's seeded
random pairs (``bench_overlap.random_pairs``), the two taking turns call by call. It
prints each tree's median wall time (ms), the median of the new call's time over the old
one's paired by turn, and whether every field of the result is the same bytes. Calls in
turn put this machine's drift (10 to 30 % within seconds) on both trees alike; the paired
ratio is the figure to quote.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

FIELDS = ("lam", "eta", "alpha", "beta", "normal", "s1", "s2", "eta_grad_mu1", "residual")


def load_minmax(tree: Path):
    """``companion.core.overlap.minmax`` as the code in ``tree`` defines it (its modules imported afresh)."""
    for name in [m for m in sys.modules if m == "companion" or m.startswith("companion.")]:
        del sys.modules[name]
    sys.path.insert(0, str(tree.resolve()))
    try:
        from companion.core import jit, overlap
        jit.warm_up()
        return overlap.minmax
    finally:
        sys.path.pop(0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--calls", type=int, default=150, help="calls per tree (default 150)")
    parser.add_argument("--pairs", type=int, default=10_000, help="pairs per call (default 10000)")
    args = parser.parse_args(argv)
    from tests.benchmarks.bench_overlap import random_pairs

    pairs = random_pairs(args.pairs)
    trees = {"old": load_minmax(args.old), "new": load_minmax(args.new)}
    results = {label: minmax(*pairs) for label, minmax in trees.items()}     # and the first call's compile
    times: dict[str, list[float]] = {label: [] for label in trees}
    for turn in range(args.calls):
        order = ("old", "new") if turn % 2 == 0 else ("new", "old")
        for label in order:
            t0 = time.perf_counter()
            trees[label](*pairs)
            times[label].append(time.perf_counter() - t0)
    old, new = np.array(times["old"]), np.array(times["new"])
    same = all(np.array_equal(getattr(results["old"], f), getattr(results["new"], f)) for f in FIELDS)
    print(f"old {args.old}: median {1e3 * np.median(old):.3f} ms")
    print(f"new {args.new}: median {1e3 * np.median(new):.3f} ms")
    print(f"new / old, paired by turn: {np.median(new / old):.3f} ({args.calls} calls of {args.pairs} pairs each)")
    print("results identical" if same else "results DIFFER")


if __name__ == "__main__":
    main()
