"""The planning process ends when the stream's process dies without a word (SIGKILL, a crash).

A forked planning process holds both ends of its pipe, so it never reads an end of file;
before it checked its parent, such processes outlived their stream indefinitely.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

_STREAM = r"""
import os, signal, sys
from companion.loop.config import load_scenario
from companion.realtime.stream import PlanWorker
worker = PlanWorker(load_scenario("configs/antipodal.toml").planner)
assert worker.wait_ready(60.0)
print(worker._proc.pid, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie is gone for our purpose
        return f.read().split()[2] != "Z"


def test_that_the_planning_process_ends_soon_after_its_stream_is_killed():
    out = subprocess.run([sys.executable, "-c", _STREAM], capture_output=True, text=True, timeout=120)
    planner = int(out.stdout.split()[0])
    deadline = time.monotonic() + 10.0
    while _alive(planner) and time.monotonic() < deadline:
        time.sleep(0.1)
    alive = _alive(planner)
    if alive:
        os.kill(planner, 9)
    assert not alive, "the planning process outlived its stream by 10 s"
