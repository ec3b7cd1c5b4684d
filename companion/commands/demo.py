"""``companion demo``: the paper's scenarios flown by the companion against the bundled simulator."""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

from companion.commands._loopback import free_udp_port, wait_for_udp_listener
from companion.commands._argtypes import integer_at_least, positive_number, scenario_file, seed
from companion.commands._view import add_view_arguments, open_view
from companion.errors import ConfigError
from companion.commands._defaults import COORDINATION_MODES, FORMULATIONS, MAX_SYSTEMS, TAKEOVER_CHOICES

def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo",
        help="fly one of the paper's scenarios in the bundled simulator and print a summary",
        description=(
            "Run mavsim and the companion together. By default in lockstep (one process, the same "
            "MAVLink bytes through an in-memory link, deterministic for a seed); with --realtime as two "
            "processes over loopback UDP, like PX4 SITL."
        ),
    )
    p.add_argument("scenario", nargs="?", default="antipodal", type=scenario_file,
                   help="a shipped scenario's name (antipodal, corridor, single_obstacle, antipodal_px4sim, ...) "
                        "or a scenario .toml")
    p.add_argument("--seed", type=seed, default=0, help="simulator noise seed (default 0)")
    p.add_argument("--formulation", default=None, choices=FORMULATIONS, help="planner formulation (hyperplane, paper, deterministic, bhattacharyya)")
    p.add_argument("--no-c-max", action="store_true", help="drop the scenario's c_max upper bound")
    p.add_argument("--out", default=None, metavar="DIR", help="keep the tlogs, the ground-truth summary and the figures here (summary.json; --realtime: and mavsim's 10 Hz truth trace, truth_trace.jsonl)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--realtime", action="store_true", help="two processes over loopback UDP in real time")
    p.add_argument("--speed", type=positive_number, default=1.0, help="with --realtime: simulated seconds per wall second of mavsim (default 1)")
    p.add_argument("--signing-key-file", metavar="FILE", help="with --realtime: both programs sign with the key in FILE")
    p.add_argument("--signing-key-env", metavar="NAME",
                   help="with --realtime: both programs sign with the key in environment variable NAME")
    p.add_argument("--crowd", type=integer_at_least(0), default=0, metavar="N",
                   help=f"with --realtime: N extra stationary systems (at most {MAX_SYSTEMS}) report from 6-10 m beside the route "
                        "to the companion's obstacle port")
    p.add_argument("--drones", type=integer_at_least(1), default=1, metavar="N",
                   help="fly N drones (2 to 16), each with its own simulated autopilot and companion, the "
                        "scenario's start and goal rotated about their midpoint for each (the swap: "
                        "`demo swap --drones 4`); with --realtime mavsim --vehicles N and N companion fly processes "
                        "over loopback UDP, each with its fleet links (docs/FLEET.md)")
    p.add_argument("--takeover", default=None, choices=TAKEOVER_CHOICES,
                   help="a mission scenario (mission_survey): always flies it in OFFBOARD (the default); watch lets the "
                        "simulated autopilot fly it and announces predicted conflicts; guard lets it fly and takes over "
                        "on them (lockstep; docs/MISSIONS.md)")
    p.add_argument("--coordination", default=None, choices=COORDINATION_MODES,
                   help="with --drones: how the drones use each other's announced plans (default: the scenario's [fleet])")
    add_view_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    scenario = Path(args.scenario)  # resolved by the parser (scenario_file)
    overrides = {}
    if args.formulation:
        overrides["formulation"] = args.formulation
    if args.no_c_max:
        overrides["c_max"] = None
    from companion.offline.scenario_file import load_both  # imports mavsim: only the offline tools do

    companion_scenario, _ = load_both(scenario, **overrides)  # both programs' sections, before anything starts
    if not args.realtime and (args.signing_key_file or args.signing_key_env):
        raise ConfigError("signing is for the UDP links of --realtime; the lockstep demo has none")
    _check_signing_key(args)
    out = Path(args.out) if args.out else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    if args.crowd and not args.realtime:
        raise ConfigError("--crowd needs --realtime")
    if args.takeover is not None and (args.realtime or args.drones > 1):
        raise ConfigError("--takeover is for the lockstep demo of one drone (companion fly --takeover in real time)")
    if args.crowd > MAX_SYSTEMS:
        raise ConfigError(f"--crowd: at most {MAX_SYSTEMS} systems, got {args.crowd}")
    if args.drones > 1 or args.coordination:
        from companion.commands._demo_fleet import run_fleet

        return run_fleet(scenario, args, overrides, out)
    summary = (_run_realtime(scenario, args, overrides, out) if args.realtime
               else _run_lockstep(scenario, args, overrides, out, companion_scenario.offboard))
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        from companion.offline.report import format_report

        print(format_report(summary))
        if summary.get("goal_reached") is False:
            _say_why_not(scenario)
        if out is not None:
            print(f"outputs in {out}/")
    return _realtime_failure(summary)


