"""The goal-approach reading tool (tests/px4/approach.py) on synthetic flights with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from companion.core.planner.vehicle_model import AxisResponse
from tests.px4.approach import GRID_S, crossing, model_prediction

START, GOAL = np.array([0.0, 0.0, -5.0]), np.array([24.0, 0.0, -5.0])


def _pass(side_m: float, speed_mps: float = 0.6) -> np.ndarray:
    """A straight pass north through the goal's plane at ``speed_mps`` (at t = 10 s), ``side_m``
    east of it, stopping 0.4 m beyond: rows (t s, position NED m, velocity NED m/s), OFFBOARD at t = 0."""
    t = np.arange(0.02, 20.0, 0.05)   # off the crossing instant: the sample after it is 0.012 m past
    north = np.minimum(speed_mps * (t - 10.0), 0.4)
    v = np.gradient(north, t)
    rows = np.zeros((t.size, 7))
    rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4] = t, GOAL[0] + north, side_m, GOAL[2], v
    return rows


def _crossing(odometry: np.ndarray) -> dict:
    """:func:`crossing` with a setpoint of -0.3 m/s north throughout and PX4's acceleration setpoint 0.1 m/s^2 north."""
    t = odometry[:, 0]
    setpoints = np.column_stack([t, np.full(t.size, -0.3), np.zeros((t.size, 2))])
    targets = np.column_stack([t, np.full(t.size, 0.1), np.zeros((t.size, 2))])
    return crossing(odometry, setpoints, targets, 0.0, START, GOAL, 0.3)


def test_that_a_pass_to_the_side_is_measured_at_the_goal_plane():
    got = _crossing(_pass(0.36))
    assert got["within_tolerance_s"] is None
    assert got["crosses_s"] == pytest.approx(10.0, abs=0.06)
    assert got["speed_along_mps"] == pytest.approx(0.6, abs=0.05)
    assert got["to_the_side_m"] == pytest.approx(0.36)
    assert got["beyond_m"] == pytest.approx(0.4, abs=1e-9)
    # more than 0.3 m past from t = 10.5 s to the end (19.97 s), at rest: error -0.3 m/s
    assert got["beyond_tolerance_s"] == pytest.approx(19.97 - 10.52, abs=0.06)
    assert got["velocity_error_along_mps"] == pytest.approx(-0.3, abs=0.02)
    assert got["px4_acceleration_setpoint_along_mps2"] == pytest.approx(0.1)


def test_that_a_pass_within_the_tolerance_is_found_on_the_way():
    got = _crossing(_pass(0.2))
    # inside once sqrt(n^2 + 0.2^2) <= 0.3: n >= -0.2236 m, 0.37 s before the plane at 0.6 m/s
    assert got["within_tolerance_s"] == pytest.approx(10.0 - np.sqrt(0.3**2 - 0.2**2) / 0.6, abs=0.06)
    assert got["to_the_side_m"] == pytest.approx(0.2)


def test_that_the_steady_and_observed_starts_predict_a_steady_cruise_exactly_and_the_open_integral_does_not():
    axis = AxisResponse(1.51, 0.3254, 0.8163, 0.2169)
    t = np.arange(0.0, 20.0, GRID_S / 2)
    v = np.array([1.5, 0.0, 0.0])
    odometry = np.column_stack([t, t[:, None] * v + START, np.tile(v, (t.size, 1))])
    setpoints = np.column_stack([t, np.tile(v, (t.size, 1))])
    rows = model_prediction(odometry, setpoints, 0.0, (axis, axis))
    steady = [r for r in rows if r["start"] in ("steady", "observed")]   # the observer starts there and stays
    carried = [r for r in rows if r["start"] == "carried" and r["axis"] == "N"]
    assert max(max(r["velocity_rms_mps"], r["position_rms_m"]) for r in steady) < 1e-9
    # the carried integral of setpoint less velocity is 0 here, not the drag it must hold
    assert min(r["position_rms_m"] for r in carried) > 0.01
