"""mavsim's fleets: vehicles with their own system ids, rotated starts and goals, and the pair referee (mavsim/fleet.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.cli import main
from mavsim.errors import SimulationError
from mavsim.fleet import FleetServer, pair_clearances, rotated, rotated_scenarios
from mavsim.lockstep import LockstepSimulator
from mavsim.personalities.base import OffboardSetpoint
from mavsim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
SWAP = ROOT / "configs" / "swap.toml"
NAN3 = np.full(3, np.nan)


def test_that_vehicle_i_of_n_is_the_scenario_turned_by_i_over_n_about_the_middle_of_its_route():
    sc = load_scenario(SWAP)
    fleet = rotated_scenarios(sc, 4)
    assert [s.name for s in fleet] == [f"swap-{i}" for i in range(1, 5)]
    assert np.allclose(fleet[0].start_ned_m, sc.start_ned_m) and np.allclose(fleet[0].goal_ned_m, sc.goal_ned_m)
    assert np.allclose(fleet[1].start_ned_m, [0.0, 6.0, -5.0]) and np.allclose(fleet[1].goal_ned_m, [0.0, -6.0, -5.0])
    assert np.allclose(fleet[2].start_ned_m, [-6.0, 0.0, -5.0])
    start, goal = rotated([0.0, 0.0, -5.0], None, 1, 2)
    assert goal is None and np.allclose(start, [0.0, 0.0, -5.0])
    with pytest.raises(SimulationError, match="1 to 16"):
        rotated_scenarios(sc, 17)


def test_that_each_vehicle_speaks_with_its_own_system_id_and_obeys_only_commands_for_it():
    sim = LockstepSimulator(load_scenario(SWAP), system_id=3)
    packets = sim.advance(1.0)
    parser = mavlink2.MAVLink(None)
    systems = {parser.parse_char(p).get_srcSystem() for _, p in packets}
    assert systems == {3}
    for target, armed_after in ((1, True), (3, False)):   # it starts armed; a disarm for system 1 is not for it
        cmd = mavlink2.MAVLink_command_long_message(target, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                                    0, 21196, 0, 0, 0, 0, 0)
        sim.write(cmd.pack(mavlink2.MAVLink(None, 255, 190)))
        sim.advance(0.1)
        assert sim.truth.armed is armed_after
    with pytest.raises(SimulationError, match="system_id"):
        LockstepSimulator(load_scenario(SWAP), system_id=101)


def _trace(points, t0=0.0, dt=0.1):
    return [{"t_s": t0 + k * dt, "drone_ned_m": list(p)} for k, p in enumerate(points)]


def test_that_the_pair_referee_finds_the_closest_approach_between_samples():
    # two vehicles crossing head-on 0.2 m apart laterally at 3 m/s each: samples every 0.1 s straddle the meeting
    a = _trace([(-1.05 + 0.3 * k, 0.0, -5.0) for k in range(8)])
    b = _trace([(1.05 - 0.3 * k, 0.2, -5.0) for k in range(8)])
    (pair,) = pair_clearances([a, b], [0.5, 0.5]).items()
    assert pair[0] == "1-2"
    assert pair[1]["min_distance_m"] == pytest.approx(0.2, abs=1e-9)      # no sample is nearer than 0.36 m
    assert pair[1]["min_clearance_m"] == pytest.approx(-0.8, abs=1e-9)
    assert pair[1]["t_s"] == pytest.approx(0.35, abs=1e-9)
    assert pair_clearances([a, _trace([(0, 0, 0)], t0=10.0)], [0.5, 0.5]) == {}   # no common time span


def test_that_a_fleet_serves_each_vehicle_on_its_own_ports_and_judges_every_pair():
    fleet = FleetServer(rotated_scenarios(load_scenario(SWAP), 3), seed=0, api_port=40000, api_local_port=0,
                        gcs_port=None, gcs_local_port=None, obstacle_port=40100, obstacle_local_port=0, speed=10.0)
    with fleet:
        assert [sorted(p) for p in fleet.local_ports] == [["api", "obstacles"]] * 3
        fleet.run(2.0)
        summary = fleet.summary()
    assert summary["vehicles"] == 3 and sorted(summary["pairs"]) == ["1-2", "1-3", "2-3"]
    assert [sim.system_id for sim in fleet.sims] == [1, 2, 3]
    # hovering at their starts, 6 m from the centre, 120 deg apart: 10.39 m apart, less both radii
    assert summary["pairs"]["1-2"]["min_clearance_m"] == pytest.approx(6.0 * math.sqrt(3.0) - 1.0, abs=0.1)
    assert not summary["collided"]


def _engage(sim, t_us: int) -> None:
    """Stream a hover setpoint and switch to OFFBOARD at ``t_us`` (sim's own clock), 0.5 s of streaming after."""
    sp = OffboardSetpoint(NAN3, np.zeros(3), NAN3, np.nan, np.nan)
    sim.advance_to(t_us)
    sim.commander.accept_setpoint(sp, sim.time_s)
    sim.commander.request_mode(6, 0, sim.time_s, sim.vehicle)
    for k in range(1, 11):
        sim.commander.accept_setpoint(sp, sim.time_s)
        sim.advance_to(t_us + k * 50_000)


def test_that_a_fleets_traffic_starts_for_every_vehicle_once_the_last_one_has_engaged():
    scenario = load_scenario(SWAP)
    fleet = FleetServer(rotated_scenarios(scenario, 2), seed=0, api_port=40000, api_local_port=0, gcs_port=None,
                        gcs_local_port=None, obstacle_port=40100, obstacle_local_port=0, obstacles_start="offboard")
    starts = {ob.name: ob.start_ned_m for ob in scenario.obstacles}
    with fleet:
        one, two = fleet.sims
        _engage(one, 2_000_000)                # vehicle 1 flies from 2 s; vehicle 2's companion is late
        two.advance_to(one.now_us)
        assert fleet.engagement.engaged == [True, False]
        for sim in fleet.sims:
            assert sim.obstacles_started_s is None
            for name, p in sim.truth.obstacle_positions_ned_m.items():
                assert np.array_equal(p, starts[name]), name
        one.advance_to(6_000_000)              # the fleet's clocks run side by side
        _engage(two, 6_000_000)                # engaged at 6 s: now both vehicles' traffic moves
        one.advance_to(two.now_us)
        started = [sim.obstacles_started_s for sim in fleet.sims]
    assert started[1] == pytest.approx(6.0, abs=0.011)
    assert started[0] == pytest.approx(6.0, abs=0.011)   # vehicle 1 sees it on its next step
    for sim in fleet.sims:
        moved = sim.time_s - sim.obstacles_started_s
        assert np.linalg.norm(sim.truth.obstacle_positions_ned_m["traffic-1"] - starts["traffic-1"]) == \
            pytest.approx(1.5 * moved, abs=1e-6)


def test_that_a_fleet_from_boot_moves_its_traffic_at_once():
    fleet = FleetServer(rotated_scenarios(load_scenario(SWAP), 2), seed=0, api_port=40000, api_local_port=0,
                        gcs_port=None, gcs_local_port=None, obstacle_port=40100, obstacle_local_port=0)
    with fleet:
        assert [sim.obstacles_started_s for sim in fleet.sims] == [0.0, 0.0]


@pytest.mark.parametrize("flag", [["--lockstep"], ["--serial", "/dev/null"], ["--tlog", "x.tlog"]])
def test_that_what_a_fleet_cannot_do_is_one_line_and_exit_2(flag, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["--scenario", str(SWAP), "--vehicles", "2", "--duration", "0.1", *flag]) == 2
    err = capsys.readouterr().err.strip()
    assert "not available with --vehicles" in err and len(err.splitlines()) == 1


def test_that_the_command_runs_a_fleet_and_prints_its_summary(capsys, tmp_path):
    trace = tmp_path / "truth.jsonl"
    assert main(["--scenario", str(SWAP), "--vehicles", "2", "--no-gcs", "--api-port", "40200", "--api-local-port", "0",
                 "--obstacle-port", "40300", "--obstacle-local-port", "0", "--speed", "20", "--duration", "1.0",
                 "--json", "--truth-trace", str(trace)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["vehicles"] == 2 and list(summary["pairs"]) == ["1-2"]
    rows = [json.loads(line) for line in trace.read_text().splitlines()]
    assert {r["vehicle"] for r in rows} == {1, 2}
