"""The stream's CPU priority (:func:`companion.loop.realtime.raise_stream_priority`), tried in a child process.

Where permitted (root or CAP_SYS_NICE) the stream runs in ``SCHED_FIFO`` at
``STREAM_FIFO_PRIORITY`` and a process it starts afterwards is back in the ordinary class;
where not, nothing changes and the result says so. Never in the test process itself.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

_PROBE = r"""
import json, os, sys
from companion.loop.realtime import raise_stream_priority
fifo_priority = None if sys.argv[1] == "none" else int(sys.argv[1])
nice, fifo = raise_stream_priority(fifo_priority=fifo_priority)
r, w = os.pipe()
pid = os.fork()
if pid == 0:
    os.write(w, str(os.sched_getscheduler(0)).encode())
    os._exit(0)
os.waitpid(pid, 0)
child = int(os.read(r, 16))
print(json.dumps({"nice": nice, "fifo": fifo, "policy": os.sched_getscheduler(0), "child": child,
                  "FIFO": os.SCHED_FIFO, "OTHER": os.SCHED_OTHER, "rtprio": os.sched_getparam(0).sched_priority}))
"""


def _probe(fifo_priority: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE, fifo_priority], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SCHED_FIFO and sched_getscheduler are Linux's")
def test_the_stream_runs_before_ordinary_processes_where_permitted_and_its_children_do_not():
    from companion.loop.realtime import STREAM_FIFO_PRIORITY

    got = _probe(str(STREAM_FIFO_PRIORITY))
    if got["fifo"] is not None:          # permitted (root here)
        assert got["fifo"] == STREAM_FIFO_PRIORITY == got["rtprio"]
        assert got["policy"] & 0xFF == got["FIFO"]
        assert got["child"] == got["OTHER"]         # reset on fork
    else:                                # not permitted: nothing changed, and the result says so
        assert got["policy"] == got["OTHER"] and got["rtprio"] == 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="sched_getscheduler is Linux's")
def test_without_a_real_time_priority_the_stream_stays_in_the_ordinary_class():
    got = _probe("none")
    assert got["fifo"] is None and got["policy"] == got["OTHER"] and got["rtprio"] == 0
