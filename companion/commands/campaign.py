"""``companion campaign``: Monte Carlo safety campaign over randomised encounters.

Draws ``--episodes`` encounters of a ``--family`` from ``--seed``, flies each one with
every method of ``--methods`` in lockstep (mavsim plus the companion over MAVLink
bytes), in parallel over ``--workers`` processes or on a Dask cluster (``--scheduler``),
appends every finished run to a results file (``--results``; ``--resume`` continues it),
and prints one table row per method computed from that file: collisions with a 95 %
Clopper-Pearson interval, the per-step collision frequency against the bound
``Phi(-r_min)``, the share of steps below ``c_min``, goal reached, time to goal, planner
failures, slack use and solve times. ``--episode I`` re-runs episode ``I`` alone (same
encounter, same simulator seed).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

from companion.commands._argtypes import (
    integer_between,
    non_negative_seconds,
    open_unit_interval,
    output_file,
    seconds_up_to,
    seed,
)
from companion.commands._defaults import (
    COORDINATION_MODES,
    DEFAULT_DURATION_S,
    EKF_CORRELATION_S,
    FAMILIES,
    MAX_DURATION_S,
    MAX_EPISODES,
    METHODS,
    PROGRESS_MODES,
    SOLVERS,
    VEHICLES,
    WORKERS_PER_CPU,
)
from companion.commands._help import DefaultsHelpFormatter
from companion.errors import ConfigError

logger = logging.getLogger(__name__)

QUIET_LOGGERS = ("mavsim", "estimator", "companion.loop.app", "companion.core.planner", "companion.mavlink.offboard",
                 "companion.mavlink.link", "companion.loop.mission_watch", "companion.loop.mission_goal",
                 "companion.loop.mission_guard", "companion.loop.fence_source")
#: --family mission's methods: the planner formulations guarding, and the autopilot alone
MISSION_METHODS = ("hyperplane", "deterministic", "alone")


def _methods(text: str) -> list[str]:
    names = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in names if m not in METHODS and m not in COORDINATION_MODES and m not in MISSION_METHODS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"unknown method(s) {', '.join(unknown) or '(none)'}; choose from "
                                         f"{', '.join(METHODS)} (--family swap: {', '.join(COORDINATION_MODES)}; "
                                         f"--family mission: {', '.join(MISSION_METHODS)})")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"method listed twice: {text}")
    return names


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``campaign`` subcommand."""
    p = subparsers.add_parser("campaign", help="Monte Carlo safety campaign: randomised encounters, per method",
                              description=__doc__.split("\n\n")[1], formatter_class=DefaultsHelpFormatter)
    cpus = os.cpu_count() or 1
    p.add_argument("--family", choices=(*FAMILIES, "swap", "mission"), default="antipodal",
                   help="kind of encounter; swap: --drones N drones swapping places on a circle, with crossing "
                        "traffic, the methods being coordination modes (docs/FLEET.md); mission: randomised missions "
                        "in a geofence with traffic across their legs, flown by the autopilot and guarded "
                        f"(--takeover guard) with each formulation, or alone (methods {','.join(MISSION_METHODS)}; "
                        "docs/MISSIONS.md)")
    p.add_argument("--drones", type=integer_between(2, 16, "a swap of 2 to 16 drones"), default=None, metavar="N",
                   help="with --family swap: drones per episode (2 to 16)")
    p.add_argument("--episodes", type=integer_between(1, MAX_EPISODES, "the most one campaign holds"), default=20,
                   help=f"number of episodes (indices 0..N-1), at most {MAX_EPISODES}")
    p.add_argument("--methods", type=_methods, default=None,
                   help="comma-separated planner formulations (default: all); with --family swap, coordination modes "
                        f"({','.join(COORDINATION_MODES)}; default: all)",
                   metavar=",".join(METHODS))
    p.add_argument("--seed", type=seed, default=0, help="campaign seed (episode i uses default_rng([seed, i]))")
    p.add_argument("--workers", type=integer_between(1, WORKERS_PER_CPU * cpus, f"{WORKERS_PER_CPU} per CPU, {cpus} CPUs"),
                   default=None, help=f"local worker processes, at most {WORKERS_PER_CPU} per CPU "
                                      f"({WORKERS_PER_CPU * cpus} here) (default: the CPU count, {cpus})")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run the episodes on a Dask distributed cluster (e.g. tcp://10.0.0.5:8786); "
                        "needs pip install 'ogccmpc[cluster]'")
    p.add_argument("--episode", type=integer_between(0, MAX_EPISODES - 1), default=None, metavar="I",
                   help="run only episode I of this campaign (reproduce one encounter)")
    p.add_argument("--save-scenario", metavar="FILE", default=None,
                   help="with --episode: also write the episode's scenario as a TOML file (fly it with companion demo)")
    p.add_argument("--c-min", type=open_unit_interval, default=0.90, help="contour of touch that may not be crossed")
    p.add_argument("--duration", type=seconds_up_to(MAX_DURATION_S, "one hour"), default=DEFAULT_DURATION_S,
                   metavar="SECONDS", help=f"simulated seconds per episode, at most {MAX_DURATION_S:g}")
    p.add_argument("--noise-correlation", type=non_negative_seconds, default=0.0, metavar="SECONDS",
                   help="correlation time of the simulated drone position error and of every obstacle's measurement "
                        "error (Gauss-Markov, as an EKF's or a GNSS receiver's error wanders; same covariances, reported "
                        f"honestly); 0: white; {EKF_CORRELATION_S:g} s is the honest model of docs/CAMPAIGNS.md")
    p.add_argument("--vehicle", choices=VEHICLES, default="lag",
                   help="mavsim's vehicle profile: lag (0.3 s lag, the planner's own model), px4 (PX4's velocity "
                        "loop against drag) or ardupilot (ArduCopter's jerk-limited shaping, flown by mavsim's ArduPilot personality: the "
                        "companion engages it in GUIDED); the planner uses the response identified for it")
    p.add_argument("--solver", choices=SOLVERS, default="osqp",
                   help="the planner's QP backend ([planner] solver; docs/SOLVERS.md)")
    p.add_argument("--results", metavar="FILE", default=None,
                   help="results file (JSON lines, one finished run per line, appended as runs finish; "
                        "default: beside --json with the suffix .jsonl, else campaign-FAMILY-seedS.jsonl; "
                        "none with --episode)")
    p.add_argument("--resume", action="store_true",
                   help="continue the results file: run only the runs it does not hold yet")
    p.add_argument("--progress", choices=PROGRESS_MODES, default="auto",
                   help="progress bar on a terminal, a one-line log every 30 s otherwise")
    p.add_argument("--json", type=output_file, metavar="FILE", help="write the summary and per-episode rows as JSON")
    p.add_argument("--plot", metavar="DIR", help="draw the campaign figures (PNG) into DIR")
    p.set_defaults(func=run)


