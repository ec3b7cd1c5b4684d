"""Waiting between the stream's polls: asleep until a link has bytes or the next tick is due.

The stream polls its links, ticks, handles obstacle traffic, then waits. Polling on a fixed
short period (2 ms) costs a wake-up and a read of every socket 500 times a second whether
anything came or not: about a fifth of a companion's CPU in a fleet of eight on two cores
(docs/FLEET.md). Polling less often would delay every message, and PX4 drops a TIMESYNC
round trip longer than 10 ms. :class:`LinkWait` waits on the links' file descriptors instead
(:mod:`selectors`: epoll on Linux), so the stream wakes when a packet arrives, at once, or
when the next tick is due, and sleeps otherwise.

Polls stay at most one a poll period: after a wake-up the wait first sleeps out the rest
of the period, so a busy link (a crowd of obstacle systems, thousands of datagrams a second)
is read in batches as before, and a descriptor that stays readable with nothing to parse (a
TCP peer that closed, bytes that are not MAVLink) costs what polling cost, never a busy loop.
It falls back to sleeping the poll period when a link has no file descriptor (an in-memory
link) or the caller injects its own ``sleep`` (a virtual clock).
"""

from __future__ import annotations

import selectors
import time
from collections.abc import Sequence
from typing import Callable

from companion.mavlink.link import Link


class LinkWait:
    """Wait until one of ``links`` is readable or a timeout (s) passes (see the module docstring).

    Parameters
    ----------
    links : the stream's links.
    sleep : the stream's sleep; anything but :func:`time.sleep` (a test's virtual clock) turns
        the wait on descriptors off.
    poll_period_s : the fallback's sleep, and the shortest time between two wake-ups.
    """

    def __init__(self, links: Sequence[Link], sleep: Callable[[float], None], poll_period_s: float) -> None:
        self._sleep, self.poll_period_s = sleep, float(poll_period_s)
        self._links = tuple(links)
        self._selector: selectors.BaseSelector | None = None
        self._fds: tuple[int | None, ...] = ()
        self._last_wake = -float("inf")   # monotonic s
        if sleep is time.sleep and self._links:
            self._selector = selectors.DefaultSelector()

    @property
    def on_descriptors(self) -> bool:
        """Whether the next wait ends when a link is readable (else it sleeps the poll period)."""
        return self._registered()

    def _registered(self) -> bool:
        """Register the links' descriptors as they are now (a ``tcpin`` link's changes once its
        peer connects); False when waits cannot be on them."""
        if self._selector is None:
            return False
        fds = tuple(link.fileno() for link in self._links)
        if fds != self._fds:
            self._selector.close()
            self._selector = selectors.DefaultSelector()
            self._fds = fds
            if None not in fds:
                for fd in set(fds):
                    self._selector.register(fd, selectors.EVENT_READ)
        return None not in fds

    def wait(self, until_tick_s: float) -> None:
        """Wait at most ``until_tick_s`` (s, the time to the next tick): until a link is readable,
        but not before a poll period has passed since the last wake-up."""
        until_tick_s = max(0.0, until_tick_s)
        if not self._registered():
            self._sleep(min(self.poll_period_s, until_tick_s))
            return
        assert self._selector is not None
        nap = min(self.poll_period_s - (time.monotonic() - self._last_wake), until_tick_s)
        if nap > 0.0:
            time.sleep(nap)
            until_tick_s -= nap
        if until_tick_s > 0.0:
            self._selector.select(until_tick_s)
        self._last_wake = time.monotonic()

    def close(self) -> None:
        if self._selector is not None:
            self._selector.close()
            self._selector = None
