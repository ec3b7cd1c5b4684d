"""``mavsim`` command line: run the simulator over UDP like PX4 SITL.

Examples::

    mavsim --scenario configs/antipodal.toml            # real time, ports as PX4 SITL
    mavsim --scenario configs/antipodal.toml --speed 5 --duration 30 --json --tlog out.tlog
    mavsim --lockstep --duration 60 --json              # no sockets: as fast as possible, no client
    mavsim --scenario configs/antipodal.toml --on-ground --obstacles-start offboard   # the README's fly recipe
    mavsim traffic --scenario configs/antipodal_px4.toml --duration 120 --json     # obstacles into a real PX4 (mavsim.traffic_cli)

Exit status: 0 on success, 2 on a bad scenario file or bad arguments (the message
names the file, section and key; a bad argument; a port that cannot be bound).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import signal
import sys
import threading
import time
from importlib import metadata
from pathlib import Path
from typing import NoReturn

from mavsim.signing import SigningKeyError, load_signing_key
from mavsim.core import OBSTACLE_LINK, OBSTACLES_START, Simulator
from mavsim.errors import ScenarioError, SimulationError
from mavsim.lockstep import LockstepSimulator
from mavsim.personalities import DEFAULT_PERSONALITY, PERSONALITIES
from mavsim.scenario import default_scenario, load_scenario, on_the_ground
from mavsim.udp import LinkAddress, SerialAddress, UdpServer

logger = logging.getLogger(__name__)

__all__ = ["main", "build_parser"]


def _port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in 0..65535, got {v}")
    return v


def _baud(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not 300 <= v <= 4_000_000:
        raise argparse.ArgumentTypeError(f"baud rate must be in 300..4000000, got {v}")
    return v


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


def _seed(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not 0 <= v <= 2**63 - 1:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 2**63 - 1], got {text}")
    return v


def _output_file(text: str) -> Path:
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, not a file")
    if not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"directory {path.parent} does not exist")
    return path


def _vehicles(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not 1 <= v <= 16:
        raise argparse.ArgumentTypeError(f"must be 1 to 16, got {v}")
    return v


_LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")


def _log_level(text: str) -> str:
    if text.upper() not in _LOG_LEVELS:
        raise argparse.ArgumentTypeError(f"must be one of {', '.join(_LOG_LEVELS)}, got {text!r}")
    return text.upper()


def _version() -> str:
    """The installed distribution's version (mavsim ships in the ``ogccmpc`` distribution)."""
    try:
        return metadata.version("ogccmpc")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"


