"""The autopilot's reported position uncertainty said to the operator (companion/loop/position_quality.py)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.loop.position_quality import PositionQuality, largest_sd_m


def _cov(sd_x: float, sd_y: float = 0.1, sd_z: float = 0.1) -> np.ndarray:
    return np.diag([sd_x ** 2, sd_y ** 2, sd_z ** 2])


def test_that_the_largest_deviation_is_along_the_major_axis():
    assert largest_sd_m(_cov(0.3, 0.4, 0.2)) == pytest.approx(0.4)
    rotated = np.array([[0.5, 0.4, 0.0], [0.4, 0.5, 0.0], [0.0, 0.0, 0.01]])   # eigenvalues 0.9, 0.1, 0.01
    assert largest_sd_m(rotated) == pytest.approx(np.sqrt(0.9))


def test_that_an_uncertain_position_is_said_once_and_certain_again_once_with_a_hysteresis():
    q = PositionQuality(0.5)
    said = [q.update(_cov(sd)) for sd in (0.15, 0.3, 0.49, 0.5, 0.9, 1.2, 0.45, 0.36, 0.34, 0.2, 0.6)]
    assert said == [None, None, None, "companion: position uncertain (sd 0.50 m)", None, None, None, None,
                    "companion: position certain again (sd 0.34 m)", None, "companion: position uncertain (sd 0.60 m)"]
    assert q.events == 2 and q.uncertain and q.largest_sd_m == pytest.approx(1.2)
    assert all(len(text) <= 50 for text in said if text)      # a STATUSTEXT holds 50 characters


def test_that_nothing_is_said_without_a_reported_covariance_or_for_the_same_report_twice():
    q = PositionQuality(0.5)
    assert q.update(None) is None and q.largest_sd_m is None
    cov = _cov(0.8)
    assert q.update(cov) is not None
    q.uncertain = False                      # the same report again is not judged again
    assert q.update(cov) is None and q.events == 1
    assert q.update(np.full((3, 3), np.nan)) is None
