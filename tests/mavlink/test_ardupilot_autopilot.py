"""ArduPilot (ArduCopter) through the autopilot boundary, and its engagement in the offboard sequencer:
wait for the EKF's absolute position, request the streams, GUIDED, arm, take off in GUIDED to a height
above home (complete by the vehicle's estimate), engage, hand back to LOITER or BRAKE."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import ConfigError, InputError
from companion.mavlink import autopilots, messages
from companion.mavlink.autopilots import ModeRole, ardupilot
from companion.mavlink.autopilots.ardupilot import ARDUPILOT, CopterMode
from companion.mavlink.messages import CommandAck, VehicleHeartbeat
from companion.mavlink.offboard import OffboardConfig, OffboardSequencer, Phase, SendCommand

READY, NOT_READY = 831, 167   # EKF_STATUS_REPORT flags measured on ArduCopter SITL (README)


def hb(mode=CopterMode.STABILIZE, armed=False, key=(1, 1), autopilot=3):
    return VehicleHeartbeat(sysid=key[0], compid=key[1], autopilot=autopilot, type=2,
                            base_mode=(217 if armed else 89), custom_mode=int(mode), system_status=3, armed=armed,
                            mode=ARDUPILOT.mode_name(mode), is_autopilot=autopilots.of_heartbeat(*key, autopilot, 2) is not None,
                            role=ARDUPILOT.mode_role(mode), kind=autopilots.by_mav_autopilot(autopilot))


def test_that_the_registry_knows_ardupilot_by_its_heartbeat():
    assert autopilots.of_heartbeat(1, 1, 3, 2) is ARDUPILOT
    assert autopilots.by_choice("ardupilot") is ARDUPILOT and autopilots.by_choice("auto") is None
    assert autopilots.AUTOPILOT_CHOICES == ("auto", "px4", "ardupilot")


@pytest.mark.parametrize(("mode", "role"), [
    (CopterMode.GUIDED, ModeRole.OFFBOARD), (CopterMode.LOITER, ModeRole.HOLD), (CopterMode.BRAKE, ModeRole.HOLD),
    (CopterMode.AUTO, ModeRole.MISSION), (CopterMode.STABILIZE, ModeRole.OTHER), (CopterMode.RTL, ModeRole.OTHER),
    (CopterMode.AVOID_ADSB, ModeRole.OTHER),
    (99, ModeRole.OTHER)])
def test_that_copter_modes_have_their_roles(mode, role):
    assert ARDUPILOT.mode_role(mode) is role


def test_that_mode_names_requests_and_set_mode_params_are_arducopters():
    assert ARDUPILOT.mode_name(4) == "GUIDED" and ARDUPILOT.mode_name(17) == "BRAKE" and ARDUPILOT.mode_name(99) == "UNKNOWN(99)"
    assert ardupilot.custom_mode_from_name("loiter") == 5
    assert [ARDUPILOT.custom_mode_of(r) for r in (ModeRole.OFFBOARD, ModeRole.HOLD, ModeRole.BRAKE)] == [4, 5, 17]
    assert ARDUPILOT.set_mode_params(4, armed=True) == (1.0, 4.0)
    with pytest.raises(InputError):
        ARDUPILOT.set_mode_params(8, armed=False)
    assert ARDUPILOT.takeoff_param7(5.0, 488.0) == 5.0       # metres above home, not AMSL


def test_that_readiness_needs_an_absolute_horizontal_position_and_no_constant_position_mode():
    assert not ARDUPILOT.ready(NOT_READY) and ARDUPILOT.ready(READY)
    assert not ARDUPILOT.ready(16 | 128) and ARDUPILOT.ready(16)


def test_that_ekf_status_report_is_decoded_from_the_ardupilot_dialect():
    from pymavlink.dialects.v20 import ardupilotmega as apm
    msg = apm.MAVLink_ekf_status_report_message(831, 0.1, 0.1, 0.1, 0.1, 0.0)
    mav = apm.MAVLink(None, 1, 1)
    parsed = autopilots.DIALECT.MAVLink(None).parse_buffer(bytes(msg.pack(mav)))[0]
    assert messages.decode(parsed) == messages.EstimatorStatus(key=(1, 1), flags=831)


class Copter:
    """A scripted ArduCopter: HEARTBEAT at 1 Hz, EKF status at 2 Hz, its pose at 20 Hz; obeys commands."""

    def __init__(self, config: OffboardConfig, ready_at_s: float = 3.0, refuse_arm: int = 0):
        self.seq = OffboardSequencer(config)
        self.mode, self.armed, self.height, self.t = CopterMode.STABILIZE, False, 0.0, 0.0
        self.ready_at_s, self.refuse_arm = ready_at_s, refuse_arm
        self.target_height: float | None = None
        self.sent: list[tuple[float, mavlink2.MAVLink_message]] = []

    def run(self, duration_s: float) -> Phase:
        end = self.t + duration_s
        while self.t < end - 1e-9:
            ms = round(self.t * 1000)
            if ms % 1000 == 0:
                self.seq.on_heartbeat(self.t, hb(self.mode, self.armed))
            if ms % 500 == 0:
                self.seq.on_estimator_status(self.t, READY if self.t >= self.ready_at_s else NOT_READY)
            if self.target_height is not None:
                self.height = min(self.target_height, self.height + 2.5 * 0.05)
            if ms % 50 == 0 and self.t >= self.ready_at_s:
                climbing = self.target_height is not None and self.height < self.target_height
                self.seq.on_vehicle_position(self.t, -self.height, -2.5 if climbing else 0.0)
            for a in self.seq.step(self.t):
                if isinstance(a, SendCommand):
                    self.sent.append((self.t, a.msg))
                    self._obey(a.msg)
            self.t = round(self.t + 0.05, 6)
        return self.seq.phase

    def _obey(self, msg) -> None:
        if msg.get_type() != "COMMAND_LONG":
            return
        result = 0
        if msg.command == 176:
            self.mode = CopterMode(int(msg.param2))
        elif msg.command == 400:
            if self.refuse_arm > 0:
                self.refuse_arm -= 1
                result = 4
            else:
                self.armed = True
        elif msg.command == 22:
            if self.mode == CopterMode.GUIDED and self.armed:
                self.target_height = msg.param7
            else:
                result = 4
        self.seq.on_ack(self.t, CommandAck(key=(1, 1), command=msg.command, result=result, target_system=245,
                                           target_component=191))

    def commands(self, command: int) -> list[tuple[float, mavlink2.MAVLink_message]]:
        return [(t, m) for t, m in self.sent if m.get_type() == "COMMAND_LONG" and m.command == command]


def test_that_arducopter_is_waited_for_then_put_in_guided_armed_and_taken_off_above_home_before_streaming():
    cop = Copter(OffboardConfig(arm=True, takeoff_alt_m=5.0, takeoff_settle_s=1.0), ready_at_s=10.0, refuse_arm=2)
    assert cop.run(5.0) is Phase.WAIT_READY and not cop.seq.state.streaming
    streams = cop.commands(511)
    assert {int(m.param1) for _, m in streams} >= {32, 193, 242}         # LOCAL_POSITION_NED, EKF status, home
    assert [int(m.param2) for _, m in streams if int(m.param1) == 32][0] == 20000   # 50 Hz
    assert not cop.commands(400) and not cop.commands(176)              # nothing commanded before the EKF is ready
    cop.run(20.0)
    set_modes, arms, takeoffs = cop.commands(176), cop.commands(400), cop.commands(22)
    assert set_modes[0][0] >= 10.0 and set_modes[0][1].param2 == 4      # GUIDED first
    assert arms[0][0] > set_modes[0][0] and len(arms) == 3              # refused twice, retried
    assert takeoffs[0][1].param7 == 5.0 and takeoffs[0][0] > arms[-1][0]
    assert cop.seq.phase is Phase.ENGAGED and cop.seq.state.streaming
    assert any("takeoff height reached: 5.00 m" in e.text for e in cop.seq.events)
    assert not cop.commands(512)                                       # no HOME_POSITION wait: param7 is relative
    n = len(cop.commands(511))
    assert n == 2 * len(streams)                                       # asked again 5 s later: not ready yet
    cop.run(10.0)
    assert len(cop.commands(511)) == n                                 # ready and the pose flows: asked no more


def test_that_nothing_is_streamed_during_the_takeoff_in_guided():
    cop = Copter(OffboardConfig(arm=True, takeoff_alt_m=5.0), ready_at_s=0.0)
    seen = []
    while cop.t < 8.0:
        cop.run(0.05)
        seen.append((cop.seq.phase, cop.seq.state.streaming))
    assert all(not streaming for phase, streaming in seen if phase is Phase.TAKEOFF)
    assert seen[-1] == (Phase.ENGAGED, True)


@pytest.mark.parametrize(("hand_back_mode", "mode"), [("hold", 5), ("brake", 17)])
def test_that_the_hand_back_asks_for_loiter_or_brake(hand_back_mode, mode):
    cop = Copter(OffboardConfig(arm=True, takeoff_alt_m=5.0, hand_back_mode=hand_back_mode), ready_at_s=0.0)
    cop.run(8.0)
    assert cop.seq.phase is Phase.ENGAGED
    assert cop.seq.hand_back(cop.t, "done")
    cop.run(2.0)
    assert cop.commands(176)[-1][1].param2 == mode and cop.seq.phase is Phase.HELD


def test_that_the_takeoff_gives_up_when_the_height_is_never_reached():
    cop = Copter(OffboardConfig(arm=True, takeoff_alt_m=5.0, takeoff_timeout_s=5.0), ready_at_s=0.0)
    original = cop._obey

    def no_climb(msg):
        original(msg)
        cop.target_height = 2.0 if cop.target_height is not None else None
    cop._obey = no_climb
    cop.run(12.0)
    assert cop.seq.phase is Phase.GAVE_UP and "takeoff not complete" in cop.seq.state.reason


def test_that_autopilot_choice_follows_only_that_kind():
    seq = OffboardSequencer(OffboardConfig(autopilot="px4"))
    seq.on_heartbeat(0.0, hb())
    assert seq.target is None
    seq = OffboardSequencer(OffboardConfig(autopilot="ardupilot"))
    seq.on_heartbeat(0.0, hb())
    assert seq.target == (1, 1) and seq.kind is ARDUPILOT and seq.phase is Phase.WAIT_READY


@pytest.mark.parametrize("kwargs", [{"autopilot": "apm"}, {"hand_back_mode": "land"}, {"brake_hand_back_s": -1.0},
                                    {"brake_hand_back_s": math.nan}])
def test_that_bad_ardupilot_settings_are_refused(kwargs):
    with pytest.raises(ConfigError):
        OffboardConfig(**kwargs)