class _OneLineErrorParser(argparse.ArgumentParser):
    """argparse with its errors on one line (``mavsim: error: argument --x: ...``), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineErrorParser(prog="mavsim", description="PX4-like MAVLink kinematic simulator with scripted obstacles "
                            "(`mavsim traffic --help`: play a scenario's obstacles into a real autopilot)")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    p.add_argument("--autopilot", choices=tuple(PERSONALITIES), default=DEFAULT_PERSONALITY,
                   help=f"the autopilot imitated (default {DEFAULT_PERSONALITY})")
    p.add_argument("--scenario", help="scenario file (configs/*.toml) or a shipped scenario's name (antipodal, ...); "
                                      "default: no obstacles, on the ground")
    p.add_argument("--speed", type=_positive, default=1.0, help="simulated seconds per wall second (default 1)")
    p.add_argument("--duration", type=_positive, help="simulated seconds to run (default: the scenario's duration_s)")
    p.add_argument("--forever", action="store_true", help="run until interrupted (ignores duration_s)")
    p.add_argument("--seed", type=_seed, default=0, help="noise seed (default 0)")
    p.add_argument("--tlog", type=_output_file, help="record the API link to this tlog file")
    p.add_argument("--json", action="store_true", help="print the run summary as JSON at the end")
    p.add_argument("--truth-trace", type=_output_file, metavar="FILE",
                   help="at the end, write the true positions of the drone and the obstacles, 10 Hz, "
                        "as JSON lines (t_s, drone_ned_m, obstacles_ned_m)")
    p.add_argument("--api-port", type=_port, default=14540, help="offboard client port to send to (default 14540)")
    p.add_argument("--gcs-port", type=_port, default=14550, help="ground station port to send to (default 14550)")
    p.add_argument("--serial", metavar="DEVICE",
                   help="serve the API link on this serial device instead of UDP (/dev/ttyUSB0, a pty), as PX4 on TELEM2")
    p.add_argument("--baud", type=_baud, default=57600,
                   help="serial baud rate (default 57600); mavsim sends at most half the line's byte rate, as PX4")
    p.add_argument("--api-local-port", type=_port, default=14580, help="local API socket port (default 14580)")
    p.add_argument("--gcs-local-port", type=_port, default=18570, help="local GCS socket port (default 18570)")
    p.add_argument("--obstacle-port", type=_port, default=14601,
                   help="port obstacles with transport = \"link\" are sent to (the companion's --obstacles port; default 14601)")
    p.add_argument("--on-ground", action="store_true",
                   help="start on the ground below the scenario's start point, disarmed, in Position mode, as PX4 SITL "
                        "boots (for `companion fly --arm --takeoff-alt`)")
    p.add_argument("--obstacles-start", choices=OBSTACLES_START, default="boot",
                   help="when the obstacles' scripted motion starts: at boot (default) or when the vehicle is first "
                        "armed in OFFBOARD (with --vehicles: once every vehicle has been)")
    p.add_argument("--obstacle-local-port", type=_port, default=14591, help="local obstacle socket port (default 14591)")
    p.add_argument("--no-gcs", action="store_true", help="serve the API link only")
    p.add_argument("--bind", default="127.0.0.1", help="address to bind (default 127.0.0.1, loopback)")
    p.add_argument("--target-host", default="127.0.0.1", help="host to send to (default 127.0.0.1)")
    p.add_argument("--signing-key-file", metavar="FILE",
                   help="MAVLink 2 signing: the 32-byte key as 64 hex digits in FILE (sign all, reject unsigned)")
    p.add_argument("--signing-key-env", metavar="NAME",
                   help="MAVLink 2 signing: the key (64 hex digits) in environment variable NAME")
    p.add_argument("--lockstep", action="store_true", help="no sockets: run in lockstep, as fast as possible")
    p.add_argument("--vehicles", type=_vehicles, default=1, metavar="N",
                   help="N vehicles in one world (2 to 16), vehicle i with system id 1+i on ports shifted by i "
                        "(API 14580+i -> 14540+i, GCS 18570+i -> 14550, obstacles 14591+i -> 14601+i), its start and goal "
                        "the scenario's rotated by 360 deg * i / N about their midpoint (mavsim.fleet)")
    p.add_argument("--log-level", type=_log_level, default="WARNING", help=f"logging level: {', '.join(_LOG_LEVELS)} (default WARNING)")
    return p


@contextlib.contextmanager
def _stop_on_signals(server: UdpServer):
    """SIGINT and SIGTERM ask ``server`` to stop after its current step, instead of raising
    KeyboardInterrupt wherever the simulator happens to be (which could leave it half-updated
    and lose the summary). Yields the list of signal names received; restores the handlers.
    Signal handlers belong to the main thread: called from another, it installs none."""
    received: list[str] = []

    def handler(signum, _frame) -> None:
        received.append(signal.Signals(signum).name)
        server.stop()

    if threading.current_thread() is not threading.main_thread():  # embedded (tests): the caller stops it
        yield received
        return
    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield received
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``mavsim`` console script; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["traffic"]:
        from mavsim.traffic_cli import main as traffic_main

        return traffic_main(argv[1:])
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=getattr(logging, args.log_level),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        scenario = load_scenario(args.scenario) if args.scenario else default_scenario()
        if args.on_ground:
            scenario = on_the_ground(scenario)
        signing_key = load_signing_key(args.signing_key_file, args.signing_key_env)
    except (ScenarioError, SigningKeyError) as exc:
        print(f"mavsim: error: {exc}", file=sys.stderr)
        return 2
    duration = None if args.forever else (args.duration or scenario.duration_s)
    if args.vehicles > 1:
        return _run_fleet(args, scenario, signing_key, duration)
    if args.lockstep:
        if signing_key is not None:
            print("mavsim: error: signing is for the UDP links; --lockstep has none", file=sys.stderr)
            return 2
        if duration is None:
            print("mavsim: error: --lockstep needs a duration", file=sys.stderr)
            return 2
        if args.obstacles_start != "boot":
            print("mavsim: error: --obstacles-start offboard needs a client; --lockstep has none", file=sys.stderr)
            return 2
        try:
            sim = LockstepSimulator(scenario, seed=args.seed, tlog=args.tlog, personality=args.autopilot)
        except SimulationError as exc:  # the scenario's start mode or parameters are not the autopilot's
            print(f"mavsim: error: {exc}", file=sys.stderr)
            return 2
        with sim:
            sim.advance(duration)
            summary = sim.summary()
    else:
        links = [SerialAddress("api", args.serial, args.baud) if args.serial else
                 LinkAddress("api", args.api_local_port, args.api_port, args.bind, args.target_host)]
        if not args.no_gcs:
            links.append(LinkAddress("gcs", args.gcs_local_port, args.gcs_port, args.bind, args.target_host))
        try:
            sim = Simulator(scenario, seed=args.seed, links=tuple(l.name for l in links),
                            signing=None if signing_key is None else (signing_key, time.time()),
                            obstacles_start=args.obstacles_start, personality=args.autopilot)
        except SimulationError as exc:  # the scenario's start mode or parameters are not the autopilot's
            print(f"mavsim: error: {exc}", file=sys.stderr)
            return 2
        if OBSTACLE_LINK in sim.links:  # some obstacle sends on its own link, like a perception process
            links.append(LinkAddress(OBSTACLE_LINK, args.obstacle_local_port, args.obstacle_port, args.bind, args.target_host))
        try:
            server = UdpServer(sim, links, speed=args.speed, tlog=args.tlog)
        except SimulationError as exc:  # a port in use, an address not ours
            print(f"mavsim: error: {exc}", file=sys.stderr)
            return 2
        ports = server.local_ports
        api = (f"API serial {args.serial} at {args.baud} baud" if args.serial else
               f"API {args.bind}:{ports['api']} -> {args.target_host}:{args.api_port}")
        print(f"mavsim: scenario {scenario.name!r}, {api}"
              + ("" if args.no_gcs else f", GCS {args.bind}:{ports['gcs']} -> {args.target_host}:{args.gcs_port}")
              + (f", obstacles {args.bind}:{ports[OBSTACLE_LINK]} -> {args.target_host}:{args.obstacle_port}"
                 if OBSTACLE_LINK in ports else "")
              + (", on the ground" if args.on_ground else "")
              + (", obstacles start at OFFBOARD" if args.obstacles_start == "offboard" else "")
              + f", speed {args.speed:g}x", file=sys.stderr, flush=True)
        with server, _stop_on_signals(server) as interrupted:
            server.run(duration)
        if interrupted:
            print(f"mavsim: stopped by {interrupted[0]}", file=sys.stderr)
        summary = sim.summary()
    if args.truth_trace:
        with open(args.truth_trace, "w", encoding="utf-8") as trace:
            trace.writelines(json.dumps(row) + "\n" for row in sim.trace_rows())
    if args.json:
        print(json.dumps(summary, indent=2))
    return 0


def _run_fleet(args: argparse.Namespace, scenario, signing_key: bytes | None, duration: float | None) -> int:
    """``--vehicles N``: N vehicles over UDP (:class:`mavsim.fleet.FleetServer`)."""
    from mavsim.fleet import FleetServer, rotated_scenarios

    for flag, used in (("--lockstep", args.lockstep), ("--serial", args.serial), ("--tlog", args.tlog)):
        if used:
            print(f"mavsim: error: {flag} is not available with --vehicles", file=sys.stderr)
            return 2
    try:
        fleet = FleetServer(
            rotated_scenarios(scenario, args.vehicles), seed=args.seed, api_port=args.api_port,
            api_local_port=args.api_local_port, gcs_port=None if args.no_gcs else args.gcs_port,
            gcs_local_port=None if args.no_gcs else args.gcs_local_port, obstacle_port=args.obstacle_port,
            obstacle_local_port=args.obstacle_local_port, bind=args.bind, target_host=args.target_host, speed=args.speed,
            signing=None if signing_key is None else (signing_key, time.time()), obstacles_start=args.obstacles_start,
            personality=args.autopilot)
    except SimulationError as exc:   # a port in use, the autopilot's start mode
        print(f"mavsim: error: {exc}", file=sys.stderr)
        return 2
    for i, ports in enumerate(fleet.local_ports):
        print(f"mavsim: vehicle {i + 1} (system {i + 1}) of scenario {scenario.name!r}: API {args.bind}:{ports['api']} -> "
              f"{args.target_host}:{args.api_port + i}"
              + (f", GCS {args.bind}:{ports['gcs']} -> {args.target_host}:{args.gcs_port}" if "gcs" in ports else "")
              + (f", obstacles {args.bind}:{ports[OBSTACLE_LINK]} -> {args.target_host}:{args.obstacle_port + i}"
                 if OBSTACLE_LINK in ports else ""), file=sys.stderr, flush=True)
    if args.obstacles_start == "offboard":
        print(f"mavsim: obstacles start once all {args.vehicles} vehicles have been armed in OFFBOARD",
              file=sys.stderr, flush=True)
    with fleet, _stop_on_signals(fleet) as interrupted:
        fleet.run(duration)
    if interrupted:
        print(f"mavsim: stopped by {interrupted[0]}", file=sys.stderr)
    summary = fleet.summary()
    if args.truth_trace:
        with open(args.truth_trace, "w", encoding="utf-8") as trace:
            for i, sim in enumerate(fleet.sims):
                trace.writelines(json.dumps({"vehicle": i + 1, **row}) + "\n" for row in sim.trace_rows())
    if args.json:
        print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
