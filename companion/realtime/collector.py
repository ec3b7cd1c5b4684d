"""Python's garbage collector in the stream process: old objects out of its way, pauses measured.

A full (generation 2) collection walks every container object the process holds. In the
stream of ``companion fly`` that is about 80,000 objects before the first tick (numpy,
scipy, pymavlink, the planner's and tracker's state) and about 90,000 with 200 obstacle
tracks; one such walk took 96-106 ms on the 2-core development machine, stopping the
setpoint stream for as long (gaps of 114-143 ms where 50 ms is the period; a clean-clone
CI run measured a 168 ms gap). :func:`collector_for_real_time` freezes everything that exists
when the stream starts (:func:`gc.freeze`: those objects move to a permanent generation
that collections skip), so a collection walks only what the run itself allocated, and
measures the longest pause it sees. Measured the same way with the freeze: no collection
over 5 ms, largest setpoint gap 53 ms.

Frozen objects are not freed while frozen; the context unfreezes on exit so a process that
runs many streams (the test suite) does not accumulate them.
"""

from __future__ import annotations

import contextlib
import gc
import time
from collections.abc import Iterator
from dataclasses import dataclass


@dataclass
class CollectorPauses:
    """Collections seen while the stream ran: how many and the longest (seconds, wall)."""

    collections: int = 0
    max_pause_s: float = 0.0


@contextlib.contextmanager
def collector_for_real_time() -> Iterator[CollectorPauses]:
    """Freeze the objects that exist now and time every collection until the block ends."""
    pauses = CollectorPauses()
    started = [0.0]

    def on_collection(phase: str, info: dict) -> None:
        if phase == "start":
            started[0] = time.perf_counter()
        else:
            pauses.collections += 1
            pauses.max_pause_s = max(pauses.max_pause_s, time.perf_counter() - started[0])

    gc.freeze()
    gc.callbacks.append(on_collection)
    try:
        yield pauses
    finally:
        gc.callbacks.remove(on_collection)
        gc.unfreeze()
