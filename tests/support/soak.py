"""The soak: the patrol (configs/patrol.toml) flown for a long time in real time against mavsim.

``make soak`` flies it for 30 minutes; ``python -m tests.support.soak --minutes M --out DIR
[--json FILE]`` for any length. mavsim and ``companion fly`` run as two processes on free
loopback ports, as an operator runs them (mavsim on the ground, the companion arms, takes off,
uploads the patrol and flies laps until ``--duration``, then hands back). Every
``--sample-s`` seconds the harness reads the resident memory (``/proc/PID/status`` VmRSS) of
the companion's setpoint-stream process and of its planning process, and the size of the
tlog on disk. At the end it reads fly's ``--json`` report and mavsim's truth.

What it holds the flight to (:func:`verdict`; the issue's long-flight bar): resident memory
of each process grows less than :data:`RSS_GROWTH_LIMIT_MB` from the sample at
``warmup_min`` minutes to the last; no setpoint gap over 150 ms; every replan within its
bound (no plan braked on for its age, the planning process's slowest solve under the replan
period); no collision in truth; the tlog within its bound (:data:`SOAK_TLOG_MAX_MB`, less
than the flight writes); the run ended as asked (its
``--duration``, the vehicle handed back). It prints the figures docs/REALTIME.md keeps and
exits 1 if any check failed, 0 otherwise; the files stay in ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from companion.mavlink.tlog import segment_files
from tests.support.ports import free_port_run, wait_for_udp_listener

REPO = Path(__file__).resolve().parents[2]
SCENARIO = REPO / "configs" / "patrol.toml"
#: Largest growth of a process's resident memory after the warm-up (MB, 10^6 bytes).
RSS_GROWTH_LIMIT_MB = 5.0
#: Largest setpoint gap allowed (ms).
GAP_LIMIT_MS = 150.0
#: The soak's tlog bound (MB): less than a 30 min patrol writes, so the bound is exercised.
SOAK_TLOG_MAX_MB = 20.0
#: fly's exit code when its --duration ran out and the vehicle was handed back (Hold).
STOPPED_HELD = 3
#: How long after fly's --duration the harness waits for it to hand back and exit (s).
END_GRACE_S = 60.0


@dataclass
class Sample:
    """One reading: seconds since fly started, resident memory of the stream and planning processes (kB), tlog bytes."""

    t_s: float
    stream_kb: int | None
    planner_kb: int | None
    tlog_bytes: int


@dataclass
class SoakRun:
    """What a soak left: the samples, fly's report and exit code, mavsim's summary, the tlog's files."""

    minutes: float
    samples: list[Sample] = field(default_factory=list)
    report: dict | None = None
    fly_code: int | None = None
    mavsim: dict | None = None
    tlog_files: dict[str, int] = field(default_factory=dict)


