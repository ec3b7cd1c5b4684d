"""What ``fly`` reports of the CPU its two processes used in flight (``process_cpu_s``, /proc/PID/stat)."""

from __future__ import annotations

import subprocess
import sys
import time

from companion.commands.fly import process_cpu_s


def test_that_a_busy_process_cpu_time_is_read_from_proc():
    child = subprocess.Popen([sys.executable, "-c", "import time\nend = time.process_time() + 0.5\n"
                              "while time.process_time() < end: pass\ntime.sleep(30)"])
    try:
        deadline = time.monotonic() + 20.0
        used = process_cpu_s(child.pid)
        while (used is None or used < 0.5) and time.monotonic() < deadline:
            time.sleep(0.05)
            used = process_cpu_s(child.pid)
        assert used is not None and 0.5 <= used < 1.5, used      # its start-up and its 0.5 s of spinning
        time.sleep(0.3)
        assert process_cpu_s(child.pid) - used < 0.05            # asleep: no more
    finally:
        child.kill()
        child.wait(timeout=5)


def test_that_no_process_is_none():
    assert process_cpu_s(None) is None
    assert process_cpu_s(2 ** 30) is None
