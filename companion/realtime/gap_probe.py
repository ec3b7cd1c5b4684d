"""Where the time of the largest setpoint gap went: the stream's CPU, its wait for a CPU, its longest step.

A setpoint gap well over the period that falls outside any tick and any garbage
collection (two quiet runs of the corridor's crowd flight each had one of 188 and
192 ms) has four possible causes, and each leaves a different trace:

- the stream computed through it (its CPU time over the gap is close to the gap; the
  reading is the process's, all its threads: against PX4 SITL it was OpenBLAS's idle
  threads spinning, while the stream slept, until ``companion`` asked for one BLAS thread);
- it was ready but waited for a CPU (the scheduler's run-queue wait is close to the gap:
  the machine, not the stream);
- it was blocked in a system call or asleep past its wake-up (neither: a voluntary
  context switch, and the step that held it is the longest one);
- the virtual machine it runs in was not given a CPU by its host (the machine's steal
  time grows; the guest's own counters see nothing);

and a gap on the wall clock that the monotonic clock does not see is the wall clock
being set, not a gap (the stream stamps with the wall clock, as the tlog does).

:class:`GapProbe` reads the process's CPU time, the kernel's run-queue wait
(``/proc/self/schedstat``, Linux: the main thread's, which runs the stream), its
context switches (all threads), the machine's steal time (``/proc/stat``, all CPUs) and the monotonic
clock at every setpoint, and keeps, for the largest gap only, their change over the gap
and the longest single step of the loop within it (bounded: one record). A reading
costs about 30 microseconds (two small files opened, read and closed), at the setpoint
rate.
"""

from __future__ import annotations

import os
import time

try:
    import resource
except ImportError:  # not on this platform: no context-switch counts
    resource = None

_SCHEDSTAT = "/proc/self/schedstat"  # Linux: ns on a CPU, ns waiting on a run queue, time slices
_STAT = "/proc/stat"                  # Linux: first line "cpu user nice system idle iowait irq softirq steal ..."
try:
    _TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")
except (AttributeError, ValueError, OSError):
    _TICK_S = 0.01


def _run_queue_wait_s() -> float | None:
    """Seconds this thread has waited on a run queue, ready to run (Linux), else None."""
    try:
        with open(_SCHEDSTAT, "rb") as f:
            return int(f.read(128).split()[1]) * 1e-9
    except (OSError, IndexError, ValueError):
        return None


def _steal_s() -> float | None:
    """Seconds the host kept this virtual machine's CPUs from it, summed over CPUs (Linux), else None."""
    try:
        with open(_STAT, "rb") as f:
            return int(f.readline().split()[8]) * _TICK_S
    except (OSError, IndexError, ValueError):
        return None


class GapProbe:
    """The largest gap between setpoints, and where its time went (seconds, wall and CPU).

    Call :meth:`tick_started` as a tick starts (the moment its setpoint is stamped with),
    :meth:`step` after each step of the stream loop with its name and duration, and
    :meth:`setpoint` when the tick sent a setpoint, with the gap it ended (None for the
    first): the readings are then those of the instants the gap is measured between.
    """

    def __init__(self) -> None:
        self._last: tuple | None = None
        self._at_tick: tuple | None = None
        self._step_name: str | None = None
        self._step_s = 0.0
        self._largest_s = -1.0
        self.largest: dict | None = None   #: the record of the largest gap so far (see :meth:`setpoint`)

    def tick_started(self) -> None:
        """A tick starts: take the reading a setpoint it sends will be stamped with."""
        self._at_tick = self._reading()

    def step(self, name: str, seconds: float) -> None:
        """A step of the loop (``name``) took ``seconds`` since the last setpoint."""
        if seconds > self._step_s:
            self._step_name, self._step_s = name, seconds

    def setpoint(self, gap_s: float | None) -> None:
        """A setpoint was sent, ending a gap of ``gap_s`` since the one before (None: the first)."""
        now = self._at_tick if self._at_tick is not None else self._reading()
        self._at_tick = None
        if gap_s is not None and self._last is not None and gap_s > self._largest_s:
            mono, cpu, wait, steal, voluntary, involuntary = (None if a is None or b is None else b - a
                                                              for a, b in zip(self._last, now))
            self._largest_s = gap_s
            self.largest = {
                "gap_ms": round(gap_s * 1e3, 1),
                "monotonic_gap_ms": round(mono * 1e3, 1),   # the same interval on the monotonic clock
                "cpu_ms": round(cpu * 1e3, 1),
                "run_queue_wait_ms": None if wait is None else round(wait * 1e3, 1),
                "steal_ms": None if steal is None else round(steal * 1e3, 1),   # machine-wide, 1/CLK_TCK steps
                "voluntary_switches": voluntary,
                "involuntary_switches": involuntary,
                "longest_step": self._step_name,
                "longest_step_ms": round(self._step_s * 1e3, 1),
            }
        self._last = now
        self._step_name, self._step_s = None, 0.0

    def _reading(self) -> tuple:
        """Monotonic seconds, CPU seconds of the process, run-queue wait and steal seconds,
        voluntary and involuntary context switches."""
        voluntary = involuntary = None
        if resource is not None:
            usage = resource.getrusage(resource.RUSAGE_SELF)
            voluntary, involuntary = usage.ru_nvcsw, usage.ru_nivcsw
        return time.monotonic(), time.process_time(), _run_queue_wait_s(), _steal_s(), voluntary, involuntary