def rss_kb(pid: int) -> int | None:
    """Resident memory of process ``pid`` (kB, /proc/PID/status VmRSS), None once it is gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None
    return None


def children(pid: int) -> list[int]:
    """The child processes of ``pid`` (from /proc/PID/task/*/children), [] once it is gone."""
    out: list[int] = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children", encoding="ascii") as f:
                out += [int(c) for c in f.read().split()]
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return []
    return out


def tlog_bytes(tlog: Path) -> int:
    """Bytes on disk of the tlog ``tlog`` and its segments (``STEM.NNNN.SUFFIX``)."""
    return sum(p.stat().st_size for p in _tlog_files(tlog))


def _tlog_files(tlog: Path) -> list[Path]:
    """The tlog and its kept segments on disk."""
    return ([tlog] if tlog.is_file() else []) + segment_files(tlog)


def _at(samples: list[Sample], t_s: float, key: str) -> int | None:
    """The first sample's ``key`` at or after ``t_s`` (None if there is none)."""
    for s in samples:
        if s.t_s >= t_s and getattr(s, key) is not None:
            return getattr(s, key)
    return None


def _last(samples: list[Sample], key: str) -> int | None:
    values = [getattr(s, key) for s in samples if getattr(s, key) is not None]
    return values[-1] if values else None


def verdict(run: SoakRun, *, warmup_min: float = 5.0, replan_period_s: float = 0.3,
            tlog_max_bytes: int | None = None) -> tuple[dict, list[str]]:
    """The soak's figures and the checks that failed (each one line; [] when it passed)."""
    r = run.report or {}
    m = run.mavsim or {}
    figures: dict = {"minutes": run.minutes, "fly_exit_code": run.fly_code, "outcome": r.get("outcome")}
    failed: list[str] = []
    for key in ("stream_kb", "planner_kb"):
        warm, last = _at(run.samples, warmup_min * 60.0, key), _last(run.samples, key)
        name = key[:-3]
        figures[f"{name}_rss_mb_at_{warmup_min:g}_min"] = None if warm is None else round(warm * 1.024e-3, 1)
        figures[f"{name}_rss_mb_at_end"] = None if last is None else round(last * 1.024e-3, 1)
        figures[f"{name}_rss_mb_peak"] = round(max((getattr(s, key) or 0) for s in run.samples) * 1.024e-3, 1) \
            if run.samples else None
        if warm is None or last is None:
            failed.append(f"{name} process: no resident-memory sample at {warmup_min:g} min and at the end")
            continue
        growth = (last - warm) * 1.024e-3
        figures[f"{name}_rss_growth_mb"] = round(growth, 2)
        if growth >= RSS_GROWTH_LIMIT_MB:
            failed.append(f"{name} process: resident memory grew {growth:.1f} MB after {warmup_min:g} min "
                          f"(limit {RSS_GROWTH_LIMIT_MB:g})")
    gap = r.get("setpoint_gap_max_ms")
    figures.update({
        "setpoint_rate_hz": r.get("setpoint_rate_hz"), "setpoint_gap_max_ms": gap,
        "setpoint_gap_max_at_s": r.get("setpoint_gap_max_at_s"),
        "replans": r.get("replans"), "solve_time_median_ms": _round(r.get("solve_time_median_ms")),
        "solve_time_p99_ms": _round(r.get("solve_time_p99_ms")),
        "planner_max_solve_ms": (r.get("planner_process") or {}).get("max_solve_ms"),
        "old_plan_events": r.get("old_plan_events"), "stale_events": r.get("stale_events"),
        "plan_status": r.get("plan_status"), "min_realised_contour": _round(r.get("min_realised_contour"), 4),
        "waypoints_reached": r.get("mission_items_reached_count"), "laps": r.get("mission_jumps_taken"),
        "events_not_kept": r.get("events_not_kept", 0),
        "tlog_mb": round(tlog_bytes_total(run) / 1e6, 1), "tlog_files": len(run.tlog_files),
        "tlog_written_mb": round((r.get("tlog_bytes") or 0) / 1e6, 1),
        "collided": m.get("collided"), "min_distance_m": m.get("min_distance_m"),
    })
    if gap is None or gap > GAP_LIMIT_MS:
        failed.append(f"largest setpoint gap {gap} ms (limit {GAP_LIMIT_MS:g})")
    if r.get("old_plan_events"):
        failed.append(f"{r['old_plan_events']} plans braked on for their age")
    slowest = figures["planner_max_solve_ms"]
    if slowest is None or slowest >= replan_period_s * 1e3:
        failed.append(f"slowest solve {slowest} ms (the replan period is {replan_period_s * 1e3:g} ms)")
    if m.get("collided") is not False:
        failed.append(f"mavsim's truth: collided = {m.get('collided')!r}")
    if tlog_max_bytes is not None and tlog_bytes_total(run) > tlog_max_bytes:
        failed.append(f"tlog {tlog_bytes_total(run)} bytes on disk (bound {tlog_max_bytes})")
    if run.fly_code != STOPPED_HELD or r.get("outcome") != "stopped":
        failed.append(f"fly ended with exit {run.fly_code}, outcome {r.get('outcome')!r} "
                      f"(expected {STOPPED_HELD}, 'stopped': its --duration, the vehicle handed back)")
    return figures, failed


def tlog_bytes_total(run: SoakRun) -> int:
    return sum(run.tlog_files.values())


def _round(value, digits: int = 2):
    return None if value is None else round(float(value), digits)


def fly_soak(minutes: float, out: Path, *, sample_s: float = 10.0, tlog_max_mb: float | None = None,
             python: str = sys.executable) -> SoakRun:
    """Fly the patrol for ``minutes`` (see the module docstring); every wait bounded."""
    out.mkdir(parents=True, exist_ok=True)
    run = SoakRun(minutes)
    duration_s = minutes * 60.0
    base = free_port_run(6)
    api, gcs, obstacle, api_local, gcs_local, obstacle_local = range(base, base + 6)
    tlog = out / "patrol.tlog"
    mavsim_cmd = [python, "-m", "mavsim", "--scenario", str(SCENARIO), "--on-ground", "--obstacles-start", "offboard",
                  "--duration", f"{duration_s + 300.0:g}", "--json", "--api-port", str(api), "--gcs-port", str(gcs),
                  "--obstacle-port", str(obstacle), "--api-local-port", str(api_local),
                  "--gcs-local-port", str(gcs_local), "--obstacle-local-port", str(obstacle_local)]
    fly_cmd = [python, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{api}", "--scenario", str(SCENARIO),
               "--obstacles", f"udpin:127.0.0.1:{obstacle}", "--arm", "--takeoff-alt", "5",
               "--duration", f"{duration_s:g}", "--tlog", str(tlog), "--json"]
    if tlog_max_mb is not None:
        fly_cmd += ["--tlog-max-mb", f"{tlog_max_mb:g}"]
    with open(out / "fly.json", "w") as fly_out, open(out / "fly.err", "w") as fly_err, \
            open(out / "mavsim.json", "w") as sim_out, open(out / "mavsim.err", "w") as sim_err:
        fly = subprocess.Popen(fly_cmd, stdout=fly_out, stderr=fly_err, cwd=REPO)
        sim = None
        try:
            if not (wait_for_udp_listener(api, fly, 60.0) and wait_for_udp_listener(obstacle, fly, 10.0)):
                raise RuntimeError("fly did not bind its ports within 60 s (see fly.err)")
            sim = subprocess.Popen(mavsim_cmd, stdout=sim_out, stderr=sim_err, cwd=REPO)
            started = time.monotonic()
            deadline = started + duration_s + 120.0 + END_GRACE_S
            next_sample = started
            while fly.poll() is None and time.monotonic() < deadline:
                now = time.monotonic()
                if now >= next_sample:
                    planners = children(fly.pid)
                    planner = sum(k for k in (rss_kb(p) for p in planners) if k) if planners else None
                    run.samples.append(Sample(round(now - started, 1), rss_kb(fly.pid), planner, tlog_bytes(tlog)))
                    next_sample += sample_s
                time.sleep(min(1.0, max(0.05, next_sample - time.monotonic())))
            if fly.poll() is None:
                fly.send_signal(signal.SIGINT)
            run.fly_code = fly.wait(timeout=END_GRACE_S)
        finally:
            if fly.poll() is None:
                fly.kill()
                fly.wait(timeout=10)
            if sim is not None:
                if sim.poll() is None:
                    sim.send_signal(signal.SIGINT)
                try:
                    sim.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    sim.kill()
                    sim.wait(timeout=10)
    run.report = _json(out / "fly.json")
    run.mavsim = _json(out / "mavsim.json")
    run.tlog_files = {p.name: p.stat().st_size for p in _tlog_files(tlog)}
    (out / "samples.json").write_text(json.dumps([s.__dict__ for s in run.samples]))
    return run


def _json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.support.soak", description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=30.0, help="how long the patrol is flown (default 30)")
    p.add_argument("--out", type=Path, default=REPO / "out" / "soak", help="where the run's files go (default out/soak)")
    p.add_argument("--sample-s", type=float, default=10.0, help="seconds between memory samples (default 10)")
    p.add_argument("--warmup-min", type=float, default=5.0, help="memory growth is measured from here (default 5)")
    p.add_argument("--tlog-max-mb", type=float, default=SOAK_TLOG_MAX_MB,
                   help=f"fly's --tlog-max-mb (default {SOAK_TLOG_MAX_MB:g}: less than 30 min writes, so it is kept)")
    p.add_argument("--json", type=Path, default=None, help="also write the figures and failures here")
    args = p.parse_args(argv)
    if not 0.0 < args.warmup_min < args.minutes:
        p.error("--warmup-min must lie between 0 and --minutes")
    run = fly_soak(args.minutes, args.out, sample_s=args.sample_s, tlog_max_mb=args.tlog_max_mb)
    bound = int(args.tlog_max_mb * 1e6) if args.tlog_max_mb else None
    figures, failed = verdict(run, warmup_min=args.warmup_min, tlog_max_bytes=bound)
    for key, value in figures.items():
        print(f"{key:32s} {value}")
    for line in failed:
        print(f"FAILED: {line}")
    if args.json is not None:
        args.json.write_text(json.dumps({"figures": figures, "failed": failed}, indent=2))
    print(f"soak: {'passed' if not failed else 'FAILED'} ({args.minutes:g} min; files in {args.out})")
    return 0 if not failed else 1


if __name__ == "__main__":
    sys.exit(main())
