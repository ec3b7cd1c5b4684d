"""``companion replay LOG.tlog --scenario FILE``: replay a tlog through the estimator and planner.

The scenario is required: a tlog holds MAVLink traffic only, not the mission, planner
and estimator settings the companion flew with, and guessing them would make a
comparison meaningless. Exit 0 when the recorded commands were reproduced (or, for a
log without companion commands, when the what-if ran); 1 when a log with recorded commands
was not reproduced (none compared, some unmatched, or a difference above
:data:`REPRODUCED_MPS`), with one line saying which and what to check; 2 with a message on
bad input (missing, empty or non-tlog file, a log without a vehicle, a bad scenario).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from companion.commands._argtypes import finite_number, non_negative_seconds, positive_number, scenario_file
from companion.commands._defaults import FORMULATIONS
from companion.commands._flight_flags import add_recorded_flight_flags, goal_given, goal_keywords, offboard_settings, planner_overrides
from companion.commands._view import add_view_arguments, open_view

logger = logging.getLogger(__name__)

#: Largest command difference (m/s, on the wire's float32 values) that still counts as reproduced.
REPRODUCED_MPS = 1e-6


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "replay",
        help="replay a tlog through the estimator and planner and compare with the recorded commands",
        description=(
            "Feed the inbound messages of a tlog (companion, mavsim, MAVProxy or QGroundControl) to a fresh "
            "companion in log time, tick it when the recorded companion ticked, and compare its velocity "
            "setpoints with the recorded SET_POSITION_TARGET_LOCAL_NED. A log without companion commands "
            "(a plain flight) reports what the companion would have commanded, assuming OFFBOARD was granted."
        ),
    )
    p.add_argument("log", metavar="LOG.tlog", help="the tlog to replay")
    p.add_argument("--scenario", required=True, type=scenario_file,
                   help="scenario TOML the companion flew (mission, planner, estimator, map), or a shipped scenario's name")
    p.add_argument("--formulation", default=None, choices=FORMULATIONS, help="planner formulation the recorded run used (overrides the scenario)")
    p.add_argument("--time-offset", type=finite_number, default=None, metavar="S",
                   help="seconds subtracted from tlog stamps (default: detect a lockstep log, else 0)")
    p.add_argument("--arm", action="store_true", help="the recorded run armed the vehicle (fly --arm)")
    p.add_argument("--takeoff-alt", type=positive_number, default=None, metavar="M", help="the recorded run took off (fly --takeoff-alt M)")
    p.add_argument("--exit-after-goal", type=non_negative_seconds, default=None, metavar="S",
                   help="the recorded run handed back S seconds after the goal (fly --exit-after-goal S)")
    add_recorded_flight_flags(p)
    p.add_argument("--json", action="store_true", help="print the replay summary as JSON")
    p.add_argument("--plot", default=None, metavar="DIR", help="write the flight figures (PNG) here")
    add_view_arguments(p)
    p.set_defaults(func=run)


def _format(summary: dict) -> str:
    rows = [
        ("log", summary["tlog"]),
        ("mode", summary["mode"] + (" (lockstep time base)" if summary["lockstep"] else "")),
        ("messages read", summary["messages"]),
        ("inbound / outbound", f"{summary['inbound']} / {summary['outbound']}"),
        ("log duration [s]", f"{summary['log_duration_s']:.3f}"),
        ("ticks replayed (recorded)", f"{summary['ticks']} ({summary['recorded_ticks']})"),
        ("replans", summary["replans"]),
        ("plan status", ", ".join(f"{k} {v}" for k, v in sorted(summary["plan_status"].items())) or "-"),
        ("commands replayed", summary["commands_replayed"]),
    ]
    if summary["mode"] == "compare":
        diff = summary["max_abs_diff_mps"]
        rows += [
            ("commands compared (recorded)", f"{summary['commands_compared']} ({summary['commands_recorded']})"),
            ("max |difference| [m/s]", "-" if diff is None else f"{diff:.3g} at t = {summary['max_diff_t_s']:.3f} s from the log start"),
            ("unmatched commands", summary["unmatched_commands"]),
            ("ticks that differ", summary["tick_mismatches"]),
        ]
    speed = summary["max_commanded_speed_mps"]
    rows += [
        ("largest commanded speed [m/s]", "-" if speed is None else f"{speed:.3f}"),
        ("goal reached at [s from the log start]", "-" if summary["goal_reached_t_s"] is None else f"{summary['goal_reached_t_s']:.2f}"),
        ("braking / stale events", f"{summary['braking_events']} / {summary['stale_events']}"),
        ("tracks", summary["tracks"]),
    ]
    tracking = summary.get("tracking_error")
    if tracking:   # the estimate against the plan in force at each replan: what tracking_margin_m2 must cover
        from companion.loop.records import describe_tracking

        rows.append(("strayed from the plan in force", describe_tracking(tracking)))
    width = max(len(k) for k, _ in rows)
    lines = [f"{k.ljust(width)}  {v}" for k, v in rows]
    lines += [f"note: {n}" for n in summary["notes"]]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    overrides = planner_overrides(args)
    from companion.loop.config import load_scenario
    from companion.offline.replay import replay

    scenario = load_scenario(args.scenario, goal_elsewhere=goal_given(args), **overrides)
    offboard = offboard_settings(scenario.offboard, args)
    view = None
    if args.view is not None or args.mcap is not None:
        from companion.mavlink.tlog import read_tlog
        from companion.offline.replay import _align_clocks

        first_s = next(iter(read_tlog(args.log)))[0]    # the log's clock: stamps in calendar time
        view = open_view(args, threaded=False, time_offset_s=_align_clocks(first_s, args.time_offset)[0])
    try:
        result = replay(args.log, args.scenario, time_offset_s=args.time_offset, offboard=offboard,
                        after_tick=view, companion_keywords=goal_keywords(args, scenario), **overrides)
    finally:
        if view is not None:
            view.close()
    summary = result.summary()
    if view is not None:
        summary["view"] = view.summary()
    if args.plot:
        from companion.plots.flight_figures import write_flight_figures

        summary["figures"] = [str(p) for p in write_flight_figures(result.companion, args.plot)]
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        print(_format(summary), file=sys.stdout)
        for path in summary.get("figures", []):
            print(f"figure: {path}")
    problem = not_reproduced(summary)
    if problem:
        print(f"companion replay: {problem}", file=sys.stderr)
        return 1
    return 0


def not_reproduced(summary: dict) -> str | None:
    """Why a compare-mode replay did not reproduce its recording (None when it did, or in what-if mode)."""
    if summary["mode"] != "compare":
        return None
    flags = ("give the replay the scenario and the flags the flight used "
             "(--arm, --takeoff-alt, --exit-after-goal, --formulation, --target-system, --goal or --mission, --fence)")
    recorded, compared = summary["commands_recorded"], summary["commands_compared"]
    if compared == 0:
        return f"compared 0 of {recorded} recorded commands: the replayed companion never streamed when the recorded one did; {flags}"
    diff = summary["max_abs_diff_mps"]
    if summary["unmatched_commands"] or compared < recorded or (diff is not None and diff > REPRODUCED_MPS):
        return (f"not reproduced: {compared} of {recorded} recorded commands compared, "
                f"{summary['unmatched_commands']} unmatched, largest difference {diff:.3g} m/s "
                f"at t = {summary['max_diff_t_s']:.2f} s from the log start; {flags}")
    return None
