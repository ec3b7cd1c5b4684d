"""``companion demo SCENARIO --drones N``: a fleet, in lockstep or in real time.

Lockstep: :func:`companion.offline.fleet_harness.run_fleet_lockstep` in this process.
Real time (``--realtime``): ``mavsim --vehicles N`` and N ``companion fly`` processes over
loopback UDP. Drone i's scenario file is the scenario with its start and goal turned as
mavsim turns vehicle i (:func:`companion.offline.swap.rotated_fleet`); its fly listens on
its own ports (API and obstacles shifted by i, as mavsim sends), hears the other drones on
its own fleet port and tells each of them on theirs. The traffic waits at its start points
until every vehicle has engaged (``mavsim --obstacles-start offboard``), so the encounter
meets the fleet in flight however long the companions took to start. Every wait is
bounded; every process started is ended.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from companion.commands._loopback import free_port_run, udp_port_taken
from companion.errors import ConfigError

#: Seconds a fly may take to start listening.
FLY_START_S = 60.0


def run_fleet(scenario: Path, args: argparse.Namespace, overrides: dict, out: Path | None) -> int:
    """Fly ``--drones N`` (lockstep or ``--realtime``), print the fleet's summary; the exit status."""
    if not 2 <= args.drones <= 16:
        raise ConfigError(f"--drones: a fleet of 2 to 16 drones, got {args.drones}")
    for flag, used in (("--crowd", args.crowd), ("--view", getattr(args, "view", None)),
                       ("--mcap", getattr(args, "mcap", None))):
        if used:
            raise ConfigError(f"{flag} is not available with --drones")
    from companion.loop.config import read_scenario_toml
    from companion.offline.swap import rotated_fleet

    data = read_scenario_toml(scenario)
    planner = dict(data.get("planner", {}))
    for key, value in overrides.items():
        if value is None:
            planner.pop(key, None)
        else:
            planner[key] = value
    data["planner"] = planner
    if args.coordination:
        data["fleet"] = {**data.get("fleet", {}), "coordination": args.coordination}
    drones = rotated_fleet(data, args.drones)
    t0 = time.perf_counter()
    summary = _realtime(scenario, drones, args, out) if args.realtime else _lockstep(drones, args)
    summary["wall_time_s"] = round(time.perf_counter() - t0, 2)
    if out is not None:
        (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        print(format_fleet(summary))
        if out is not None:
            print(f"outputs in {out}/")
    errors = summary.get("errors") or []
    if errors:
        print(f"companion demo: error: {errors[0]}", file=sys.stderr)
        return 1
    return 0


def _lockstep(drones: list[dict], args: argparse.Namespace) -> dict:
    from companion.offline.fleet_harness import run_fleet_lockstep

    result = run_fleet_lockstep(drones, seed=args.seed)
    summary = {"mode": "lockstep", **result.summary()}
    first = result.drones[0].companion.scenario
    summary["coordination"] = first.fleet.coordination
    summary["c_min"] = first.planner.c_min
    return summary


def _stop(proc: subprocess.Popen, timeout_s: float = 15.0) -> tuple[str, str]:
    """SIGINT (a fly hands back, mavsim prints its summary), then kill: its output either way."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()


def _signing_flags(args: argparse.Namespace) -> list[str]:
    """The signing flags as given (the key itself never appears on a command line)."""
    out: list[str] = []
    for flag, value in (("--signing-key-file", args.signing_key_file), ("--signing-key-env", args.signing_key_env)):
        if value is not None:
            out += [flag, value]
    return out


def _json_in(text: str) -> dict:
    try:
        return json.loads(text[text.index("{"):]) if "{" in text else {}
    except json.JSONDecodeError:
        return {}


def _realtime(scenario: Path, drones: list[dict], args: argparse.Namespace, out: Path | None) -> dict:
    from companion.loop.config import load_scenario
    from companion.offline.campaign.toml_writer import to_toml

    n = len(drones)
    config = load_scenario(scenario)
    fly_duration_s = config.duration_s / max(args.speed, 1e-3) + 30.0
    where = out if out is not None else Path(tempfile.mkdtemp(prefix="companion-fleet-"))
    files = []
    for i, data in enumerate(drones):
        path = where / f"drone{i + 1}.toml"
        path.write_text(to_toml(data))
        files.append(path)
    api, api_local, obstacle, obstacle_local, fleet = (free_port_run(n) for _ in range(5))
    flies: list[subprocess.Popen] = []
    sim = None
    errors: list[str] = []
    outs: list[tuple[str, str]] = []
    try:
        for i in range(n):
            cmd = [sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{api + i}",
                   "--scenario", str(files[i]), "--obstacles", f"udpin:127.0.0.1:{obstacle + i}",
                   "--fleet", f"udpin:127.0.0.1:{fleet + i}",
                   *[a for j in range(n) if j != i for a in ("--fleet", f"udpout:127.0.0.1:{fleet + j}")],
                   "--exit-after-goal", "1.0", "--duration", f"{fly_duration_s:.1f}", "--json"]
            if out is not None:
                cmd += ["--tlog", str(out / f"companion{i + 1}.tlog")]
            cmd += _signing_flags(args)
            flies.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        deadline = time.monotonic() + FLY_START_S
        while time.monotonic() < deadline and not all(udp_port_taken(obstacle + i) or f.poll() is not None
                                                      for i, f in enumerate(flies)):
            time.sleep(0.05)
        # the traffic waits until every vehicle is flying: N companions start over seconds on a busy machine
        sim_cmd = [sys.executable, "-m", "mavsim.cli", "--scenario", str(scenario), "--vehicles", str(n), "--no-gcs",
                   "--obstacles-start", "offboard", "--seed", str(args.seed), "--api-port", str(api),
                   "--api-local-port", str(api_local), "--obstacle-port", str(obstacle), "--obstacle-local-port", str(obstacle_local),
                   "--speed", str(args.speed), "--json"]
        if out is not None:
            sim_cmd += ["--truth-trace", str(out / "truth_trace.jsonl")]
        sim_cmd += _signing_flags(args)
        sim = subprocess.Popen(sim_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i, fly in enumerate(flies):
            try:
                outs.append(fly.communicate(timeout=fly_duration_s + 60.0))
            except subprocess.TimeoutExpired:
                errors.append(f"companion fly of drone {i + 1} did not end within {fly_duration_s + 60.0:.0f} s")
                outs.append(_stop(fly))
    finally:
        for fly in flies:
            if fly.poll() is None:
                _stop(fly)
        sim_out, sim_err = _stop(sim) if sim is not None else ("", "")
    reports = []
    for i, (fly_out, fly_err) in enumerate(outs):
        report = _json_in(fly_out)
        if not report:
            last = [line for line in fly_err.splitlines() if line.strip()]
            errors.append(f"companion fly of drone {i + 1} failed: {last[-1] if last else 'no output'}")
        reports.append(report)
    truth = _json_in(sim_out)
    if not truth:
        errors.append(f"mavsim printed no summary: {(sim_err.strip().splitlines() or ['no output'])[-1]}")
    if out is not None:
        (out / "truth.json").write_text(json.dumps(truth, indent=2, default=str))
    contours = [r.get("fleet", {}).get("min_peer_realised_contour") for r in reports]
    contours = [c for c in contours if c is not None]
    gaps = [r.get("setpoint_gap_max_ms") for r in reports if r.get("setpoint_gap_max_ms") is not None]
    per_vehicle = truth.get("per_vehicle") or [{}] * n
    return {
        "mode": "realtime", "drones": n, "coordination": config.fleet.coordination if not args.coordination else args.coordination,
        "c_min": config.planner.c_min,
        "collided": truth.get("collided"), "goal_reached": truth.get("goal_reached"),
        "drone_drone_collisions": sum(p["min_clearance_m"] < 0.0 for p in (truth.get("pairs") or {}).values()),
        "drone_traffic_collisions": sum(bool(v.get("collided")) for v in per_vehicle),
        "time_to_all_goals_s": (round(max(v["time_to_goal_s"] for v in per_vehicle), 2)
                                if per_vehicle and all(v.get("time_to_goal_s") is not None for v in per_vehicle) else None),
        "min_pair_clearance_m": truth.get("min_pair_clearance_m"),
        "min_peer_realised_contour": min(contours) if contours else None,
        "setpoint_gap_max_ms": max(gaps) if gaps else None,
        "per_drone": [{"collided": v.get("collided"), "goal_reached": v.get("goal_reached"),
                       "time_to_goal_s": None if v.get("time_to_goal_s") is None else round(v["time_to_goal_s"], 2),
                       "outcome": r.get("outcome"),
                       "setpoint_rate_hz": r.get("setpoint_rate_hz"), "setpoint_gap_max_ms": r.get("setpoint_gap_max_ms"),
                       "stream_cpu_share": r.get("stream_cpu_share"), "stream_loops_per_s": r.get("stream_loops_per_s"),
                       "cpu_share": r.get("cpu_share"),
                       "cpu_share_in_flight": r.get("cpu_share_in_flight"),
                       "max_rss_mb": r.get("max_rss_mb"), "replans_with_slack": r.get("replans_with_slack"),
                       "failed_plans": r.get("failed_plans")}
                      for v, r in zip(per_vehicle, reports)],
        "errors": errors,
    }


def format_fleet(s: dict) -> str:
    """A fleet summary as lines: the fleet, then one line per drone."""
    def f(value, spec: str) -> str:
        return "-" if value is None else format(value, spec)

    lines = [
        f"drones: {s['drones']} ({s['coordination']}, {s.get('mode', 'lockstep')})",
        f"collision: {s['collided']} (drone-drone {s['drone_drone_collisions']}, drone-traffic {s['drone_traffic_collisions']})",
        f"all goals reached: {s['goal_reached']}, the last at {s['time_to_all_goals_s']} s",
        f"smallest true clearance between drones [m]: {f(s['min_pair_clearance_m'], '.3f')}",
        f"smallest realised contour between drones: {f(s['min_peer_realised_contour'], '.4f')} (c_min {s['c_min']})",
    ]
    if s.get("mode") == "realtime":
        lines.append(f"largest setpoint gap of any drone [ms]: {s['setpoint_gap_max_ms']}")
    lines.append(f"wall time [s]: {s['wall_time_s']}")
    for i, d in enumerate(s["per_drone"]):
        extra = (f", stream {d.get('setpoint_rate_hz')} Hz, gap {d.get('setpoint_gap_max_ms')} ms, "
                 f"CPU {f(d.get('cpu_share_in_flight'), '.1%')} in flight ({f(d.get('cpu_share'), '.1%')} with start-up), "
                 f"RSS {d.get('max_rss_mb')} MB" if s.get("mode") == "realtime" else "")
        lines.append(f"  drone {i + 1}: goal {d['goal_reached']} at {d['time_to_goal_s']} s, collided {d['collided']}, "
                     f"slack replans {d['replans_with_slack']}, failed plans {d['failed_plans']}{extra}")
    return "\n".join(lines)
