"""The real-time edge's clock: Unix time at the start, then the monotonic clock's steps.

The stream schedules ticks, stamps every message it receives and sends, and the tlog keeps
those stamps (Unix epoch, whole microseconds) so a replay acts at exactly the same times.
Read straight from the system clock (``time.time``), those times jump whenever the
system clock is stepped: an NTP or GPS time sync on a companion computer without a
real-time clock (a Raspberry Pi) steps it by seconds to years, often minutes after boot,
when the network or the vehicle's GPS time first arrives. A step back stopped the setpoint
stream until the clock caught up (the next tick's time lay in the future), and a step forward
made every plan look old at once.

:class:`SteadyUnixClock` reads the system clock once, at construction, and from then on
advances with ``time.monotonic`` (which no step moves): the stamps stay Unix time as the run
began, never go back, and measure real intervals. After a step they differ from the system
clock by the step; the run's own times stay consistent with each other, which is all the
loop and a replay use.
"""

from __future__ import annotations

import time
from typing import Callable


class SteadyUnixClock:
    """Seconds since the Unix epoch, rounded to whole microseconds, immune to system clock steps.

    Parameters
    ----------
    wall, monotonic : the system clock and the monotonic clock (s); injectable for tests.
    """

    def __init__(self, wall: Callable[[], float] = time.time, monotonic: Callable[[], float] = time.monotonic) -> None:
        self._monotonic = monotonic
        self._mono0 = monotonic()
        self._unix0_us = round(wall() * 1e6)

    def __call__(self) -> float:
        """Now (s since the epoch), a whole number of microseconds: what a tlog stores, exactly."""
        return (self._unix0_us + round((self._monotonic() - self._mono0) * 1e6)) * 1e-6
