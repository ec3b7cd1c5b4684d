"""A SITL flight run N times from the command line: each run judged once, its figures printed
as JSON, then the tally (``python -m tests.px4.flight --runs 5`` and its kin)."""

from __future__ import annotations

import json
from collections.abc import Callable


def fly_runs(fly: Callable[[int], dict], judge: Callable[[dict], list[str]], runs: int) -> int:
    """Fly ``runs`` times (``fly(i)``, i the run's index and seed); each run's failed checks go
    in its ``failed`` list. Returns the exit code: 0 when every run passed, 1 otherwise."""
    results = []
    for i in range(runs):
        r = fly(i)
        r["failed"] = judge(r)
        results.append(r)
        print(json.dumps(r, indent=1, default=str), flush=True)
    passed = sum(not r["failed"] for r in results)
    print("passed", passed, "of", len(results))
    return 0 if passed == len(results) else 1
