"""Start-up: how long ``companion --version``, ``--help`` and ``fly`` take to answer (median of 10 runs each).

``fly`` is timed from its start to its first HEARTBEAT on the wire: it is given
``--connect udpout:127.0.0.1:PORT`` toward a socket of the benchmark's, which takes the
first packet, then stopped with SIGTERM (no autopilot: it exits at once). The peer of each
row, measured in the same run, is a bare interpreter (``python -c pass``): what no
command can beat. With ``BENCH_BASE_TREE=DIR`` (a checkout of an earlier commit) the same
commands are also run from that tree, for a before/after in one run.

Targets (the issue's): ``--version`` and ``--help`` under 0.5 s, ``fly`` ready to send its
first HEARTBEAT within 1.5 s.
"""

from __future__ import annotations

import os
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
RUNS = 10
FIRST_PACKET_TIMEOUT_S = 30.0


def _env(tree: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(tree)}


def _command_s(args: list[str], tree: Path) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, *args], cwd=tree, env=_env(tree), capture_output=True, timeout=60, check=False)
    return time.perf_counter() - started


def _fly_first_heartbeat_s(tree: Path) -> float:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(FIRST_PACKET_TIMEOUT_S)
        port = sock.getsockname()[1]
        started = time.perf_counter()
        fly = subprocess.Popen([sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpout:127.0.0.1:{port}",
                                "--scenario", str(SCENARIO), "--no-realtime-priority"],
                               cwd=tree, env=_env(tree), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            sock.recv(512)
            elapsed = time.perf_counter() - started
        finally:
            fly.send_signal(signal.SIGTERM)
            try:
                fly.wait(timeout=15)
            except subprocess.TimeoutExpired:
                fly.kill()
                fly.wait()
    return elapsed


def _median(measure, *args) -> float:
    return statistics.median(measure(*args) for _ in range(RUNS))


def run() -> list[dict]:
    trees = [("", ROOT)]
    base = os.environ.get("BENCH_BASE_TREE")
    if base:
        trees.append((f" (base {Path(base).name})", Path(base)))
    floor = _median(_command_s, ["-c", "pass"], ROOT)
    rows = []
    for label, tree in trees:
        for name, args, target in (("companion --version", ["-m", "companion.cli", "--version"], 0.5),
                                   ("companion --help", ["-m", "companion.cli", "--help"], 0.5)):
            value = _median(_command_s, args, tree)
            rows.append({"name": f"{name}{label}, median of {RUNS}", "value": value, "unit": "s", "target": f"< {target}",
                         "peer": floor, "note": f"{value / floor:.1f}x a bare interpreter start"})
        value = _median(_fly_first_heartbeat_s, tree)
        rows.append({"name": f"companion fly to its first HEARTBEAT{label}, median of {RUNS}", "value": value,
                     "unit": "s", "target": "< 1.5", "peer": floor,
                     "note": "imports, scenario, link open; the kernels and the planning process come after it"})
    return rows
