"""Run every ``bench_*.py`` module (or those named on the command line) and report."""

from __future__ import annotations

import importlib
import json
import logging
import os
import pkgutil
import platform
import sys
import time
from pathlib import Path

import tests.benchmarks as _pkg

ROOT = Path(__file__).resolve().parents[2]


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "" if value is None else str(value)


#: The issue's must-show figures, printed together after the table: (suite, row name).
SUMMARY = (
    ("planner", "hyperplane replan time / OSQP's own solve time"),
    ("planner", "replan N=40 P=3 W=2 hyperplane median"),
    ("planner", "replan N=40 P=3 W=2 hyperplane p99"),
    ("planner", "hyperplane largest replan"),
    ("planner", "hyperplane speed-up over cvxpy"),
    ("backends", "benchmark replan p99, piqp"),
    ("backends", "corridor replan p99, piqp"),
    ("backends", "PIQP iteration in ADMM iterations (fitted)"),
    ("overlap", "minmax batched, 10k 3-D pairs"),
    ("overlap", "max relative eta difference vs brentq"),
    ("estimator", "tracker cycle: update 10 tracks + predict all N=40 (median)"),
    ("campaign", "core-seconds per antipodal campaign episode (hyperplane)"),
    ("startup", "companion --version, median of 10"),
    ("startup", "companion --help, median of 10"),
    ("startup", "companion fly to its first HEARTBEAT, median of 10"),
)


def _summary(rows: list[dict]) -> list[str]:
    """The :data:`SUMMARY` rows as ``name: value unit (target ...; peer ...)`` lines, with the load."""
    by_key = {(r["suite"], r["name"]): r for r in rows}
    lines = []
    for key in SUMMARY:
        r = by_key.get(key)
        if r is None:
            continue
        extra = [f"target {_fmt(r.get('target'))}"] if r.get("target") is not None else []
        if r.get("peer") is not None:
            extra.append(f"peer {_fmt(r.get('peer'))}")
        lines.append(f"  {r['name']}: {_fmt(r['value'])} {r.get('unit', '')} ({'; '.join(extra)})")
    if lines:
        load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
        lines.insert(0, f"summary (load average {load}; timings under load are not final):")
    return lines


def main(argv: list[str]) -> int:
    # Benchmarks drive the simulator without avoidance: its collision warnings are expected noise.
    logging.basicConfig(level=logging.ERROR)
    wanted = set(argv)
    modules = sorted(m.name for m in pkgutil.iter_modules(_pkg.__path__) if m.name.startswith("bench_"))
    if wanted:
        modules = [m for m in modules if m.removeprefix("bench_") in wanted or m in wanted]
    rows: list[dict] = []
    # The compiled kernels are loaded (or compiled) once per process, as a planning process or
    # a campaign worker does at its start: timed here, apart from every suite's figures.
    from companion.core import jit
    from companion.core.planner import Planner  # noqa: F401  (registers the planner's kernels)

    t0 = time.perf_counter()
    jit.warm_up()
    rows.append({"suite": "start-up", "name": "compiled kernels loaded (numba import + disk cache, or compile)",
                 "value": time.perf_counter() - t0, "unit": "s",
                 "note": "once per process, before the suites; compiling (first run after an install) takes longer"})
    for name in modules:
        module = importlib.import_module(f"{_pkg.__name__}.{name}")
        t0 = time.perf_counter()
        print(f"running {name} ...", file=sys.stderr, flush=True)
        for row in module.run():
            rows.append({"suite": name.removeprefix("bench_"), **row})
        print(f"  done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    cols = ["suite", "name", "value", "unit", "target", "peer", "ratio", "note"]
    table = [[_fmt(r.get(c)) for c in cols] for r in rows]
    widths = [max(len(c), *(len(t[i]) for t in table)) if table else len(c) for i, c in enumerate(cols)]
    print("  ".join(c.ljust(w) for c, w in zip(cols, widths)))
    for t in table:
        print("  ".join(v.ljust(w) for v, w in zip(t, widths)))
    summary = _summary(rows)
    if summary:
        print("\n".join(summary))
    out = {
        "load_average": os.getloadavg(),
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "processor": platform.processor()},
        "rows": rows,
    }
    (ROOT / "bench-results.json").write_text(json.dumps(out, indent=2))
    print(f"wrote {ROOT / 'bench-results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
