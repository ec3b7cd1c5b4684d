"""mavsim's start like PX4 SITL (``--on-ground``) and obstacles from engagement
(``--obstacles-start offboard``), in the simulator itself (no sockets).

Checked: on the ground below the start point, disarmed, POSCTL; the obstacles wait at their
start points (reported and in truth) until the vehicle is first armed in OFFBOARD and then
follow their tracks from that moment; the default (from boot) keeps mavsim's bytes.
"""

from __future__ import annotations

import numpy as np
import pytest

from mavsim.core import Simulator
from mavsim.errors import SimulationError
from mavsim.personalities.base import OffboardSetpoint
from mavsim.scenario import load_scenario, on_the_ground

SCENARIO = "configs/antipodal.toml"
NAN3 = np.full(3, np.nan)


def test_that_on_the_ground_puts_the_vehicle_on_the_ground_disarmed_in_position_mode():
    sim = Simulator(on_the_ground(load_scenario(SCENARIO)))
    truth = sim.truth
    assert truth.on_ground and not truth.armed and truth.mode == "POSCTL"
    assert truth.drone_position_ned_m.tolist() == [0.0, 0.0, 0.0]


def test_that_obstacles_start_when_the_vehicle_is_first_armed_in_offboard():
    scenario = load_scenario(SCENARIO)
    sim = Simulator(scenario, obstacles_start="offboard")   # spawns airborne and armed in AUTO.LOITER
    starts = {ob.name: ob.start_ned_m for ob in scenario.obstacles}
    sim.advance_to(5_000_000)
    assert sim.obstacles_started_s is None
    for name, p in sim.truth.obstacle_positions_ned_m.items():
        assert np.array_equal(p, starts[name]), name
    # stream, then OFFBOARD at 5 s
    sp = OffboardSetpoint(NAN3, np.zeros(3), NAN3, np.nan, np.nan)
    sim.commander.accept_setpoint(sp, sim.time_s)
    sim.commander.request_mode(6, 0, sim.time_s, sim.vehicle)
    for k in range(1, 41):
        sim.commander.accept_setpoint(sp, sim.time_s)
        sim.advance_to(5_000_000 + k * 50_000)
    assert sim.obstacles_started_s == pytest.approx(5.0, abs=0.011)
    moved = sim.time_s - sim.obstacles_started_s
    head_on = sim.truth.obstacle_positions_ned_m["head-on"]
    assert head_on[0] == pytest.approx(24.0 - 1.5 * moved, abs=1e-9)
    summary = sim.summary()
    assert summary["obstacles_started_s"] == sim.obstacles_started_s
    # whole microseconds, the same float as a mode change's time at that instant in the JSON
    assert summary["obstacles_started_s"] == round(sim.motion_epoch_us * 1e-6, 6)


def test_that_obstacles_from_boot_are_the_default_and_a_bad_start_is_refused():
    sim = Simulator(SCENARIO)
    assert sim.obstacles_started_s == 0.0
    sim.advance_to(2_000_000)
    assert sim.truth.obstacle_positions_ned_m["head-on"][0] == pytest.approx(24.0 - 1.5 * 2.0)
    with pytest.raises(SimulationError, match="obstacles_start"):
        Simulator(SCENARIO, obstacles_start="later")
