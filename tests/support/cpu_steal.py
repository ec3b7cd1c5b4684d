"""Take the host's CPUs away in bursts, as a busy hypervisor does: a loaded machine on demand.

    python -m tests.support.cpu_steal --burst-ms 300 --period-s 0.5 -- CMD ARGS...

One process per CPU, pinned to it, in Linux's ``SCHED_FIFO`` class at priority 99 (above
PX4 SITL's threads and the companion's stream), sleeps for ``period_s`` times a factor drawn
from 0.3 to 1.7 and then spins for ``burst_ms`` times a factor from 0.3 to 1.0, until
``CMD`` exits; its exit status is the command's. Linux keeps 5 % of each second for ordinary
processes whatever runs in ``SCHED_FIFO``. Needs root or CAP_SYS_NICE (exit 2 without).

Used to reproduce, on a quiet machine, the flights that braked on a "stale" estimate when the
CI host took its CPUs (docs/notes/vehicle_clock.md). The draws are seeded per CPU (``--seed``),
the timing of the bursts against the flight is not.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import time

FIFO_PRIORITY = 99


def _spin(cpu: int, burst_s: float, period_s: float, seed: int) -> None:
    os.sched_setaffinity(0, {cpu})
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
    rnd = random.Random(seed * 1000 + cpu)
    while True:
        time.sleep(rnd.uniform(0.3, 1.7) * period_s)
        end = time.monotonic() + rnd.uniform(0.3, 1.0) * burst_s
        while time.monotonic() < end:
            pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--burst-ms", type=float, default=300.0, help="longest burst a CPU is taken for (ms)")
    parser.add_argument("--period-s", type=float, default=0.5, help="mean time between bursts (s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- CMD ARGS...: run while the CPUs are taken")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command or not (0 < args.burst_ms <= 1000 and 0.05 <= args.period_s <= 60):
        parser.error("give a command after --, a burst of 0 to 1000 ms and a period of 0.05 to 60 s")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError) as exc:
        print(f"cpu_steal: cannot use SCHED_FIFO here ({exc}); needs root or CAP_SYS_NICE", file=sys.stderr)
        return 2
    spinners = []
    for cpu in sorted(os.sched_getaffinity(0)):
        pid = os.fork()
        if pid == 0:
            try:
                _spin(cpu, args.burst_ms / 1000.0, args.period_s, args.seed)
            finally:
                os._exit(0)
        spinners.append(pid)
    try:
        return subprocess.run(command).returncode
    finally:
        for pid in spinners:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)


if __name__ == "__main__":
    sys.exit(main())
