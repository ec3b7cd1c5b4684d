"""``companion fly``: fly a scenario's mission against a live autopilot (PX4 SITL, mavsim, a vehicle)."""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import json
import logging
import os
import signal
import sys

from companion.commands._argtypes import (
    connection_string,
    fence_file,
    goal_spec,
    mission_source,
    integer_at_least,
    non_negative_seconds,
    output_file,
    positive_number,
    positive_seconds,
    scenario_file,
    tlog_megabytes,
)
from companion.commands._defaults import DEFAULT_URL, FORMULATIONS, TAKEOVER_CHOICES
from companion.commands._flight_flags import goal_given, goal_keywords, offboard_settings, planner_overrides
from companion.commands._view import add_view_arguments, open_view
from companion.errors import CompanionError, ConfigError
from companion.realtime.stream_priority import STREAM_FIFO_PRIORITY, stream_priority

logger = logging.getLogger(__name__)

_PLANNER_START_S = 30.0
#: Replan records a flight keeps (the latest; about 7 KB each, 3.3 a second: 90 s, 2 MB): the
#: live view draws the newest, the report sums every replan (``Companion.tally``).
REPLAN_HISTORY = 300
#: The tlog's disk bound by default (MB): the 30 min patrol of `make soak` writes 39.5 MB (docs/REALTIME.md).
TLOG_MAX_MB = 1000.0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "fly",
        help="fly a scenario's mission over MAVLink in real time",
        description=(
            "Connect to a PX4 or ArduPilot (ArduCopter) autopilot, stream velocity setpoints in its offboard mode "
            "(PX4 OFFBOARD, ArduCopter GUIDED; confirmed from the HEARTBEAT) and fly the scenario's mission around "
            "the obstacles heard on the link. ArduCopter is first waited for (its EKF's absolute position), asked "
            "for its streams, switched to GUIDED, armed and taken off in GUIDED. Without "
            "--arm the companion does not arm: it waits for the pilot to arm, then streams setpoints and "
            "requests OFFBOARD. If the vehicle leaves OFFBOARD, the companion stops commanding. "
            "Ctrl-C or SIGTERM hands the vehicle back (Hold, while the setpoints still stream) before "
            "stopping; a second one stops at once. Exit codes: 0 goal reached, 1 error (the sequence gave up), "
            "2 bad input, 3 stopped (handed back, or never in control, or handed back after braking on trouble), 4 stopped without Hold confirmed, "
            "5 pilot took over, 6 link lost (or no autopilot heard), 7 the autopilot's own failsafe took the vehicle "
            "out of OFFBOARD (after link silence, or shown by its HEARTBEAT)."
        ),
    )
    p.add_argument("--connect", type=connection_string, default=DEFAULT_URL,
                   help=f"pymavlink connection string: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, or a serial "
                        f"device DEVICE[,BAUD] such as /dev/ttyACM0 or /dev/ttyUSB0,921600 (57600 baud unless given) "
                        f"(default {DEFAULT_URL})")
    p.add_argument(
        "--obstacles", action="append", type=connection_string, default=[], metavar="URL",
        help="receive-only obstacle link (pymavlink connection string, e.g. udpin:0.0.0.0:14601); repeatable; "
        "added to the scenario's [traffic] obstacle_links",
    )
    p.add_argument(
        "--fleet", action="append", type=connection_string, default=[], metavar="URL",
        help="a link to the other drones of a fleet (e.g. udpin:0.0.0.0:15001 to hear them, udpout:10.0.0.2:15001 to "
        "tell one); repeatable: this drone's state and plan go out on every link that can send to all it hears, "
        "the others' come in on all; [fleet] says how they are used (docs/FLEET.md). Never the autopilot's link",
    )
    p.add_argument("--scenario", type=scenario_file,
                   help="scenario TOML (mission, planner, estimator, map) or a shipped scenario's name; required unless --identify")
    p.add_argument("--goal", type=goal_spec, default=None, metavar="FRAME:A,B,C",
                   help="where to fly instead of the scenario's [mission] goal: ned:N,E,D (local NED m), home:N,E,U "
                        "(m from home), geo:LAT,LON,ALTamsl or geo:LAT,LON,ALTrel (degrees; altitude AMSL or above "
                        "home); placed through the vehicle's GPS_GLOBAL_ORIGIN / HOME_POSITION before arming")
    p.add_argument("--mission", type=mission_source, default=None, metavar="FILE|vehicle",
                   help="fly a mission's waypoints instead of one goal: a QGroundControl .plan or QGC WPL 110 file "
                        "(uploaded to the vehicle first), or 'vehicle' (the mission stored on it, downloaded); "
                        "docs/MISSIONS.md")
    p.add_argument("--fence", type=fence_file, default=None, metavar="FILE|vehicle",
                   help="keep inside a geofence: a QGroundControl .plan file's, or 'vehicle' (the fence stored on "
                        "the autopilot, downloaded); its inclusion and exclusion polygons and circles, placed through "
                        "the vehicle's origin (default: the scenario's [mission] fence_file, or the mission file's own fence)")
    p.add_argument("--identify", action="store_true",
                   help="instead of a mission, fly the identification velocity steps (about 75 s, 45 m north) in "
                        "OFFBOARD (PX4) or GUIDED (ArduCopter), hand back to Hold or LOITER and record --tlog for "
                        "`companion identify`")
    p.add_argument("--target-system", type=integer_at_least(1), default=None, metavar="N",
                   help="MAVLink system id of the only vehicle to command (default: the scenario's [offboard] "
                        "target_system, else the first autopilot heard; --arm refuses when several are heard)")
    p.add_argument("--autopilot", choices=("auto", "px4", "ardupilot"), default=None,
                   help="the kind of autopilot to fly: px4 (OFFBOARD), ardupilot (ArduCopter, GUIDED), or auto: "
                        "whichever the HEARTBEAT announces (default: the scenario's [offboard] autopilot, else auto)")
    p.add_argument("--arm", action="store_true", help="arm the vehicle if it is disarmed")
    p.add_argument("--takeoff-alt", type=positive_number, default=None, metavar="M", help="take off to M metres above home first")
    p.add_argument("--reengage", action="store_true", help="re-request OFFBOARD after the pilot took over, and take over a vehicle found armed in "
                        "a failsafe at start, as after a restart (default: never)")
    p.add_argument("--takeover", choices=TAKEOVER_CHOICES, default=None,
                   help="always: fly the whole flight in OFFBOARD (GUIDED); watch: never command, let the autopilot fly "
                        "its mission (started with --arm, else by the operator) and warn of predicted conflicts on its "
                        "path; guard: as watch, and take over in OFFBOARD on a predicted conflict, fly round it and give "
                        "the vehicle back to its mission once the path is clear (watch and guard need --mission; "
                        "docs/MISSIONS.md) (default: the scenario's [offboard] takeover, else always)")
    p.add_argument("--formulation", default=None, choices=FORMULATIONS, help="planner formulation (overrides the scenario)")
    p.add_argument("--no-c-max", action="store_true", help="drop the scenario's c_max upper bound")
    p.add_argument("--tlog", type=output_file, default=None, help="record the link to this tlog")
    p.add_argument("--tlog-max-mb", type=tlog_megabytes, default=TLOG_MAX_MB, metavar="MB",
                   help=f"disk the tlog may take (MB): past it the tlog goes on in numbered files (flight.0001.tlog, "
                        f"...) and the first and latest are kept (default {TLOG_MAX_MB:g}; 0: no bound)")
    p.add_argument("--duration", type=positive_seconds, default=None, metavar="S",
                   help="stop after S wall seconds (handing the vehicle back first, as on Ctrl-C)")
    p.add_argument("--hand-back-timeout", type=non_negative_seconds, default=5.0, metavar="S",
                   help="on a stop, wait at most S seconds for the HEARTBEAT to show Hold (default 5)")
    p.add_argument("--linger", type=non_negative_seconds, default=3.0, metavar="S",
                   help="after the pilot took over, keep recording S seconds, then exit (default 3)")
    p.add_argument("--exit-after-goal", type=non_negative_seconds, default=None, metavar="S",
                   help="S seconds after the goal is reached, once the vehicle is settled at it (at most "
                        "[offboard] goal_settle_max_s, 10 s, more), switch it to Hold (AUTO.LOITER) and stop "
                        "once the HEARTBEAT shows it holding")
    p.add_argument("--signing-key-file", metavar="FILE",
                   help="MAVLink 2 signing: the 32-byte key as 64 hex digits in FILE (sign all, reject unsigned)")
    p.add_argument("--signing-key-env", metavar="NAME",
                   help="MAVLink 2 signing: the key (64 hex digits) in environment variable NAME")
    p.add_argument("--no-realtime-priority", action="store_true",
                   help="keep the setpoint stream in the ordinary scheduling class (default: SCHED_FIFO "
                        f"priority {STREAM_FIFO_PRIORITY} where permitted, as well as nice -10)")
    p.add_argument("--json", action="store_true", help="print the run report as JSON")
    add_view_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.identify:
        from companion.commands.fly_identify import run as fly_identification

        return fly_identification(args)
    if not args.scenario:
        raise ConfigError("--scenario FILE is required (unless --identify)")
    if args.connect in args.fleet:
        raise ConfigError(f"--fleet {args.connect}: that is the autopilot's link (--connect); a fleet's announcements "
                          "never go there (PX4 fuses any ODOMETRY it hears as its own vision)")
    # imported here, not with the parser: numpy, scipy, filterpy, osqp, numba and pymavlink
    from companion.core import jit
    from companion.loop.app import Companion
    from companion.realtime.stream import PlanWorker, run_realtime
    from companion.realtime.run_end import RunEnd, RunEndConfig
    from companion.realtime.clock import SteadyUnixClock
    from companion.realtime.service import ServiceNotifier
    from companion.loop.intake.traffic_config import FLEET_LINK, obstacle_link_name
    from companion.mavlink import messages
    from companion.mavlink.link import open_link
    from companion.mavlink.signing import SigningKeyError, load_signing_key
    from companion.mavlink.tlog import TlogWriter
    from companion.offline.report import companion_report, format_report
    from companion.offline.scenario_file import load_both

    scenario, _ = load_both(args.scenario, goal_elsewhere=goal_given(args),
                            **planner_overrides(args))  # mavsim's sections too: never accept what mavsim rejects
    offboard = offboard_settings(scenario.offboard, args, scenario.mission)
    try:
        signing_key = load_signing_key(args.signing_key_file, args.signing_key_env)
    except SigningKeyError as exc:
        raise ConfigError(str(exc)) from None
    stats = None
    # Unix time in whole microseconds (what a tlog stores: a flight replays tick for tick), advancing
    # with the monotonic clock: a step of the system clock (a time sync) moves nothing here
    microsecond_clock = SteadyUnixClock()
    with contextlib.ExitStack() as resources:  # each closed once, in reverse order, however the run ends
        tlog = (TlogWriter(args.tlog, max_bytes=int(args.tlog_max_mb * 1e6) if args.tlog_max_mb > 0 else None)
                if args.tlog else None)  # the stream writes it, in handling order
        if tlog is not None:
            resources.callback(tlog.close)
        link = open_link(args.connect, clock=microsecond_clock, signing_key=signing_key)
        resources.callback(link.close)
        # Say we are here at once (a peer that waits for a companion's HEARTBEAT hears it now); the
        # stream's own 1 Hz HEARTBEATs follow from its first tick, once the planner is up.
        link.send(messages.companion_heartbeat(), t_s=microsecond_clock())
        # The compiled kernels, loaded (or compiled) before the planning process is forked: it
        # inherits them and is ready at once, instead of both processes loading them side by side.
        jit.warm_up()
        worker = PlanWorker(scenario.planner)  # a planning process beside the setpoint stream
        resources.callback(worker.close)
        if not worker.wait_ready(_PLANNER_START_S):
            raise CompanionError(f"the planning process did not start within {_PLANNER_START_S:.0f} s")
        companion = Companion(scenario, offboard=offboard, planning=worker, fleet=bool(args.fleet),
                              replan_history=REPLAN_HISTORY, **goal_keywords(args, scenario))
        run_end = RunEnd(RunEndConfig(duration_s=args.duration, hand_back_timeout_s=args.hand_back_timeout,
                                      linger_s=args.linger))
        # the fleet's links: the other drones' announcements in (tlogged as traffic), ours out
        fleet_links = []
        for url in args.fleet:
            fleet_links.append(open_link(url, clock=microsecond_clock, signing_key=signing_key, name=FLEET_LINK))
            resources.callback(fleet_links[-1].close)
        # receive-only obstacle links: their traffic goes into the same tlog, written by the stream
        obstacle_links = []
        for i, url in enumerate((*scenario.traffic.obstacle_links, *args.obstacles)):
            obstacle_links.append(open_link(url, clock=microsecond_clock, signing_key=signing_key,
                                            name=obstacle_link_name(i), receive_only=True))
            resources.callback(obstacle_links[-1].close)
        # the view's thread and server started before the stream's priority is raised: they keep the normal one
        view = open_view(args, threaded=True)
        if view is not None:
            resources.callback(view.close)
        # the stream's priority for the stream only; the planning process, started above, keeps its own
        stream_nice, stream_fifo = resources.enter_context(
            stream_priority(fifo_priority=None if args.no_realtime_priority else STREAM_FIFO_PRIORITY))
        # systemd (Type=notify): ready now, the loop's status, the watchdog from each tick
        service = ServiceNotifier.from_environment()
        resources.callback(service.close)
        if service.watchdog_s is not None:  # killed by the watchdog (SIGABRT): every thread's stack to the journal
            faulthandler.enable()
        started = microsecond_clock()
        service.ready(f"waiting for an autopilot on {args.connect}")
        planner_cpu_start = process_cpu_s(worker.pid)
        with _stop_on_signals(run_end, service):
            stats = run_realtime(companion, link, stop=_saying_what_it_waits_for(run_end, args.connect, started),
                                 clock=microsecond_clock, tlog=tlog, obstacle_links=obstacle_links,
                                 after_tick=_each_after_tick(view, service.after_tick if service.enabled else None),
                                 fleet_links=fleet_links)
        planner_cpu_end = process_cpu_s(worker.pid)
        outcome = run_end.outcome(companion)
        service.stopping(f"{outcome.text} (exit {outcome.code})")
    if companion.goal_error is not None:
        print(f"companion fly: {companion.goal_error}", file=sys.stderr)
    report = {"outcome": outcome.text, "exit_code": outcome.code, "stop_requested_by": run_end.stop_reason,
              **companion_report(companion)}
    for key in ("events", "alerts"):  # seconds since the start of this run, not epoch
        report[key] = [(round(t - started, 2), text) for t, text in report[key]]
    if report.get("goal_reached_companion_t_s") is not None:
        report["goal_reached_companion_t_s"] = round(report["goal_reached_companion_t_s"] - started, 2)
    for key in ("mission_items_reached_t_s", "autopilot_items_reached_t_s"):
        if key in report:
            report[key] = [round(t - started, 2) for t in report[key]]
    for row in (*report.get("watch_conflicts", []), *report.get("takeovers", []), *report.get("mission_items_reached_by", [])):
        for key in ("start_s", "end_s", "offboard_s", "t_s"):
            if row.get(key) is not None:
                row[key] = round(row[key] - started, 2)
    if stats is not None:
        report.update(stats.summary())
        report["wall_s"] = round(stats.wall_s, 2)
        report.update(_resources_used(stats.wall_s))
        # both processes from the stream's first tick to its last: what flying costs, start-up left out
        if planner_cpu_start is not None and planner_cpu_end is not None and stats.wall_s > 0:
            report["cpu_share_in_flight"] = round((stats.cpu_s + planner_cpu_end - planner_cpu_start) / stats.wall_s, 3)
    report["planner_process"] = {
        "solved": worker.stats.solved, "superseded": worker.stats.superseded, "errors": worker.stats.errors,
        "max_solve_ms": round(worker.stats.max_solve_s * 1e3, 1),
        "max_send_ms": round(worker.stats.max_send_s * 1e3, 1), "max_receive_ms": round(worker.stats.max_receive_s * 1e3, 1),
    }
    if view is not None:
        report["view"] = view.summary(stats.wall_s if stats is not None else None)
    report["stream_nice"] = stream_nice
    report["stream_fifo_priority"] = stream_fifo
    report["signing"] = signing_key is not None
    report["signature_rejected"] = link.stats.signature_rejected
    if tlog is not None:
        report["tlog_bytes"] = tlog.bytes_written
        report["tlog_segments_deleted"] = tlog.segments_deleted
    if args.json:
        print(json.dumps(report, indent=2, default=str))
    else:
        print(format_report(report), file=sys.stdout)
    return outcome.code


