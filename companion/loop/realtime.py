"""The real-time edge: wall clock, sleeping and a real link around the pure :class:`Companion`.

The loop polls the link often (inbound messages are stamped by the link's clock when
they arrive) and ticks the companion at its setpoint rate. If the process falls behind,
ticks are not bunched up: the schedule restarts from now, as a late setpoint is better
than a burst of stale ones.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

from companion.loop.app import Companion
from companion.mavlink.link import Link

logger = logging.getLogger(__name__)


@dataclass
class RealtimeStats:
    """What the real-time loop did."""

    ticks: int = 0
    late_ticks: int = 0
    wall_s: float = 0.0


def run_realtime(
    companion: Companion,
    link: Link,
    *,
    duration_s: float | None = None,
    stop: Callable[[Companion], bool] | None = None,
    clock: Callable[[], float] = time.time,
    sleep: Callable[[float], None] = time.sleep,
    poll_period_s: float = 0.002,
) -> RealtimeStats:
    """Run the companion against a live link until ``duration_s`` passes or ``stop(companion)``.

    Parameters
    ----------
    companion : the control loop.
    link : an open link (its clock should be ``clock`` so receive stamps and ticks agree).
    duration_s : wall seconds to run; None runs until ``stop`` or KeyboardInterrupt.
    stop : checked after every tick.
    clock, sleep : injectable for tests.
    """
    period = 1.0 / companion.loop.setpoint_rate_hz
    stats = RealtimeStats()
    start = clock()
    next_tick = start
    while True:
        for rx in link.poll():
            companion.handle(rx)
        now = clock()  # after the poll: every message handled before a tick is stamped no later than it
        if now >= next_tick:
            for msg in companion.tick(now):
                link.send(msg, t_s=now)  # stamped with the tick time: replay ticks at the same times
            stats.ticks += 1
            next_tick += period
            if next_tick < now:
                stats.late_ticks += 1
                next_tick = now + period
            if stop is not None and stop(companion):
                break
        if duration_s is not None and now - start >= duration_s:
            break
        sleep(max(0.0, min(poll_period_s, next_tick - clock())))
    stats.wall_s = clock() - start
    return stats
