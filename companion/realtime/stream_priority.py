"""The setpoint stream's CPU priority: ahead of ordinary processes, where the system permits it.

The stream needs little CPU (about a seventh of a core with 200 tracks) but needs it on
time. At the default priority on a loaded machine it waited up to 0.8 s for a CPU. At
nice -10 on a quiet one it still waited: 3 to 5 ms in the kernel's run queue each time a
job it handed over woke the planning process on its CPU, and once 38.6 ms in a gap of
80 ms (docs/REALTIME.md). Ordinary processes never take a CPU from one in Linux's
``SCHED_FIFO`` class; the stream sleeps between ticks and every step of its loop is
bounded, so it cannot hold a CPU (Linux also keeps 5 % of each second for ordinary
processes). PX4 SITL runs its own threads in ``SCHED_FIFO`` at 1 to 99: beside it the
stream ranks above PX4's low-priority work queue only.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator

logger = logging.getLogger(__name__)

#: Nice steps :func:`raise_stream_priority` takes the stream up by, when permitted.
STREAM_PRIORITY_STEPS = 10
#: Real-time (``SCHED_FIFO``) priority :func:`raise_stream_priority` gives the stream, when
#: permitted: low among Linux's 1-99, above every ordinary process.
STREAM_FIFO_PRIORITY = 10


def raise_stream_priority(steps: int = STREAM_PRIORITY_STEPS,
                          fifo_priority: int | None = STREAM_FIFO_PRIORITY) -> tuple[int | None, int | None]:
    """Give this process the CPU before ordinary processes, as far as allowed: ``(nice, fifo)``.

    ``nice``: the process's nice value after lowering it by ``steps`` (None: not permitted).
    ``fifo``: the real-time priority it then runs at in Linux's ``SCHED_FIFO`` class (None:
    not asked, not permitted or not on this platform); processes it starts later return
    to the ordinary class (``SCHED_RESET_ON_FORK``).

    Call it after the planning process (:class:`companion.realtime.stream.PlanWorker`) has
    started, so that it keeps the default priority. Needs root or CAP_SYS_NICE (or an
    ``RLIMIT_NICE`` and ``RLIMIT_RTPRIO`` allowing it); without it nothing changes.
    """
    nice = fifo = None
    try:
        current = os.getpriority(os.PRIO_PROCESS, 0)
        os.setpriority(os.PRIO_PROCESS, 0, current - int(steps))
        nice = os.getpriority(os.PRIO_PROCESS, 0)
    except (AttributeError, OSError) as exc:  # no such call on this platform, or not permitted
        logger.info("stream nice value unchanged (%s)", exc)
    if fifo_priority is not None:
        try:
            policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
            os.sched_setscheduler(0, policy, os.sched_param(int(fifo_priority)))
            fifo = os.sched_getparam(0).sched_priority
        except (AttributeError, OSError) as exc:
            logger.info("stream stays in the ordinary scheduling class (%s)", exc)
    return nice, fifo


@contextlib.contextmanager
def stream_priority(steps: int = STREAM_PRIORITY_STEPS,
                    fifo_priority: int | None = STREAM_FIFO_PRIORITY) -> Iterator[tuple[int | None, int | None]]:
    """:func:`raise_stream_priority` for the block, then the process's nice value and
    scheduling class as they were (a caller that goes on after the stream, a test, keeps
    no real-time priority)."""
    saved = None
    try:
        saved = (os.getpriority(os.PRIO_PROCESS, 0), os.sched_getscheduler(0), os.sched_getparam(0))
    except (AttributeError, OSError):  # no such calls on this platform
        pass
    nice, fifo = raise_stream_priority(steps, fifo_priority)
    try:
        yield nice, fifo
    finally:
        if saved is not None:
            try:
                if fifo is not None:
                    os.sched_setscheduler(0, saved[1], saved[2])
                if nice is not None:
                    os.setpriority(os.PRIO_PROCESS, 0, saved[0])   # a higher nice value: always permitted
            except OSError as exc:
                logger.warning("stream priority not restored (%s)", exc)
