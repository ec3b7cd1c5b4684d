"""mavsim's autopilot personalities: the registry, and the core asking the personality.

A stand-in personality (PX4's with another HEARTBEAT identity and its own start mode)
registered for one test shows that adding an autopilot is a module plus its registration:
the simulator, the scenario's start mode and the HEARTBEAT follow it without other changes.
"""

from __future__ import annotations

import dataclasses

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim import personalities
from mavsim.cli import main as mavsim_main
from mavsim.core import Simulator
from mavsim.errors import SimulationError
from mavsim.personalities.ardupilot import ARDUPILOT
from mavsim.personalities.px4 import PX4, Px4Personality
from mavsim.scenario import load_scenario, on_the_ground

SCENARIO = "configs/antipodal.toml"


def _heartbeats(sim: Simulator) -> list:
    mav = mavlink2.MAVLink(file=None)
    mav.robust_parsing = True
    msgs = [m for _, _, data in sim.advance_to(2_000_000) for m in (mav.parse_buffer(data) or [])]
    return [m for m in msgs if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1]


def test_that_px4_is_registered_and_the_default():
    assert personalities.PERSONALITIES == {"px4": PX4, "ardupilot": ARDUPILOT}
    assert personalities.DEFAULT_PERSONALITY == "px4"
    assert Simulator(load_scenario(SCENARIO)).personality is PX4
    assert personalities.VEHICLE_PROFILES == ("lag", "px4", "ardupilot")
    assert personalities.velocity_response("lag") is None
    assert personalities.velocity_response("px4") is PX4.response_models["px4"]


def test_that_an_unknown_autopilot_is_one_clear_error(capsys):
    with pytest.raises(SimulationError, match=r"unknown autopilot 'nope' \(known: px4, ardupilot\)"):
        Simulator(load_scenario(SCENARIO), personality="nope")
    with pytest.raises(SystemExit):
        mavsim_main(["--lockstep", "--autopilot", "nope", "--duration", "1"])
    assert "invalid choice: 'nope'" in capsys.readouterr().err


class _Other(Px4Personality):
    """PX4's behaviour under another name, HEARTBEAT identity and mode list."""

    name = "other"
    mav_autopilot = 3            # MAV_AUTOPILOT_ARDUPILOTMEGA, for the test only
    mode_names = ("POSCTL", "AUTO.LOITER")

    def default_start_mode(self, airborne: bool) -> str:
        return "POSCTL"


def test_that_a_registered_personality_is_what_the_simulator_flies(monkeypatch):
    other = _Other()
    monkeypatch.setitem(personalities.PERSONALITIES, "other", other)
    scenario = load_scenario(SCENARIO)           # airborne, start_mode unset
    sim = Simulator(scenario, personality="other")
    assert sim.personality is other and sim.commander.mode == "POSCTL"
    assert {hb.autopilot for hb in _heartbeats(sim)} == {3}
    assert {hb.autopilot for hb in _heartbeats(Simulator(scenario))} == {12}
    # the scenario's start mode must be the personality's own
    takeoff = dataclasses.replace(scenario, sim=dataclasses.replace(scenario.sim, start_mode="AUTO.TAKEOFF"))
    with pytest.raises(SimulationError, match="start_mode 'AUTO.TAKEOFF' is not a mode of autopilot 'other'"):
        Simulator(takeoff, personality="other")
    assert Simulator(on_the_ground(scenario), personality="other").commander.mode == "POSCTL"
