"""``companion fly``: fly a scenario's mission against a live autopilot (PX4 SITL, mavsim, a vehicle)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time

from companion.loop.app import Companion
from companion.mavlink.link import DEFAULT_URL, open_link
from companion.loop.realtime import run_realtime
from companion.offline.report import companion_report, format_report
from companion.loop.config import load_scenario

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "fly",
        help="fly a scenario's mission over MAVLink in real time",
        description=(
            "Connect to a PX4 autopilot, stream velocity setpoints, request OFFBOARD (confirmed from the "
            "HEARTBEAT) and fly the scenario's mission around the obstacles heard on the link. Without "
            "--arm the companion does not arm: it waits for the pilot to arm, then streams setpoints and "
            "requests OFFBOARD. If the vehicle leaves OFFBOARD, the companion stops commanding."
        ),
    )
    p.add_argument("--connect", default=DEFAULT_URL, help=f"pymavlink connection string (default {DEFAULT_URL})")
    p.add_argument("--scenario", required=True, help="scenario TOML (mission, planner, estimator, map)")
    p.add_argument("--arm", action="store_true", help="arm the vehicle if it is disarmed")
    p.add_argument("--takeoff-alt", type=float, default=None, metavar="M", help="take off to M metres above home first")
    p.add_argument("--reengage", action="store_true", help="re-request OFFBOARD after the pilot took over (default: never)")
    p.add_argument("--formulation", default=None, help="planner formulation (overrides the scenario)")
    p.add_argument("--no-c-max", action="store_true", help="drop the scenario's c_max upper bound")
    p.add_argument("--tlog", default=None, help="record the link to this tlog")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S wall seconds")
    p.add_argument("--exit-after-goal", type=float, default=None, metavar="S",
                   help="S seconds after the goal is reached, switch the vehicle to Hold (AUTO.LOITER) and stop "
                        "once the HEARTBEAT shows it holding")
    p.add_argument("--json", action="store_true", help="print the run report as JSON")
    p.set_defaults(func=run)


def microsecond_clock() -> float:
    """Unix time rounded to whole microseconds: the times the loop acts on are exactly the
    times a tlog can store, so a recorded flight replays tick for tick."""
    return round(time.time() * 1e6) * 1e-6


def run(args: argparse.Namespace) -> int:
    overrides: dict = {"formulation": args.formulation} if args.formulation else {}
    if args.no_c_max:
        overrides["c_max"] = None
    scenario = load_scenario(args.scenario, **overrides)
    offboard = scenario.loop.offboard_config(
        arm=args.arm, takeoff_alt_m=args.takeoff_alt, reengage=args.reengage or scenario.loop.reengage,
        hold_after_goal_s=args.exit_after_goal,
    )
    companion = Companion(scenario, offboard=offboard)

    def stop(c: Companion) -> bool:
        """Once the vehicle holds after --exit-after-goal (the sequencer hands it back), or on giving up."""
        return c.sequencer.phase.name in ("HELD", "GAVE_UP")

    link = open_link(args.connect, tlog=args.tlog, clock=microsecond_clock)
    started = microsecond_clock()
    try:
        stats = run_realtime(companion, link, duration_s=args.duration, stop=stop, clock=microsecond_clock)
    except KeyboardInterrupt:
        stats = None
    finally:
        link.close()
    report = companion_report(companion)
    for key in ("events", "failsafe_events"):  # seconds since the start of this run, not epoch
        report[key] = [(round(t - started, 2), text) for t, text in report[key]]
    if report.get("goal_reached_companion_t_s") is not None:
        report["goal_reached_companion_t_s"] = round(report["goal_reached_companion_t_s"] - started, 2)
    if stats is not None:
        report["ticks"], report["late_ticks"] = stats.ticks, stats.late_ticks
    if args.json:
        print(json.dumps(report, indent=2, default=str))
    else:
        print(format_report(report), file=sys.stdout)
    return 0 if companion.sequencer.phase.name != "GAVE_UP" else 1
