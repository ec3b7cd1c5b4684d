"""The stream's CPU priority (:func:`companion.realtime.stream_priority.stream_priority`), tried in a child process.

Where permitted (root or CAP_SYS_NICE) the stream runs in ``SCHED_FIFO`` at
``STREAM_FIFO_PRIORITY`` and a process it starts meanwhile is back in the ordinary class;
where not, nothing changes and the result says so. After the block the process's nice
value and class are as before. Never in the test process itself.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

_PROBE = r"""
import json, os, sys
from companion.realtime.stream_priority import stream_priority
fifo_priority = None if sys.argv[1] == "none" else int(sys.argv[1])
nice_before = os.getpriority(os.PRIO_PROCESS, 0)
with stream_priority(fifo_priority=fifo_priority) as (nice, fifo):
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.write(w, str(os.sched_getscheduler(0)).encode())
        os._exit(0)
    os.waitpid(pid, 0)
    child = int(os.read(r, 16))
    policy, rtprio = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
print(json.dumps({"nice": nice, "fifo": fifo, "policy": policy, "child": child, "rtprio": rtprio,
                  "FIFO": os.SCHED_FIFO, "OTHER": os.SCHED_OTHER, "policy_after": os.sched_getscheduler(0),
                  "nice_before": nice_before, "nice_after": os.getpriority(os.PRIO_PROCESS, 0)}))
"""


def _probe(fifo_priority: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE, fifo_priority], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SCHED_FIFO and sched_getscheduler are Linux's")
def test_the_stream_runs_before_ordinary_processes_where_permitted_and_its_children_do_not():
    from companion.realtime.stream_priority import STREAM_FIFO_PRIORITY

    got = _probe(str(STREAM_FIFO_PRIORITY))
    if got["fifo"] is not None:          # permitted (root here)
        assert got["fifo"] == STREAM_FIFO_PRIORITY == got["rtprio"]
        assert got["policy"] & 0xFF == got["FIFO"]
        assert got["child"] == got["OTHER"]         # reset on fork
    else:                                # not permitted: nothing changed, and the result says so
        assert got["policy"] == got["OTHER"] and got["rtprio"] == 0
    # afterwards as before
    assert got["policy_after"] == got["OTHER"] and got["nice_after"] == got["nice_before"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="sched_getscheduler is Linux's")
def test_without_a_real_time_priority_the_stream_stays_in_the_ordinary_class():
    got = _probe("none")
    assert got["fifo"] is None and got["policy"] == got["OTHER"] and got["rtprio"] == 0
    assert got["nice_after"] == got["nice_before"]
