"""One line that says how a real-time or SITL flight went, for a failing test and for ``make flake-check``.

A flight test hands its summary (``companion demo --json``'s dict, or a SITL flight's result)
to :func:`record_flight`; ``tests/conftest.py`` prints the line under the test's failure in the
CI log, and pytest's JUnit XML carries it as the property ``flight`` for the flake check's
table. The line names the outcome, the goal, the true clearances (m), the largest setpoint gap
and where its time went, the last events and where the tlogs were kept: enough to find a
cause without flying again.
"""

from __future__ import annotations

from typing import Any, Callable

#: How many of the flight's last events the line carries.
LAST_EVENTS = 4


def _number(value: Any, unit: str) -> str:
    return f"{value:.3f} {unit}" if isinstance(value, (int, float)) and not isinstance(value, bool) else "-"


def flight_line(summary: dict, kept_at: str | None = None) -> str:
    """The flight in one line: outcome, goal, true clearances (m), setpoint gaps (ms), last events, tlogs."""
    report = summary.get("companion_report") or {}
    parts = []
    outcome = summary.get("phase") or report.get("phase") or report.get("outcome")
    parts.append(f"outcome {outcome or '-'}")
    goal_t = summary.get("goal_reached_companion_t_s", report.get("goal_reached_companion_t_s"))
    parts.append(f"goal {'at ' + _number(goal_t, 's') if goal_t is not None else 'NOT reached'}")
    if "time_to_goal_s" in summary:
        parts.append(f"truth time to goal {_number(summary['time_to_goal_s'], 's')}")
    parts.append(f"true goal distance {_number(summary.get('min_true_goal_distance_m'), 'm')}")
    parts.append(f"collided {summary.get('collided', '-')}")
    parts.append(f"true clearance {_number(summary.get('min_true_clearance_m'), 'm')}")
    if "min_wall_clearance_m" in summary:
        parts.append(f"wall clearance {_number(summary['min_wall_clearance_m'], 'm')}")
    contour = summary.get("min_realised_contour", report.get("min_realised_contour"))
    parts.append(f"realised contour {_number(contour, '')}".rstrip())
    gap = summary.get("setpoint_gap_max_ms", report.get("setpoint_gap_max_ms"))
    detail = summary.get("setpoint_gap_max_detail") or {}
    where = ", ".join(f"{k} {detail[k]}" for k in ("cpu_ms", "run_queue_wait_ms", "longest_step", "longest_step_ms")
                      if k in detail)
    parts.append(f"largest setpoint gap {_number(gap, 'ms')}" + (f" ({where})" if where else ""))
    if "setpoint_gaps_over_150ms" in summary:
        parts.append(f"gaps over 150 ms {summary['setpoint_gaps_over_150ms']}")
    for key in ("replans", "failed_plans", "replans_with_slack", "stale_events"):
        if key in summary:
            parts.append(f"{key.replace('_', ' ')} {summary[key]}")
    events = summary.get("events") or summary.get("texts") or []
    if events:
        last = "; ".join(f"{t} {text}" for t, text in events[-LAST_EVENTS:])
        parts.append(f"last events: {last}")
    if summary.get("fly_error"):
        parts.append(f"fly error: {summary['fly_error']}")
    if kept_at:
        parts.append(f"tlogs kept in {kept_at}")
    return " | ".join(parts)


def record_flight(record_property: Callable[[str, object], None], summary: dict, kept_at: object = None) -> None:
    """Hand the flight's line and its smallest true clearance (m) to pytest (``record_property`` fixture).

    The line is printed under a failure and both are kept in JUnit XML for ``make flake-check``.
    """
    record_property("flight", flight_line(summary, None if kept_at is None else str(kept_at)))
    clearance = summary.get("min_true_clearance_m")
    if isinstance(clearance, (int, float)) and not isinstance(clearance, bool):
        record_property("true_clearance_m", float(clearance))
