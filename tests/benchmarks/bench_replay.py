"""Replay speed: log seconds per wall second for the antipodal demo log.

The log is recorded first with a lockstep run of the antipodal scenario (full length,
until 2 s after the goal), then replayed through a fresh companion with
:func:`companion.offline.replay.replay` (estimator and planner run exactly as in flight; no wall
clock). Rows: the whole replay (tlog reading included), and the same as a check that it
reproduced the recorded commands (largest difference, m/s). Target: faster than real
time by 10x, so an hour-long flight replays in minutes.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from companion.offline.harness import run_lockstep
from companion.offline.replay import replay

SCENARIO = Path(__file__).resolve().parents[2] / "configs" / "antipodal.toml"
TARGET = 10.0


def run() -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "antipodal.tlog"
        run_lockstep(SCENARIO, seed=0, tlog_path=log)
        t0 = time.perf_counter()
        res = replay(log, SCENARIO)
        wall = time.perf_counter() - t0
    note = (f"antipodal demo log, {res.duration_s:.1f} s, {res.messages} messages, "
            f"{res.ticks} ticks, {res.replans} replans")
    return [
        {"name": "replay_log_s_per_wall_s", "value": res.duration_s / wall, "unit": "log s / wall s",
         "target": f">= {TARGET:g}", "note": note},
        {"name": "replay_max_command_difference", "value": res.max_abs_diff_mps, "unit": "m/s",
         "target": "<= 1e-9", "note": f"{res.commands_compared} recorded setpoints compared (float32 wire values)"},
    ]
