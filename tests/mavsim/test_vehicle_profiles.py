"""mavsim's vehicle profiles: the PX4 profile against PX4 SITL's measured step table, and its ``[sim]`` key."""

from __future__ import annotations

import numpy as np
import pytest

from companion.errors import ConfigError
from companion.loop.config import load_scenario as companion_load
from mavsim.errors import ScenarioError
from mavsim.personalities.px4_response import ControllerState, Px4Response, controller_step
from mavsim.scenario import load_scenario as mavsim_load
from tests.benchmarks.step_response import MEASURED_PX4_SITL, fraction_differences, step_table


@pytest.fixture(scope="module")
def px4_table():
    return step_table("px4")


def test_that_the_px4_profile_reproduces_the_measured_step_table(px4_table):
    d = np.abs(fraction_differences(px4_table))
    # 38 of 48 fractions within 0.05 today; the rest are the 1 m/s rows at 2 s (the measured
    # response stalls there, below its own 1 s value) and a few 0.06-0.07 entries
    assert (d <= 0.05 + 1e-9).sum() >= 36
    assert d.max() <= 0.16
    assert np.sqrt(np.mean(d**2)) <= 0.05
    for r, ref in zip(px4_table, MEASURED_PX4_SITL):
        assert r.t63_s == pytest.approx(ref[4], abs=0.25), r.label


def test_that_the_horizontal_response_has_two_parts_and_the_vertical_one_is_fast(px4_table):
    north_up = px4_table[0]
    assert 0.55 <= north_up.fractions[2] <= 0.7          # fast part: ~60 % within 1 s
    assert 5.0 <= north_up.t90_s <= 8.0                  # then a creep: 5 to 7 s to 90 %
    assert all(0.2 <= r.t63_s <= 0.35 for r in px4_table[4:])


def test_that_the_simple_lag_does_not_reproduce_the_table():
    d = np.abs(fraction_differences(step_table("lag")))
    assert (d <= 0.05).sum() < 24 and d.max() > 0.3


def test_that_the_integral_removes_the_drag_offset_at_steady_state():
    r, ctrl, v, vdot = Px4Response(), ControllerState.zero(), np.zeros(3), np.zeros(3)
    for _ in range(6000):                                # 60 s at 0.01 s
        ctrl, v_new = controller_step(ctrl, v, vdot, np.array([2.0, 0.0, -1.0]), 0.01, r)
        v, vdot = v_new, (v_new - v) / 0.01
    assert v == pytest.approx([2.0, 0.0, -1.0], abs=1e-3)
    assert ctrl.integral_mps2 == pytest.approx(r.drag_per_s * v, abs=1e-2)   # the integral holds the drag


def test_that_the_tilt_limit_bounds_the_horizontal_acceleration():
    r, ctrl = Px4Response(), ControllerState.zero()
    peak = 0.0
    v, vdot = np.zeros(3), np.zeros(3)
    for _ in range(300):
        ctrl, v_new = controller_step(ctrl, v, vdot, np.array([40.0, 0.0, 0.0]), 0.01, r)
        vdot = (v_new - v) / 0.01
        v = v_new
        peak = max(peak, float(np.hypot(*ctrl.thrust_accel_mps2[:2])))
    assert peak <= 9.80665 * np.tan(r.tilt_max_rad) + 1e-9 and peak > 9.0


@pytest.mark.parametrize("body, match", [
    ('vehicle = "px5"', r"bad\.toml: \[sim\] vehicle: must be one of lag, px4"),
    ('vehicle = "px4"\nvelocity_time_constant_s = 0.3', r"bad\.toml: \[sim\] velocity_time_constant_s: applies to vehicle"),
    ("vehicle = 4", r"bad\.toml: \[sim\] vehicle: must be a string"),
])
def test_that_a_bad_vehicle_profile_names_file_section_and_key(tmp_path, body, match):
    path = tmp_path / "bad.toml"
    path.write_text(f"[mission]\ngoal_ned_m = [1.0, 0.0, -5.0]\ngoal_tolerance_m = 0.3\n[sim]\n{body}\n")
    with pytest.raises(ScenarioError, match=match):
        mavsim_load(path)


def test_that_both_programs_accept_the_vehicle_key_and_reject_a_misspelt_one(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[mission]\ngoal_ned_m = [1.0, 0.0, -5.0]\ngoal_tolerance_m = 0.3\n[sim]\nvehicle = "px4"\n')
    assert mavsim_load(path).sim.vehicle == "px4"
    companion_load(path)
    path.write_text('[mission]\ngoal_ned_m = [1.0, 0.0, -5.0]\ngoal_tolerance_m = 0.3\n[sim]\nvehicel = "px4"\n')
    with pytest.raises(ConfigError, match=r"s\.toml \[sim\]: unknown key\(s\) vehicel"):
        companion_load(path)
    with pytest.raises(ScenarioError, match=r"s\.toml: \[sim\] unknown key 'vehicel'"):
        mavsim_load(path)
