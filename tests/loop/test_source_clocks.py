"""Per-source clock mapping (companion.loop.intake.source_clocks): offsets, drift, jumps, the future."""

from __future__ import annotations

import numpy as np
import pytest

from companion.loop.intake.source_clocks import SourceClock


def _stream(clock: SourceClock, offset_s: float, drift: float, n: int = 300, period_s: float = 0.1, seed: int = 0):
    """Feed n reports of a sender whose clock reads offset + (1 + drift) t; latency 2-30 ms."""
    rng = np.random.default_rng(seed)
    errors = []
    for i in range(n):
        t = 50.0 + i * period_s
        stamp_us = round((offset_s + (1.0 + drift) * t) * 1e6) % (1 << 64)
        t_rx = t + rng.uniform(0.002, 0.030)
        m = clock.map(stamp_us, t_rx, 1e-6)
        errors.append(m.t_s - t)
        assert m.t_s <= t_rx
    return np.array(errors), m


@pytest.mark.parametrize("offset_s", [-100.0, 5.5, 100.0, 1.7e9])
@pytest.mark.parametrize("drift", [0.0, 0.01, -0.01])
def test_that_a_sender_clock_maps_onto_arrival_time_within_the_latency_whatever_its_offset_and_drift(offset_s, drift):
    clock = SourceClock()
    errors, last = _stream(clock, offset_s, drift)
    settled = errors[30:]
    assert clock.epochs == 1  # never restarted
    assert np.all(settled > -0.01) and np.all(settled < 0.035), (settled.min(), settled.max())
    assert last.drift == pytest.approx(-drift / (1 + drift), abs=2e-3)


def test_that_a_uint64_stamp_from_a_clock_before_its_zero_maps_exactly():
    clock = SourceClock()
    errors, _ = _stream(clock, -1000.0, 0.0)  # 2**64 - 950e6 us ...: exact integer arithmetic
    assert np.all(np.abs(errors[30:]) < 0.035)


def test_that_a_garbage_stamp_restarts_the_mapping_and_the_next_good_stamp_restarts_it_again():
    clock = SourceClock()
    for i in range(20):
        assert not clock.map(1000 + 100 * i, 10.0 + 0.1 * i, 1e-3).restarted or i == 0
    bad = clock.map(0xFFFFFFFF, 12.0, 1e-3)
    assert bad.restarted and bad.t_s == pytest.approx(12.0)  # its arrival time: no earlier than that
    good = clock.map(3000, 12.1, 1e-3)
    assert good.restarted and good.t_s == pytest.approx(12.1)
    after = clock.map(3100, 12.2, 1e-3)
    assert not after.restarted and after.t_s == pytest.approx(12.2)
    assert clock.epochs == 3


def test_that_a_reboot_restarts_the_mapping_once():
    clock = SourceClock()
    for i in range(50):
        clock.map(600_000 + 100 * i, 10.0 + 0.1 * i, 1e-3)
    m = clock.map(0, 15.0, 1e-3)  # the sender rebooted: its boot clock starts again at 0
    assert m.restarted and m.t_s == pytest.approx(15.0)
    assert not clock.map(100, 15.1, 1e-3).restarted


def test_that_a_report_from_the_future_is_clamped_to_its_arrival():
    clock = SourceClock(jump_s=5.0)
    for i in range(30):
        clock.map(1000 + 100 * i, 10.0 + 0.1 * i + 0.02, 1e-3)
    m = clock.map(1000 + 100 * 30 + 2000, 13.02, 1e-3)  # stamped 2 s ahead, inside the jump tolerance
    assert m.clamped and m.t_s == pytest.approx(13.02)


def test_that_bad_settings_and_non_finite_times_raise():
    with pytest.raises(ValueError):
        SourceClock(window_s=0.0)
    with pytest.raises(ValueError):
        SourceClock().map(float("nan"), 1.0)


def test_that_the_envelope_is_refitted_only_when_its_bins_change_and_maps_as_a_fresh_fit():
    """The fit is a function of the bins: kept while a report changes none of them, it must map
    every stamp exactly as a fit made afresh at that report would (a clock kept up to date at
    every report is the reference)."""
    kept, fresh = SourceClock(), SourceClock()
    fits = []
    real = SourceClock._fit_envelope

    def counting(self):
        if self is kept:
            fits.append(1)
        return real(self)

    rng = np.random.default_rng(3)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SourceClock, "_fit_envelope", counting)
        for i in range(600):
            t = 10.0 + 0.05 * i
            stamp_us = round((7.0 + 1.001 * t) * 1e6)
            t_rx = t + rng.uniform(0.002, 0.030)
            fresh._fit = None                            # the reference refits at every report
            a, b = kept.map(stamp_us, t_rx, 1e-6), fresh.map(stamp_us, t_rx, 1e-6)
            assert (a.t_s, a.offset_s, a.drift, a.clamped) == (b.t_s, b.offset_s, b.drift, b.clamped)
    assert 0 < len(fits) < 400                           # most reports leave the bins as they were
