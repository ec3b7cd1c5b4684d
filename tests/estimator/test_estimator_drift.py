"""The drift of a position estimate against its own velocity (estimator.drift)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator import EstimatorConfigError, PositionDrift


def fed(drift: PositionDrift, seconds: float, rate_hz: float, velocity, extra, t0: float = 0.0, p0=(0.0, 0.0, -5.0)):
    """Reports at ``rate_hz`` whose position moves at ``velocity + extra`` while they say ``velocity``."""
    v, e = np.asarray(velocity, float), np.asarray(extra, float)
    for k in range(int(round(seconds * rate_hz)) + 1):
        t = t0 + k / rate_hz
        drift.add(t, np.asarray(p0) + (v + e) * (t - t0), v)


def test_that_a_consistent_estimate_has_no_drift_and_an_inconsistent_one_has_its_rate():
    consistent = PositionDrift(2.0)
    fed(consistent, 3.0, 30.0, [1.5, -0.5, 0.2], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(consistent.value(), 0.0, atol=1e-12)
    drifting = PositionDrift(2.0)
    fed(drifting, 3.0, 30.0, [1.5, -0.5, 0.2], [0.0, -0.4, 0.3])
    np.testing.assert_allclose(drifting.value(), [0.0, -0.4, 0.3], atol=1e-12)


def test_that_the_velocity_is_integrated_by_the_trapezoid_rule():
    # velocity ramps 0 -> 2 m/s over 2 s and the position follows it exactly (x = t^2 / 2): no drift
    d = PositionDrift(2.0)
    for k in range(41):
        t = k * 0.05
        d.add(t, [0.5 * t * t, 0.0, 0.0], [t, 0.0, 0.0])
    np.testing.assert_allclose(d.value(), 0.0, atol=1e-12)


def test_that_only_the_last_window_counts_and_memory_is_bounded():
    d = PositionDrift(1.0, max_reports=50)
    fed(d, 2.0, 50.0, [1.0, 0.0, 0.0], [0.5, 0.0, 0.0])               # an old drift north...
    fed(d, 1.0, 50.0, [1.0, 0.0, 0.0], [0.0, 0.2, 0.0], t0=2.02, p0=(3.0, 0.0, -5.0))   # ...then east only
    np.testing.assert_allclose(d.value(), [0.0, 0.2, 0.0], atol=1e-9)
    assert len(d._reports) <= 50
    # 10,000 reports at 1 kHz keep at most max_reports
    fed(d, 10.0, 1000.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], t0=10.0)
    assert len(d._reports) <= 50


def test_that_it_says_nothing_before_half_a_window_and_forgets_on_clear():
    d = PositionDrift(2.0)
    fed(d, 0.9, 20.0, [0.0, 0.0, 0.0], [0.3, 0.0, 0.0])
    np.testing.assert_array_equal(d.value(), 0.0)
    fed(d, 0.2, 20.0, [0.0, 0.0, 0.0], [0.3, 0.0, 0.0], t0=0.95, p0=(0.285, 0.0, -5.0))
    assert d.value()[0] == pytest.approx(0.3, abs=1e-9)
    d.clear()
    np.testing.assert_array_equal(d.value(), 0.0)


def test_that_a_jump_is_bounded_and_bad_or_old_reports_are_ignored():
    d = PositionDrift(1.0, max_mps=0.8)
    fed(d, 1.0, 20.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    d.add(1.05, [5.0, -5.0, -5.0], [0.0, 0.0, 0.0])        # an estimate reset by metres
    np.testing.assert_allclose(d.value(), [0.8, -0.8, 0.0])
    before = d.value().copy()
    for t, p, v in ((1.0, [9.0, 9.0, 9.0], [0, 0, 0]), (1.05, [9.0, 9.0, 9.0], [0, 0, 0]),
                    (1.2, [np.nan, 0, 0], [0, 0, 0]), (1.2, [0, 0, 0], [np.inf, 0, 0]), (np.nan, [0, 0, 0], [0, 0, 0])):
        d.add(t, p, v)
    np.testing.assert_array_equal(d.value(), before)


@pytest.mark.parametrize("kwargs", [{"window_s": 0.0}, {"window_s": float("nan")}, {"window_s": 1.0, "max_mps": 0.0}])
def test_that_bad_settings_are_refused_by_name(kwargs):
    with pytest.raises(EstimatorConfigError, match="PositionDrift"):
        PositionDrift(**kwargs)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-0.9, 0.9), min_size=3, max_size=3), st.lists(st.floats(-3, 3), min_size=3, max_size=3),
       st.floats(5.0, 100.0))
def test_that_any_constant_drift_within_the_bound_is_recovered(extra, velocity, rate_hz):
    d = PositionDrift(1.0)
    fed(d, 1.5, rate_hz, velocity, extra)
    np.testing.assert_allclose(d.value(), extra, atol=1e-9)
