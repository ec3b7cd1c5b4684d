"""The real-time edge's clock (companion.realtime.clock): Unix stamps a system clock step cannot move."""

from __future__ import annotations

import time

from companion.realtime.clock import SteadyUnixClock


class FakeClocks:
    """A system clock that an operator (or NTP) can step, beside a monotonic clock nothing moves."""

    def __init__(self) -> None:
        self.mono = 5000.0
        self.step_s = 0.0

    def wall(self) -> float:
        return 1_765_000_000.123456789 + (self.mono - 5000.0) + self.step_s

    def monotonic(self) -> float:
        return self.mono


def test_that_a_step_of_the_system_clock_moves_nothing():
    clocks = FakeClocks()
    clock = SteadyUnixClock(clocks.wall, clocks.monotonic)
    start = clock()
    assert start == round(clocks.wall() * 1e6) * 1e-6      # Unix time when the run began, whole microseconds
    readings = []
    for i in range(1, 401):                                  # 20 s at 20 Hz
        clocks.mono += 0.05
        if i == 100:
            clocks.step_s += 3600.0                          # a time sync steps the clock an hour forward
        if i == 200:
            clocks.step_s -= 7200.0                          # and two hours back
        readings.append(clock())
    steps = [b - a for a, b in zip([start, *readings], readings)]
    assert min(steps) > 0.0499 and max(steps) < 0.0501       # every tick 50 ms apart, through both steps
    assert abs(readings[-1] - start - 20.0) < 1e-6


def test_that_its_readings_are_whole_microseconds_a_tlog_stores_exactly():
    clock = SteadyUnixClock()
    for _ in range(100):
        t = clock()
        assert round(t * 1e6) * 1e-6 == t
    assert abs(clock() - time.time()) < 1.0                  # Unix time, on a machine whose clock was not stepped