def results_path(args: argparse.Namespace) -> Path | None:
    """The results file: ``--results``, else beside ``--json``, else in the working directory;
    none for ``--episode I`` (re-running one encounter) unless ``--results`` names one."""
    if args.results:
        return Path(args.results)
    if args.episode is not None:
        return None
    if args.json:
        return Path(args.json).with_suffix(".jsonl")
    return Path(f"campaign-{args.family}-seed{args.seed}.jsonl")


def run(args: argparse.Namespace) -> int:
    """Run the campaign, print the table, write JSON and figures if asked."""
    from companion.offline.campaign import format_table, generate_scenario, run_campaign, write_scenario

    if not getattr(args, "verbose", 0):
        # Collisions and planner trouble are what a campaign counts: report them in the
        # table, not as hundreds of log lines from the worker processes.
        for name in QUIET_LOGGERS:
            logging.getLogger(name).setLevel(logging.ERROR)
    if args.family == "swap":
        return _run_swap(args)
    if args.save_scenario and args.episode is None:
        raise ConfigError("--save-scenario needs --episode I (which episode to save)")
    if args.family == "mission":
        return _run_mission(args)
    if args.drones is not None:
        raise ConfigError("--drones is for --family swap")
    if args.methods is None:
        args.methods = list(METHODS)
    wrong = [m for m in args.methods if m not in METHODS]
    if wrong:
        elsewhere = "a coordination mode (for --family swap)" if wrong[0] in COORDINATION_MODES else "for --family mission"
        raise ConfigError(f"--methods: {wrong[0]} is {elsewhere}; the {args.family} family's methods are "
                          f"{', '.join(METHODS)}")
    episodes = [args.episode] if args.episode is not None else range(args.episodes)
    if args.save_scenario:
        path = write_scenario(generate_scenario(args.family, args.seed, args.episode, c_min=args.c_min,
                                                duration_s=args.duration,
                                                noise_correlation_s=args.noise_correlation,
                                                vehicle=args.vehicle),
                              args.save_scenario)
        print(f"wrote {path}")
    store = results_path(args)
    result = run_campaign(args.family, episodes, args.methods, args.seed, workers=args.workers, c_min=args.c_min,
                          duration_s=args.duration, progress=args.progress, results_path=store, resume=args.resume,
                          scheduler=args.scheduler, noise_correlation_s=args.noise_correlation,
                          vehicle=args.vehicle, solver=args.solver)
    print(format_table(result))
    if store is not None:
        print(f"results: {store}")
    if args.episode is not None:
        for row in result.results:
            print(json.dumps({k: v for k, v in row.to_json(pooled=False).items() if k != "truth"}, default=float))
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result.to_json(), indent=1, default=float, allow_nan=False))
        print(f"wrote {path}")
    if args.plot:
        for path in result.plot(args.plot):
            print(f"wrote {path}")
    return _exit_code(result, store)


