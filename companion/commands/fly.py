"""``companion fly``: fly a scenario's mission against a live autopilot (PX4 SITL, mavsim, a vehicle)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import sys
import time

from companion.commands._argtypes import non_negative_seconds, output_file, positive_number, positive_seconds
from companion.errors import CompanionError, ConfigError
from companion.loop.app import Companion
from companion.loop.realtime import PlanWorker, run_realtime
from companion.loop.stream_priority import STREAM_FIFO_PRIORITY, stream_priority
from companion.loop.traffic_config import obstacle_link_name
from companion.mavlink.link import DEFAULT_URL, open_link
from companion.mavlink.tlog import TlogWriter
from companion.offline.report import companion_report, format_report
from companion.offline.scenario_file import load_both
from companion.mavlink.signing import SigningKeyError, load_signing_key

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
    p.add_argument(
        "--obstacles", action="append", default=[], metavar="URL",
        help="receive-only obstacle link (pymavlink connection string, e.g. udpin:0.0.0.0:14601); repeatable; "
        "added to the scenario's [traffic] obstacle_links",
    )
    p.add_argument("--scenario", help="scenario TOML (mission, planner, estimator, map); required unless --identify")
    p.add_argument("--identify", action="store_true",
                   help="instead of a mission, fly the identification velocity steps (about 75 s, 45 m north) in "
                        "OFFBOARD, switch to Hold and record --tlog for `companion identify`")
    p.add_argument("--arm", action="store_true", help="arm the vehicle if it is disarmed")
    p.add_argument("--takeoff-alt", type=positive_number, default=None, metavar="M", help="take off to M metres above home first")
    p.add_argument("--reengage", action="store_true", help="re-request OFFBOARD after the pilot took over (default: never)")
    p.add_argument("--formulation", default=None, help="planner formulation (overrides the scenario)")
    p.add_argument("--no-c-max", action="store_true", help="drop the scenario's c_max upper bound")
    p.add_argument("--tlog", type=output_file, default=None, help="record the link to this tlog")
    p.add_argument("--duration", type=positive_seconds, default=None, metavar="S", help="stop after S wall seconds")
    p.add_argument("--exit-after-goal", type=non_negative_seconds, default=None, metavar="S",
                   help="S seconds after the goal is reached, switch the vehicle to Hold (AUTO.LOITER) and stop "
                        "once the HEARTBEAT shows it holding")
    p.add_argument("--signing-key-file", metavar="FILE",
                   help="MAVLink 2 signing: the 32-byte key as 64 hex digits in FILE (sign all, reject unsigned)")
    p.add_argument("--signing-key-env", metavar="NAME",
                   help="MAVLink 2 signing: the key (64 hex digits) in environment variable NAME")
    p.add_argument("--no-realtime-priority", action="store_true",
                   help="keep the setpoint stream in the ordinary scheduling class (default: SCHED_FIFO "
                        f"priority {STREAM_FIFO_PRIORITY} where permitted, as well as nice -10)")
    p.add_argument("--json", action="store_true", help="print the run report as JSON")
    p.set_defaults(func=run)


def microsecond_clock() -> float:
    """Unix time rounded to whole microseconds: the times the loop acts on are exactly the
    times a tlog can store, so a recorded flight replays tick for tick."""
    return round(time.time() * 1e6) * 1e-6


def run(args: argparse.Namespace) -> int:
    if args.identify:
        from companion.commands.fly_identify import run as fly_identification

        return fly_identification(args)
    if not args.scenario:
        raise ConfigError("--scenario FILE is required (unless --identify)")
    overrides: dict = {"formulation": args.formulation} if args.formulation else {}
    if args.no_c_max:
        overrides["c_max"] = None
    scenario, _ = load_both(args.scenario, **overrides)  # mavsim's sections too: never accept what mavsim rejects
    offboard = dataclasses.replace(
        scenario.offboard,
        arm=args.arm or scenario.offboard.arm,
        takeoff_alt_m=scenario.offboard.takeoff_alt_m if args.takeoff_alt is None else args.takeoff_alt,
        reengage=args.reengage or scenario.offboard.reengage,
        hold_after_goal_s=args.exit_after_goal,
    )
    try:
        signing_key = load_signing_key(args.signing_key_file, args.signing_key_env)
    except SigningKeyError as exc:
        raise ConfigError(str(exc)) from None
    worker = PlanWorker(scenario.planner)  # a planning process beside the setpoint stream
    if not worker.wait_ready(_PLANNER_START_S):
        worker.close()
        raise CompanionError(f"the planning process did not start within {_PLANNER_START_S:.0f} s")
    companion = Companion(scenario, offboard=offboard, planning=worker)

    def stop(c: Companion) -> bool:
        """Once the vehicle holds after --exit-after-goal (the sequencer hands it back), or on giving up."""
        return c.sequencer.phase.name in ("HELD", "GAVE_UP")

    stats = None
    with contextlib.ExitStack() as resources:  # each closed once, in reverse order, however the run ends
        resources.callback(worker.close)
        tlog = TlogWriter(args.tlog) if args.tlog else None  # the stream writes it, in handling order
        if tlog is not None:
            resources.callback(tlog.close)
        link = open_link(args.connect, clock=microsecond_clock, signing_key=signing_key)
        resources.callback(link.close)
        # receive-only obstacle links: their traffic goes into the same tlog, written by the stream
        obstacle_links = []
        for i, url in enumerate((*scenario.traffic.obstacle_links, *args.obstacles)):
            obstacle_links.append(open_link(url, clock=microsecond_clock, signing_key=signing_key,
                                            name=obstacle_link_name(i), receive_only=True))
            resources.callback(obstacle_links[-1].close)
        # the stream's priority for the stream only; the planning process, started above, keeps its own
        stream_nice, stream_fifo = resources.enter_context(
            stream_priority(fifo_priority=None if args.no_realtime_priority else STREAM_FIFO_PRIORITY))
        started = microsecond_clock()
        try:
            stats = run_realtime(companion, link, duration_s=args.duration, stop=stop, clock=microsecond_clock,
                                 tlog=tlog, obstacle_links=obstacle_links)
        except KeyboardInterrupt:
            pass
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
        "max_send_ms": round(worker.stats.max_send_s * 1e3, 1), "max_receive_ms": round(worker.stats.max_receive_s * 1e3, 1),
    }
    report["stream_nice"] = stream_nice
    report["stream_fifo_priority"] = stream_fifo
    report["signing"] = signing_key is not None
    report["signature_rejected"] = link.stats.signature_rejected
    if args.json:
        print(json.dumps(report, indent=2, default=str))
    else:
        print(format_report(report), file=sys.stdout)
    return 0 if companion.sequencer.phase.name != "GAVE_UP" else 1