def process_cpu_s(pid: int | None) -> float | None:
    """CPU time (user + system, s) process ``pid`` has used so far, from ``/proc/PID/stat``;
    None where that cannot be read (no such process, not Linux)."""
    if pid is None:
        return None
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()   # after the command name, which may hold spaces
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")   # utime, stime (fields 14, 15)
    except (OSError, IndexError, ValueError):
        return None


def _resources_used(wall_s: float) -> dict:
    """CPU (this process and its planning process, which has ended) and the largest resident memory of each."""
    import resource

    me, planner = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = me.ru_utime + me.ru_stime + planner.ru_utime + planner.ru_stime
    return {"cpu_s": round(cpu_s, 2), "cpu_share": round(cpu_s / wall_s, 3) if wall_s > 0 else None,
            "max_rss_mb": round(me.ru_maxrss / 1024.0, 1),            # Linux: kibibytes
            "planner_max_rss_mb": round(planner.ru_maxrss / 1024.0, 1)}


#: How often ``fly`` says it is still waiting for an autopilot (s).
_WAITING_SAY_S = 5.0


def _saying_what_it_waits_for(run_end, url: str, started: float):
    """``run_end`` as the stream's stop check, saying on stderr every 5 s that no autopilot was heard yet."""
    said = [started]

    def stop(companion, t_s: float) -> bool:
        if companion.autopilot is None and t_s - said[0] >= _WAITING_SAY_S:
            said[0] = t_s
            print(f"companion fly: no autopilot heard on {url} after {t_s - started:.0f} s "
                  "(is it sending to this port? Ctrl-C stops)", file=sys.stderr)
        return run_end(companion, t_s)

    return stop


def _each_after_tick(*hooks):
    """One ``after_tick`` calling each hook given (None: left out) in turn; None if there is none."""
    hooks = tuple(h for h in hooks if h is not None)
    if len(hooks) <= 1:
        return hooks[0] if hooks else None

    def after_tick(companion, t_s: float, outbox) -> None:
        for hook in hooks:
            hook(companion, t_s, outbox)

    return after_tick


@contextlib.contextmanager
def _stop_on_signals(run_end, service):
    """SIGINT and SIGTERM become stop requests of ``run_end`` (the stream hands back first); restored after.
    systemd hears ``STOPPING=1`` at the first (``service``, a :class:`ServiceNotifier`)."""
    def request(signum, _frame) -> None:
        name = signal.Signals(signum).name
        run_end.request_stop(name)
        if len(run_end.requests) == 1:
            service.stopping(f"{name}: handing the vehicle back")
            print(f"companion fly: {name}: handing the vehicle back (again to stop at once)", file=sys.stderr)

    previous = {sig: signal.signal(sig, request) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
