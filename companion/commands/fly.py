"""``companion fly``: fly a scenario's mission against a live autopilot (PX4 SITL, mavsim, a vehicle)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time

from companion.commands._argtypes import positive_seconds
from companion.errors import CompanionError
from companion.loop.app import Companion
from companion.loop.config import load_scenario
from companion.loop.realtime import PlanWorker, run_realtime
from companion.mavlink.link import DEFAULT_URL, open_link
from companion.mavlink.tlog import TlogWriter
from companion.offline.report import companion_report, format_report

logger = logging.getLogger(__name__)

_PLANNER_START_S = 30.0


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
    p.add_argument("--duration", type=_finite_seconds, default=None, metavar="S", help="stop after S wall seconds")
    p.add_argument("--exit-after-goal", type=_finite_seconds, default=None, metavar="S",
                   help="S seconds after the goal is reached, switch the vehicle to Hold (AUTO.LOITER) and stop "
                        "once the HEARTBEAT shows it holding")
    p.add_argument("--json", action="store_true", help="print the run report as JSON")
    p.set_defaults(func=run)


def _finite_seconds(text: str) -> float:
    value = positive_seconds(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite seconds, got {text}")
    return value


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
    worker = PlanWorker(scenario.planner)  # a planning process beside the setpoint stream
    if not worker.wait_ready(_PLANNER_START_S):
        worker.close()
        raise CompanionError(f"the planning process did not start within {_PLANNER_START_S:.0f} s")
    companion = Companion(scenario, offboard=offboard, planning=worker)

    def stop(c: Companion) -> bool:
        """Once the vehicle holds after --exit-after-goal (the sequencer hands it back), or on giving up."""
        return c.sequencer.phase.name in ("HELD", "GAVE_UP")

    tlog = None
    try:
        tlog = TlogWriter(args.tlog) if args.tlog else None  # the stream writes it, in handling order
        link = open_link(args.connect, clock=microsecond_clock)
    except BaseException:
        worker.close()
        if tlog is not None:
            tlog.close()
        raise
    started = microsecond_clock()
    stats = None
    try:
        stats = run_realtime(companion, link, duration_s=args.duration, stop=stop, clock=microsecond_clock, tlog=tlog)
    except KeyboardInterrupt:
        pass
    finally:
        link.close()
        worker.close()
        if tlog is not None:
            tlog.close()
    report = companion_report(companion)
    for key in ("events", "failsafe_events"):  # seconds since the start of this run, not epoch
        report[key] = [(round(t - started, 2), text) for t, text in report[key]]
    if report.get("goal_reached_companion_t_s") is not None:
        report["goal_reached_companion_t_s"] = round(report["goal_reached_companion_t_s"] - started, 2)
    if stats is not None:
        report.update(stats.summary())
        report["wall_s"] = round(stats.wall_s, 2)
    report["planner_process"] = {
        "solved": worker.stats.solved, "superseded": worker.stats.superseded, "errors": worker.stats.errors,
        "max_solve_ms": round(worker.stats.max_solve_s * 1e3, 1),
    }
    if args.json:
        print(json.dumps(report, indent=2, default=str))
    else:
        print(format_report(report), file=sys.stdout)
    return 0 if companion.sequencer.phase.name != "GAVE_UP" else 1
