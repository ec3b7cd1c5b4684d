"""``mavsim traffic``: play a scenario's obstacles into a real autopilot (PX4 SITL or a vehicle).

Examples::

    mavsim traffic --scenario configs/antipodal_px4.toml --duration 120 --json     # PX4 SITL's ports
    mavsim traffic --scenario mission.toml --no-truth --autopilot-host 192.168.1.10 --record traffic.jsonl

The obstacles start moving when the autopilot's HEARTBEAT first shows it armed in OFFBOARD
(``--start now``: at once). It prints one line when it starts and one when it stops (to
stderr), and with ``--json`` the summary (:meth:`mavsim.traffic.TrafficPlayer.summary`) on
stdout: the smallest distance between the vehicle and each obstacle (SIH's ground truth
when ``--truth-port`` hears it, else the autopilot's LOCAL_POSITION_NED), the goal.

Exit status: 0 when the vehicle engaged (stopped by ``--duration``, SIGINT or SIGTERM);
1 when it never engaged; 2 on a bad scenario or argument, or a port that cannot be bound.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading

from mavsim.cli import _LOG_LEVELS, _OneLineErrorParser, _log_level, _output_file, _port, _positive, _seed
from mavsim.errors import ScenarioError, SimulationError
from mavsim.personalities import DEFAULT_PERSONALITY, PERSONALITIES
from mavsim.scenario import load_scenario
from mavsim.traffic import PlayerLinks, TrafficPlayer

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    d = PlayerLinks()
    p = _OneLineErrorParser(prog="mavsim traffic",
                            description="Play a scenario's scripted obstacles into a real autopilot's ground link "
                                        "(ADSB_VEHICLE) or the companion's obstacle link, from engagement (OFFBOARD), "
                                        "and referee the encounter")
    p.add_argument("--scenario", required=True,
                   help="scenario file with [[world.obstacles]] (transport link or adsb), or a shipped scenario's name")
    p.add_argument("--duration", type=_positive, required=True, help="wall seconds to play, then stop")
    p.add_argument("--start", choices=("offboard", "now"), default="offboard",
                   help="start the obstacles' motion when the vehicle is armed in OFFBOARD (default) or now")
    p.add_argument("--seed", type=_seed, default=0, help="measurement noise seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout at the end")
    p.add_argument("--record", type=_output_file, metavar="FILE",
                   help="write a JSON-lines trace (10 Hz: mode, obstacles' true positions, vehicle truth and estimate)")
    p.add_argument("--bind", default=d.bind, help=f"address to bind (default {d.bind})")
    p.add_argument("--gcs-local-port", type=_port, default=d.gcs_local_port,
                   help=f"our ground-station socket, where the autopilot's GCS link sends (default {d.gcs_local_port})")
    p.add_argument("--autopilot", choices=tuple(PERSONALITIES), default=DEFAULT_PERSONALITY,
                   help=f"the autopilot's kind: how its HEARTBEAT shows modes and engagement (default {DEFAULT_PERSONALITY})")
    p.add_argument("--autopilot-host", default=d.autopilot_host, help=f"autopilot host (default {d.autopilot_host})")
    p.add_argument("--autopilot-port", type=_port, default=d.autopilot_port,
                   help=f"the autopilot's GCS link port (default {d.autopilot_port}, PX4 SITL)")
    p.add_argument("--obstacle-host", default=d.obstacle_host, help=f"companion host (default {d.obstacle_host})")
    p.add_argument("--obstacle-port", type=_port, default=d.obstacle_port,
                   help=f"the companion's obstacle link (`fly --obstacles`; default {d.obstacle_port})")
    p.add_argument("--truth-port", type=_port, default=d.truth_port,
                   help=f"SIH ground truth HIL_STATE_QUATERNION port (default {d.truth_port})")
    p.add_argument("--no-truth", action="store_true", help="no ground-truth socket (a real vehicle)")
    p.add_argument("--log-level", type=_log_level, default="WARNING",
                   help=f"logging level: {', '.join(_LOG_LEVELS)} (default WARNING)")
    return p


def main(argv: list[str] | None = None) -> int:
    """``mavsim traffic``; returns the exit status."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=getattr(logging, args.log_level),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    links = PlayerLinks(args.bind, args.gcs_local_port, args.autopilot_host, args.autopilot_port,
                        args.obstacle_host, args.obstacle_port, None if args.no_truth else args.truth_port)
    try:
        scenario = load_scenario(args.scenario)
        player = TrafficPlayer(scenario, links, seed=args.seed, start=args.start, record=args.record,
                               autopilot=args.autopilot)
    except (ScenarioError, SimulationError) as exc:
        print(f"mavsim traffic: error: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    received: list[str] = []

    def handler(signum, _frame) -> None:
        received.append(signal.Signals(signum).name)
        stop.set()

    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    print(f"mavsim traffic: {len(scenario.obstacles)} obstacle(s) of {scenario.name!r}; autopilot "
          f"{args.autopilot_host}:{args.autopilot_port} from {args.bind}:{args.gcs_local_port}, obstacle link -> "
          f"{args.obstacle_host}:{args.obstacle_port}, truth "
          f"{'none' if links.truth_port is None else f'{args.bind}:{links.truth_port}'}; start "
          f"{'at OFFBOARD' if args.start == 'offboard' else 'at once'}, at most {args.duration:g} s",
          file=sys.stderr, flush=True)
    try:
        with player:
            player.run(args.duration, stop.is_set)
            summary = player.summary()
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    why = f"stopped by {received[0]}" if received else "duration over"
    if summary["engaged"]:
        print(f"mavsim traffic: {why}; engaged at {summary['engaged_at_s']:.2f} s, smallest distance "
              f"{summary['min_distance_m']} m ({summary['judged_on']}), goal "
              f"{'reached' if summary['goal_reached'] else 'not reached'}", file=sys.stderr)
    else:
        print(f"mavsim traffic: {why}; the vehicle never engaged (armed in OFFBOARD)"
              + ("" if summary["autopilot"] else "; no autopilot HEARTBEAT heard"), file=sys.stderr)
    if args.json:
        print(json.dumps(summary, indent=2))
    return 0 if summary["engaged"] else 1


if __name__ == "__main__":
    sys.exit(main())