def _say_why_not(scenario: Path) -> None:
    """After "goal reached False": the scenario's own description, which says when it is not
    meant to reach its goal in a closed loop (``single_obstacle``: one plan's terminal-only cost)."""
    from companion.loop.config import load_scenario

    description = load_scenario(scenario).description
    if description:
        print(f"the scenario says: {description}")


def _check_signing_key(args: argparse.Namespace) -> None:
    """Read the signing key once here, so a bad one is this command's one-line error (exit 2)
    rather than a child process's, which the real-time demo would only report as an empty summary."""
    from companion.mavlink.signing import SigningKeyError, load_signing_key

    try:
        load_signing_key(args.signing_key_file, args.signing_key_env)
    except SigningKeyError as exc:
        raise ConfigError(str(exc)) from None


def _realtime_failure(summary: dict) -> int:
    """0, or 1 with one line on stderr when a real-time demo's ``companion fly`` or mavsim failed."""
    for key, program in (("fly_error", "companion fly"), ("sim_error", "mavsim")):
        if summary.get(key):
            last = [line for line in str(summary[key]).splitlines() if line.strip()]
            print(f"companion demo: error: {program} failed: {last[-1] if last else 'no output'}", file=sys.stderr)
            return 1
    return 0


def _run_lockstep(scenario: Path, args: argparse.Namespace, overrides: dict, out: Path | None,
                  scenario_offboard) -> dict:
    """The lockstep demo; ``scenario_offboard`` is the scenario's [offboard] section (used with --takeover)."""
    from companion.offline.harness import run_lockstep  # imports mavsim: only the demo and campaign do

    from companion.offline.harness import LOCKSTEP_EPOCH_S

    view = open_view(args, threaded=False, time_offset_s=LOCKSTEP_EPOCH_S)
    offboard, path = None, []
    if getattr(args, "takeover", None) is not None:
        import dataclasses

        offboard = dataclasses.replace(scenario_offboard, takeover=args.takeover,
                                       arm=args.takeover != "always" or scenario_offboard.arm)

    def after_tick(companion, t_s: float, outbox) -> None:
        est = companion.perception.drone.state   # the whole flight, the autopilot's parts too, for the top view
        if est is not None:
            path.append(est.position.copy())
        if view is not None:
            view(companion, t_s, outbox)

    t0 = time.perf_counter()
    try:
        result = run_lockstep(
            scenario,
            seed=args.seed,
            tlog_path=out / "companion.tlog" if out else None,
            sim_tlog_path=out / "mavsim.tlog" if out else None,
            after_tick=after_tick,
            offboard=offboard,
            **overrides,
        )
    finally:
        if view is not None:
            view.close()
    summary = result.summary()
    summary["wall_time_s"] = round(time.perf_counter() - t0, 2)
    if view is not None:
        summary["view"] = view.summary(summary["wall_time_s"])
    if out is not None:
        (out / "truth.json").write_text(json.dumps(result.truth, indent=2, default=str))
        (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
        try:
            from companion.plots.flight_figures import write_flight_figures
        except ImportError:  # figures module not present in this build
            summary["figures"] = []
        else:
            summary["figures"] = [str(p) for p in write_flight_figures(result.companion, out, truth=result.truth,
                                                                       path=path[::5])]
    return summary


_FLY_START_S = 60.0
_PORT_ATTEMPTS = 3  # fly started on fresh ports when one picked as free was taken meanwhile


def _crowd(scenario: Path, n: int, seed: int, target_port: int, clock_port: int):
    """Start ``n`` stationary systems beside the scenario's route (see :mod:`companion.offline.crowd`)."""
    import tomllib

    import numpy as np

    from companion.offline.crowd import Crowd, positions_off_route

    data = tomllib.loads(scenario.read_text())
    start = np.asarray(data.get("vehicle", {}).get("start_ned_m", [0.0, 0.0, -5.0]), dtype=float)
    goal = np.asarray(data["mission"]["goal_ned_m"], dtype=float)
    return Crowd(positions_off_route(start, goal, n, seed=seed), ("127.0.0.1", target_port), clock_port).start()


class _Ports(NamedTuple):
    """Loopback ports of one real-time demo: mavsim's links to fly and to the ground station, and its obstacle link."""

    api: int
    gcs: int
    api_local: int
    gcs_local: int
    obstacle: int
    obstacle_local: int

    @classmethod
    def pick(cls) -> "_Ports":
        return cls(*(free_udp_port() for _ in cls._fields))


def _start_fly(scenario: Path, args: argparse.Namespace, overrides: dict, out: Path | None, ports: _Ports,
               fly_duration_s: float) -> tuple[subprocess.Popen, list[str]]:
    """Start ``companion fly`` on ``ports`` and wait (bounded) until it listens; its process and mavsim's command.

    fly goes first: mavsim's clock starts when it does, and a companion still importing
    would find the scenario's obstacles already on their way.
    """
    api_port, gcs_port, api_local, gcs_local, obstacle_port, obstacle_local = ports
    sim_cmd = [
        sys.executable, "-m", "mavsim.cli", "--scenario", str(scenario), "--seed", str(args.seed),
        "--api-port", str(api_port), "--gcs-port", str(gcs_port), "--api-local-port", str(api_local),
        "--gcs-local-port", str(gcs_local), "--obstacle-port", str(obstacle_port),
        "--obstacle-local-port", str(obstacle_local), "--speed", str(args.speed), "--json",
    ]
    fly_cmd = [
        sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{api_port}", "--scenario", str(scenario),
        "--obstacles", f"udpin:127.0.0.1:{obstacle_port}",
        "--exit-after-goal", "1.0", "--duration", f"{fly_duration_s:.1f}", "--json",
    ]
    if out is not None:
        sim_cmd += ["--tlog", str(out / "mavsim.tlog"), "--truth-trace", str(out / "truth_trace.jsonl")]
        fly_cmd += ["--tlog", str(out / "companion.tlog")]
    if overrides.get("formulation"):
        fly_cmd += ["--formulation", overrides["formulation"]]
    if "c_max" in overrides:
        fly_cmd += ["--no-c-max"]
    if args.view is not None:
        fly_cmd += ["--view", f"{args.view[0]}:{args.view[1]}"]
    if args.mcap is not None:
        fly_cmd += ["--mcap", str(args.mcap)]
    for flag, value in (("--signing-key-file", args.signing_key_file), ("--signing-key-env", args.signing_key_env)):
        if value is not None:  # the key itself never appears on a command line
            sim_cmd += [flag, value]
            fly_cmd += [flag, value]
    fly = subprocess.Popen(fly_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_udp_listener(api_port, fly, _FLY_START_S)
    wait_for_udp_listener(obstacle_port, fly, _FLY_START_S)  # opened right after the autopilot link
    return fly, sim_cmd


def _run_realtime(scenario: Path, args: argparse.Namespace, overrides: dict, out: Path | None) -> dict:
    """mavsim and ``companion fly`` as two processes over loopback UDP; every wait is bounded.

    ``fly`` gets ``--duration`` (the scenario's duration plus 30 s) so it ends by itself;
    should it not, it is stopped after another 60 s and the summary says so.
    """
    from companion.loop.config import load_scenario

    fly_duration_s = load_scenario(scenario).duration_s / max(args.speed, 1e-3) + 30.0
    for attempt in range(1, _PORT_ATTEMPTS + 1):
        ports = _Ports.pick()
        fly, sim_cmd = _start_fly(scenario, args, overrides, out, ports, fly_duration_s)
        if fly.poll() is None:
            break
        # fly ended before it listened: a port picked as free was taken before fly bound it
        # (the pick and the bind are separate moments), or fly refused its arguments.
        _, err = fly.communicate()
        if "Address already in use" not in err or attempt == _PORT_ATTEMPTS:
            return {"mode": "realtime", "fly_error": err[-2000:]}
    sim = subprocess.Popen(sim_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    crowd = None
    fly_error = None
    try:
        if args.crowd:
            crowd = _crowd(scenario, args.crowd, args.seed, ports.obstacle, ports.gcs)  # on the obstacle link, as a perception source would
        try:
            fly_out, fly_err = fly.communicate(timeout=fly_duration_s + 60.0)
        except subprocess.TimeoutExpired:
            fly.kill()
            fly_out, fly_err = fly.communicate()
            fly_error = f"companion fly did not end within {fly_duration_s + 60.0:.0f} s and was stopped"
    finally:
        if fly.poll() is None:
            fly.kill()
            fly.communicate()
        if crowd is not None:
            crowd.stop()
        sim.send_signal(signal.SIGINT)  # mavsim prints its ground-truth summary on SIGINT
        try:
            sim_out, sim_err = sim.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim_out, sim_err = sim.communicate()
    if fly_out.strip().startswith("{"):
        summary = json.loads(fly_out)
    else:
        summary = {"fly_error": fly_error or fly_err[-2000:]}
    try:
        truth = json.loads(sim_out[sim_out.index("{"):]) if "{" in sim_out else {}
    except json.JSONDecodeError:
        truth = {}
    # No truth (mavsim failed to report): its keys stay out rather than read "no collision".
    from companion.offline.report import truth_report

    summary = {"mode": "realtime", **(truth_report(truth) if truth else {}), **summary}
    if not truth:
        summary["sim_error"] = (sim_err or "mavsim printed no summary")[-2000:]
    if crowd is not None:
        summary["crowd_systems"] = args.crowd
        summary["crowd_reports_sent"] = crowd.stats.sent
    if out is not None:
        (out / "truth.json").write_text(json.dumps(truth, indent=2, default=str))
        (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary
