"""``companion identify`` on mavsim's vehicle profiles, flown in lockstep: the responses they simulate.

The identification steps (:func:`companion.offline.identify.step_sequence`) are streamed at 20 Hz
to mavsim hovering 5 m up with an autopilot personality and its vehicle profile (PX4 in OFFBOARD,
ArduPilot in GUIDED with its streams requested as ``fly`` requests them), and everything both
sides send is written to a tlog on the simulator's clock, as ``fly --identify`` records it. The
command itself is flown in real time against mavsim (tests/commands/test_fly_identify.py) and
against real PX4 SITL (tests/px4/test_ulog_identify.py).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages
from companion.mavlink.autopilots.ardupilot import ARDUPILOT
from companion.mavlink.tlog import TlogWriter
from companion.offline.identify import identify, load_response_log, step_sequence
from mavsim.core import Simulator
from mavsim.scenario import scenario_from_dict

T0 = 1_800_000_000.0            # the tlog's unix time at the simulator's boot (s)
PERIOD_US = 50_000              # the setpoint stream, 20 Hz
COMMANDED = {"px4": "OFFBOARD", "ardupilot": "GUIDED"}


def fly_steps_in_lockstep(path, autopilot: str):
    """The step sequence flown by mavsim with ``autopilot``'s personality and vehicle profile, in
    lockstep, recorded to the tlog ``path``; the simulator afterwards."""
    sim = Simulator(scenario_from_dict({"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
                                        "sim": {"vehicle": autopilot, "start_mode": COMMANDED[autopilot]}}),
                    seed=3, personality=autopilot)
    mav = mavlink2.MAVLink(None, 255, 191)
    t_us = 0
    with TlogWriter(path) as log:
        def send(msg) -> None:
            data = bytes(msg.pack(mav))
            log.write(T0 + t_us * 1e-6, data)
            sim.receive(data)

        if autopilot == "ardupilot":
            for message_id, rate_hz in ARDUPILOT.streams:
                send(messages.set_message_interval_command(message_id, rate_hz, target_system=1, target_component=1))
        for duration_s, v in [(2.0, (0.0, 0.0, 0.0)), *step_sequence()]:
            for _ in range(int(round(duration_s * 1e6 / PERIOD_US))):
                send(messages.velocity_setpoint(t_us // 1000, v))
                t_us += PERIOD_US
                for sent_us, _, data in sim.advance_to(t_us):
                    log.write(T0 + sent_us * 1e-6, data)
    return sim


def test_that_mavsims_px4_profile_is_identified_as_a_two_part_response(tmp_path):
    tlog = tmp_path / "steps.tlog"
    sim = fly_steps_in_lockstep(tlog, "px4")
    assert sim.commander.mode == "OFFBOARD"                   # the stream kept it there all along
    result = identify(load_response_log(tlog))
    lag, model = result.figures["lag 0.3 s"], result.figures["model"]
    print(result.horizontal, lag, model)
    assert lag["one_step_rms_horizontal"] > 3 * model["one_step_rms_horizontal"]
    assert 1.0 < result.horizontal.p_gain_per_s < 2.5 and result.horizontal.i_gain_per_s2 > 0.1


def test_that_mavsims_ardupilot_profile_is_identified_better_than_a_lag(tmp_path):
    tlog = tmp_path / "steps.tlog"
    sim = fly_steps_in_lockstep(tlog, "ardupilot")
    assert sim.commander.mode == "GUIDED"
    result = identify(load_response_log(tlog))
    lag, model = result.figures["lag 0.3 s"], result.figures["model"]
    print(result.horizontal, lag, model)
    assert lag["one_step_rms_all"] > 2 * model["one_step_rms_all"]
