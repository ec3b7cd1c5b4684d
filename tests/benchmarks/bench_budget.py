"""Largest replan in work units and milliseconds against the work budget (short version).

Flies the antipodal lockstep demo and corridor seed 0 with ``c_max`` (the family whose
least-violation path is the most expensive) and reports, per family, the largest replan
in work units (deterministic) and in milliseconds (this machine, now), with the budget.
The full table over all eight corridor seeds, with and without ``c_max``, and a small
campaign: ``python -m tests.benchmarks.worst_replan``.
"""

from __future__ import annotations

from tests.benchmarks.worst_replan import measure


def run() -> list[dict]:
    rows = []
    for r in measure([0], 0, ["antipodal", "corridor"]):
        note = (f"{r['replans']} replans; budget {r['budget']} units, cut short {r['budget_bound']}; "
                f"p99 {r['ms_p99']:.1f} ms, median {r['ms_median']:.1f} ms; statuses {r['statuses']}")
        rows.append({"name": f"largest replan, {r['family']}", "value": r["work_max"], "unit": "work units",
                     "target": f"<= {r['budget']}", "note": note})
        rows.append({"name": f"largest replan, {r['family']}", "value": r["ms_max"], "unit": "ms",
                     "target": f"< {r['replan_period_ms']:.0f} (replan period)", "note": "wall time, this machine now"})
    return rows
