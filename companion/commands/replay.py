"""``companion replay LOG.tlog --scenario FILE``: replay a tlog through the estimator and planner.

The scenario is required: a tlog holds MAVLink traffic only, not the mission, planner
and estimator settings the companion flew with, and guessing them would make a
comparison meaningless. Exit 0 on success, 2 with a message on bad input (missing,
empty or non-tlog file, a log without a PX4 vehicle, a bad scenario).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys

from companion.commands._argtypes import finite_number, non_negative_seconds, positive_number
from companion.loop.records import describe_tracking
from companion.offline.replay import replay

logger = logging.getLogger(__name__)


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
    p.add_argument("--scenario", required=True, help="scenario TOML the companion flew (mission, planner, estimator, map)")
    p.add_argument("--formulation", default=None, help="planner formulation the recorded run used (overrides the scenario)")
    p.add_argument("--time-offset", type=finite_number, default=None, metavar="S",
                   help="seconds subtracted from tlog stamps (default: detect a lockstep log, else 0)")
    p.add_argument("--arm", action="store_true", help="the recorded run armed the vehicle (fly --arm)")
    p.add_argument("--takeoff-alt", type=positive_number, default=None, metavar="M", help="the recorded run took off (fly --takeoff-alt M)")
    p.add_argument("--exit-after-goal", type=non_negative_seconds, default=None, metavar="S",
                   help="the recorded run handed back S seconds after the goal (fly --exit-after-goal S)")
    p.add_argument("--json", action="store_true", help="print the replay summary as JSON")
    p.add_argument("--plot", default=None, metavar="DIR", help="write the flight figures (PNG) here")
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
            ("max |difference| [m/s]", "-" if diff is None else f"{diff:.3g} at t = {summary['max_diff_t_s']:.3f} s"),
            ("unmatched commands", summary["unmatched_commands"]),
            ("ticks that differ", summary["tick_mismatches"]),
        ]
    speed = summary["max_commanded_speed_mps"]
    rows += [
        ("largest commanded speed [m/s]", "-" if speed is None else f"{speed:.3f}"),
        ("goal reached at [s]", "-" if summary["goal_reached_t_s"] is None else f"{summary['goal_reached_t_s']:.2f}"),
        ("braking / stale events", f"{summary['braking_events']} / {summary['stale_events']}"),
        ("tracks", summary["tracks"]),
    ]
    tracking = summary.get("tracking_error")
    if tracking:   # the estimate against the plan in force at each replan: what tracking_margin_m2 must cover
        rows.append(("strayed from the plan in force", describe_tracking(tracking)))
    width = max(len(k) for k, _ in rows)
    lines = [f"{k.ljust(width)}  {v}" for k, v in rows]
    lines += [f"note: {n}" for n in summary["notes"]]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    overrides = {"formulation": args.formulation} if args.formulation else {}
    from companion.loop.config import load_scenario

    recorded = load_scenario(args.scenario, **overrides).offboard
    offboard = dataclasses.replace(recorded, arm=args.arm or recorded.arm,
                                   takeoff_alt_m=recorded.takeoff_alt_m if args.takeoff_alt is None else args.takeoff_alt,
                                   hold_after_goal_s=args.exit_after_goal)
    result = replay(args.log, args.scenario, time_offset_s=args.time_offset, offboard=offboard, **overrides)
    summary = result.summary()
    if args.plot:
        from companion.plots.flight_figures import write_flight_figures

        summary["figures"] = [str(p) for p in write_flight_figures(result.companion, args.plot)]
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        print(_format(summary), file=sys.stdout)
        for path in summary.get("figures", []):
            print(f"figure: {path}")
    return 0
