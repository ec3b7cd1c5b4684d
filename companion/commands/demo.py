"""``companion demo``: the paper's scenarios flown by the companion against the bundled simulator."""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import time
from importlib import resources
from pathlib import Path

from companion.commands._argtypes import positive_number, seed
from companion.errors import ConfigError
from companion.offline.report import format_report, truth_report

SCENARIOS = ("antipodal", "corridor", "single_obstacle")


def resolve_scenario(name: str) -> Path:
    """A shipped scenario's name (``antipodal``) or a path to a TOML file.

    The shipped scenarios are the repository's ``configs/*.toml``, installed as the package
    ``companion.scenarios`` so that a wheel finds them from any working directory.
    """
    path = Path(name)
    if path.suffix == ".toml" and path.exists():
        return path
    if name in SCENARIOS:
        shipped = Path(str(resources.files("companion.scenarios") / f"{name}.toml"))
        if shipped.is_file():
            return shipped
    raise ConfigError(f"unknown scenario {name!r}: expected one of {', '.join(SCENARIOS)} or a .toml file")


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
    p.add_argument("scenario", nargs="?", default="antipodal", help=f"{' | '.join(SCENARIOS)} or a scenario .toml")
    p.add_argument("--seed", type=seed, default=0, help="simulator noise seed (default 0)")
    p.add_argument("--formulation", default=None, help="planner formulation (hyperplane, paper, deterministic, bhattacharyya)")
    p.add_argument("--no-c-max", action="store_true", help="drop the scenario's c_max upper bound")
    p.add_argument("--out", default=None, metavar="DIR", help="keep the tlogs, the ground-truth summary and the figures here")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--realtime", action="store_true", help="two processes over loopback UDP in real time")
    p.add_argument("--speed", type=positive_number, default=1.0, help="with --realtime: simulated seconds per wall second of mavsim (default 1)")
    p.add_argument("--signing-key-file", metavar="FILE", help="with --realtime: both programs sign with the key in FILE")
    p.add_argument("--signing-key-env", metavar="NAME",
                   help="with --realtime: both programs sign with the key in environment variable NAME")
    p.set_defaults(func=run)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run(args: argparse.Namespace) -> int:
    scenario = resolve_scenario(args.scenario)
    overrides = {}
    if args.formulation:
        overrides["formulation"] = args.formulation
    if args.no_c_max:
        overrides["c_max"] = None
    from companion.offline.scenario_file import load_both  # imports mavsim: only the offline tools do

    load_both(scenario, **overrides)  # both programs' sections, before anything starts
    if not args.realtime and (args.signing_key_file or args.signing_key_env):
        raise ConfigError("signing is for the UDP links of --realtime; the lockstep demo has none")
    out = Path(args.out) if args.out else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    summary = _run_realtime(scenario, args, overrides, out) if args.realtime else _run_lockstep(scenario, args, overrides, out)
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        print(format_report(summary))
        if out is not None:
            print(f"outputs in {out}/")
    return 0


def _run_lockstep(scenario: Path, args: argparse.Namespace, overrides: dict, out: Path | None) -> dict:
    from companion.offline.harness import run_lockstep  # imports mavsim: only the demo and campaign do

    t0 = time.perf_counter()
    result = run_lockstep(
        scenario,
        seed=args.seed,
        tlog_path=out / "companion.tlog" if out else None,
        sim_tlog_path=out / "mavsim.tlog" if out else None,
        **overrides,
    )
    summary = result.summary()
    summary["wall_time_s"] = round(time.perf_counter() - t0, 2)
    if out is not None:
        (out / "truth.json").write_text(json.dumps(result.truth, indent=2, default=str))
        (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
        try:
            from companion.plots.flight_figures import write_flight_figures
        except ImportError:  # figures module not present in this build
            summary["figures"] = []
        else:
            summary["figures"] = [str(p) for p in write_flight_figures(result.companion, out, truth=result.truth)]
    return summary


def _run_realtime(scenario: Path, args: argparse.Namespace, overrides: dict, out: Path | None) -> dict:
    api_port, gcs_port, api_local, gcs_local = (_free_udp_port() for _ in range(4))
    sim_cmd = [
        sys.executable, "-m", "mavsim.cli", "--scenario", str(scenario), "--seed", str(args.seed),
        "--api-port", str(api_port), "--gcs-port", str(gcs_port), "--api-local-port", str(api_local),
        "--gcs-local-port", str(gcs_local), "--speed", str(args.speed), "--json",
    ]
    fly_cmd = [
        sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{api_port}", "--scenario", str(scenario),
        "--exit-after-goal", "1.0", "--json",
    ]
    if out is not None:
        sim_cmd += ["--tlog", str(out / "mavsim.tlog")]
        fly_cmd += ["--tlog", str(out / "companion.tlog")]
    if overrides.get("formulation"):
        fly_cmd += ["--formulation", overrides["formulation"]]
    if "c_max" in overrides:
        fly_cmd += ["--no-c-max"]
    for flag, value in (("--signing-key-file", args.signing_key_file), ("--signing-key-env", args.signing_key_env)):
        if value is not None:  # the key itself never appears on a command line
            sim_cmd += [flag, value]
            fly_cmd += [flag, value]
    sim = subprocess.Popen(sim_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        fly = subprocess.run(fly_cmd, capture_output=True, text=True, timeout=300)
    finally:
        sim.send_signal(signal.SIGINT)  # mavsim prints its ground-truth summary on SIGINT
        try:
            sim_out, _ = sim.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim_out, _ = sim.communicate()
    summary = json.loads(fly.stdout) if fly.stdout.strip().startswith("{") else {"fly_error": fly.stderr[-2000:]}
    try:
        truth = json.loads(sim_out[sim_out.index("{"):]) if "{" in sim_out else {}
    except json.JSONDecodeError:
        truth = {}
    # No truth (mavsim failed to report): its keys stay out rather than read "no collision".
    summary = {"mode": "realtime", **(truth_report(truth) if truth else {}), **summary}
    if out is not None:
        (out / "truth.json").write_text(json.dumps(truth, indent=2, default=str))
    return summary
