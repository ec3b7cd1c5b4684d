"""The stream's own figures (companion.realtime.stream.StreamStats): the setpoint gaps summed as
they come, so an hour of streaming holds no list of them."""

from __future__ import annotations

import tracemalloc

from companion.realtime.stream import StreamStats


def test_that_the_largest_gap_when_it_ended_and_the_gaps_over_the_limit_are_kept():
    stats = StreamStats()
    times = [100.0, 100.05, 100.10, 100.30, 100.35, 100.40, 100.60, 100.65]   # gaps of 200 ms twice
    for t in times:
        stats.note_setpoint(t)
    summary = stats.summary()
    assert summary["setpoint_gap_max_ms"] == 200.0
    assert summary["setpoint_gap_max_at_s"] == 0.3           # the first of the two largest, 0.3 s after the first setpoint
    assert summary["setpoint_gaps_over_150ms"] == 2
    assert summary["setpoints"] == 8 and summary["setpoint_rate_hz"] == round(7 / 0.65, 2)


def test_that_no_setpoint_gives_no_gap():
    summary = StreamStats().summary()
    assert summary["setpoint_gap_max_ms"] is None and summary["setpoint_gap_max_at_s"] is None
    assert summary["setpoint_gaps_over_150ms"] == 0


def test_that_an_hour_of_setpoints_takes_no_memory_of_its_own():
    stats = StreamStats()
    for i in range(1000):                                   # warm up (the probe's first allocations)
        stats.note_setpoint(i * 0.05)
    tracemalloc.start()
    try:
        for i in range(1000, 1000 + 72_000):                # an hour at 20 Hz
            stats.note_setpoint(i * 0.05)
        grown, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert grown < 20_000, grown                            # a list of the gaps would be about 2.3 MB