def _run_swap(args: argparse.Namespace) -> int:
    """``--family swap``: a fleet campaign (:mod:`companion.offline.campaign.fleet`)."""
    from companion.offline.campaign.fleet import format_fleet_table, run_fleet_campaign

    if args.drones is None:
        raise ConfigError("--family swap needs --drones N (2 to 16)")
    modes = args.methods if args.methods is not None else list(COORDINATION_MODES)
    wrong = [m for m in modes if m not in COORDINATION_MODES]
    if wrong:
        raise ConfigError(f"--methods: {', '.join(wrong)} is not a coordination mode; --family swap flies "
                          f"{', '.join(COORDINATION_MODES)}")
    for flag, used in (("--vehicle", args.vehicle != "lag"), ("--noise-correlation", args.noise_correlation > 0.0),
                       ("--solver", args.solver != "osqp"),
                       ("--plot", args.plot), ("--save-scenario", args.save_scenario)):
        if used:
            raise ConfigError(f"{flag} is not available with --family swap")
    episodes = [args.episode] if args.episode is not None else range(args.episodes)
    store = Path(args.results) if args.results else (
        None if args.episode is not None else
        Path(args.json).with_suffix(".jsonl") if args.json else Path(f"campaign-swap{args.drones}-seed{args.seed}.jsonl"))
    result = run_fleet_campaign(args.drones, episodes, modes, args.seed, workers=args.workers, c_min=args.c_min,
                                duration_s=args.duration, results_path=store, resume=args.resume,
                                scheduler=args.scheduler, progress=args.progress)
    print(format_fleet_table(result.drones, result.summary, result.c_min))
    if store is not None:
        print(f"results: {store}")
    return _json_and_errors(args, result, result.runs)


def _exit_code(result, store: Path | None) -> int:
    """0 when every run was flown and scored; else 1, with one line saying how many were not.

    A run that errored (or was lost with its worker) measured nothing: the table leaves it
    out, so a campaign that is all errors would otherwise print an empty table and succeed.
    """
    failed = [r for r in result.results if r.error is not None]
    if not failed and not result.lost:
        return 0
    total = len(result.results) + result.lost
    what = []
    if failed:
        first = failed[0]
        message = " ".join(str(first.error).split())  # one line, however the exception put it
        message = message if len(message) <= 300 else message[:297] + "..."
        what.append(f"{len(failed)} of {total} runs ended with an error (first: episode {first.episode} "
                    f"{first.method}: {message})")
    if result.lost:
        what.append(f"{result.lost} of {total} runs were lost with their worker process")
    where = f"; the runs are in {store}" if store is not None else ""
    print(f"companion campaign: error: {'; '.join(what)}{where}", file=sys.stderr)
    return 1


def _run_mission(args: argparse.Namespace) -> int:
    """``--family mission``: a mission campaign (:mod:`companion.offline.campaign.missions`)."""
    from companion.offline.campaign import write_scenario
    from companion.offline.campaign.mission_episodes import generate_mission
    from companion.offline.campaign.missions import format_mission_table, run_mission_campaign

    methods = args.methods if args.methods is not None else list(MISSION_METHODS)
    wrong = [m for m in methods if m not in MISSION_METHODS]
    if wrong:
        raise ConfigError(f"--methods: {', '.join(wrong)} is not a method of --family mission ({', '.join(MISSION_METHODS)})")
    for flag, used in (("--drones", args.drones is not None), ("--vehicle", args.vehicle != "lag"),
                       ("--noise-correlation", args.noise_correlation > 0.0), ("--solver", args.solver != "osqp"),
                       ("--duration", args.duration != DEFAULT_DURATION_S), ("--plot", args.plot)):
        if used:
            raise ConfigError(f"{flag} is not available with --family mission (each mission sets its own length)"
                              if flag == "--duration" else f"{flag} is not available with --family mission")
    if args.save_scenario:
        ep = generate_mission(args.seed, args.episode, c_min=args.c_min)
        scenario = Path(args.save_scenario)
        plan = scenario.with_suffix(".plan")
        scenario.parent.mkdir(parents=True, exist_ok=True)
        plan.write_text(json.dumps(ep.plan, indent=1))
        data = json.loads(json.dumps(ep.scenario))
        data["mission"]["plan_file"] = plan.name
        data["offboard"] = {"arm": True, "takeover": "guard"}
        print(f"wrote {write_scenario(data, scenario)} and {plan} (fly it: companion demo {scenario})")
    episodes = [args.episode] if args.episode is not None else range(args.episodes)
    store = results_path(args)
    result = run_mission_campaign(episodes, methods, args.seed, workers=args.workers, c_min=args.c_min,
                                  results_path=store, resume=args.resume, scheduler=args.scheduler,
                                  progress=args.progress)
    print(format_mission_table(result.summary, result.c_min))
    if store is not None:
        print(f"results: {store}")
    if args.episode is not None:
        for row in result.runs:
            print(json.dumps(row.to_json(), default=float))
    return _json_and_errors(args, result, result.runs)


def _json_and_errors(args: argparse.Namespace, result, runs) -> int:
    """``--json``'s file written; exit 1 (one line naming the first) when runs ended with an error, else 0."""
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result.to_json(), indent=1, default=float))
        print(f"wrote {path}")
    failed = [r for r in runs if r.error is not None]
    if failed:
        first = failed[0]
        print(f"companion campaign: error: {len(failed)} of {len(runs)} runs ended with an error (first: episode "
              f"{first.episode} {first.key[1]}: {' '.join(str(first.error).split())[:300]})", file=sys.stderr)
        return 1
    return 0
