"""OffboardSequencer driven by scripted heartbeats, ACKs and STATUSTEXT, as PX4 behaves."""


import pytest

from companion.mavlink import autopilots
from companion.mavlink.autopilots import ModeRole, px4
from companion.errors import ConfigError
from companion.mavlink.messages import CommandAck, VehicleHeartbeat
from companion.mavlink.offboard import Notify, OffboardConfig, OffboardSequencer, Phase, SendCommand

BASE = {px4.OFFBOARD: 145, px4.POSCTL: 209, px4.AUTO_LOITER: 157, px4.AUTO_TAKEOFF: 157, px4.AUTO_RTL: 157}


def hb(custom_mode=px4.POSCTL, armed=True, key=(1, 1), autopilot=12):
    base = BASE.get(custom_mode, 1) if armed else BASE.get(custom_mode, 129) & ~128
    return VehicleHeartbeat(sysid=key[0], compid=key[1], autopilot=autopilot, type=2, base_mode=base,
                            custom_mode=custom_mode, system_status=4 if armed else 3, armed=armed,
                            mode=px4.mode_name(custom_mode) if autopilot == 12 else "",
                            is_autopilot=autopilots.of_heartbeat(*key, autopilot, 2) is not None,
                            role=px4.PX4.mode_role(custom_mode) if autopilot == 12 else ModeRole.OTHER,
                            kind=autopilots.by_mav_autopilot(autopilot))


def ack(command, result, key=(1, 1)):
    return CommandAck(key=key, command=command, result=result, target_system=1, target_component=191)


def commands(actions):
    return [a.msg for a in actions if isinstance(a, SendCommand)]


def events(actions):
    return [a.event for a in actions if isinstance(a, Notify)]


class Script:
    """Runs the sequencer at 20 Hz with 1 Hz heartbeats from a scripted vehicle mode."""

    def __init__(self, config, mode=px4.POSCTL, armed=True):
        self.seq = OffboardSequencer(config)
        self.mode, self.armed, self.t = mode, armed, 0.0
        self.sent = []
        self.heartbeats = True

    def run(self, duration_s, on_command=None):
        end = self.t + duration_s
        while self.t < end - 1e-9:
            if self.heartbeats and abs(self.t - round(self.t)) < 1e-6:
                self.seq.on_heartbeat(self.t, hb(self.mode, self.armed))
            for msg in commands(self.seq.step(self.t)):
                self.sent.append((self.t, msg))
                if on_command:
                    on_command(self, msg)
            self.t = round(self.t + 0.05, 6)
        return self.seq.state


def test_that_a_cooperative_vehicle_is_engaged_after_prestream_and_heartbeat_confirmation():
    def vehicle(s, msg):
        if msg.command == 176 and msg.param2 == 6:
            s.seq.on_ack(s.t, ack(176, 0))
            s.mode = px4.OFFBOARD

    s = Script(OffboardConfig())
    state = s.run(0.5)
    assert state.phase is Phase.PRESTREAM and state.streaming and not state.engaged
    state = s.run(3.0, vehicle)
    assert state.phase is Phase.ENGAGED and state.engaged and state.streaming
    (t_req, req), = s.sent
    assert t_req == pytest.approx(1.0)
    assert (req.command, req.param1, req.param2, req.param3, req.target_system) == (176, 129.0, 6.0, 0.0, 1)


def test_that_ack_zero_without_mode_change_is_not_engagement_and_is_retried_then_given_up():
    def px4_without_stream(s, msg):  # real PX4: ACK 0, mode unchanged, STATUSTEXT
        s.seq.on_ack(s.t, ack(msg.command, 0))
        s.seq.on_statustext(s.t, "Switching to Offboard is currently not available")

    cfg = OffboardConfig(max_retries=3)
    s = Script(cfg)
    state = s.run(3.0, px4_without_stream)
    assert state.phase is Phase.REQUEST_OFFBOARD and not state.engaged
    state = s.run(5.0, px4_without_stream)
    assert state.phase is Phase.GAVE_UP and not state.streaming
    assert [m.command for _, m in s.sent] == [176] * 4
    assert [m.confirmation for _, m in s.sent] == [0, 1, 2, 3]
    texts = [e.text for e in s.seq.events]
    assert any("currently not available" in t for t in texts)
    assert "no confirmation after 4 attempts" in texts[-1]


def test_that_duplicated_acks_are_counted_once():
    def double_ack(s, msg):
        s.seq.on_ack(s.t, ack(176, 0))
        s.seq.on_ack(s.t, ack(176, 0))

    s = Script(OffboardConfig())
    s.run(1.5, double_ack)
    acked = [e for e in s.seq.events if "acknowledged" in e.text]
    assert len(acked) == 1


def test_that_ack_temporarily_rejected_is_retried_and_a_later_mode_change_engages():
    def older_px4(s, msg):
        if msg.confirmation == 0:
            s.seq.on_ack(s.t, ack(176, 1))
        else:
            s.mode = px4.OFFBOARD

    s = Script(OffboardConfig())
    state = s.run(4.0, older_px4)
    assert state.phase is Phase.ENGAGED
    assert len(s.sent) == 2
    assert any("refused (MAV_RESULT_TEMPORARILY_REJECTED)" in e.text for e in s.seq.events)


def test_that_unsupported_command_gives_up_at_once():
    s = Script(OffboardConfig())
    s.run(1.5, lambda s, m: s.seq.on_ack(s.t, ack(176, 3)))
    assert s.seq.phase is Phase.GAVE_UP


def test_that_acks_from_other_systems_or_for_other_commands_are_ignored():
    s = Script(OffboardConfig())
    s.run(1.5, lambda s, m: (s.seq.on_ack(s.t, ack(176, 3, key=(101, 0))), s.seq.on_ack(s.t, ack(400, 3))))
    assert s.seq.phase is Phase.REQUEST_OFFBOARD


def test_that_pilot_takeover_stops_streaming_and_is_not_fought():
    s = Script(OffboardConfig(), mode=px4.OFFBOARD)
    assert s.run(0.1).phase is Phase.ENGAGED
    s.mode = px4.POSCTL
    state = s.run(5.0)
    assert state.phase is Phase.PILOT_TOOK_OVER and not state.streaming and not state.engaged
    assert s.sent == []
    (ev,) = [e for e in s.seq.events if e.phase is Phase.PILOT_TOOK_OVER]
    assert "left OFFBOARD for POSCTL" in ev.text and ev.severity == 4


def test_that_reengage_requests_offboard_again_after_the_vehicle_falls_back_to_hold():
    s = Script(OffboardConfig(reengage=True), mode=px4.OFFBOARD)
    s.run(0.1)
    s.mode = px4.AUTO_LOITER
    state = s.run(1.0)
    assert state.phase is Phase.PRESTREAM and state.streaming
    s.run(2.0, lambda s, m: setattr(s, "mode", px4.OFFBOARD))
    assert s.seq.phase is Phase.ENGAGED and len(s.sent) == 1


def test_that_reengage_never_takes_back_a_vehicle_the_autopilot_has_put_down():
    """A failsafe's landing has ended (EXTENDED_SYS_STATE on the ground): OFFBOARD now would fly the
    vehicle off again, so re-engaging stops there, and no request goes out after it."""
    s = Script(OffboardConfig(reengage=True), mode=px4.OFFBOARD)
    s.run(0.1)
    s.mode = px4.AUTO_LOITER
    assert s.run(1.0).phase is Phase.PRESTREAM           # the next HEARTBEAT shows it left
    s.seq.on_landed_state(s.t, on_ground=False)           # in the air: re-engaging goes on
    assert s.seq.phase is Phase.PRESTREAM
    s.seq.on_landed_state(s.t, on_ground=True)
    state = s.run(3.0)
    assert state.phase is Phase.PILOT_TOOK_OVER and not state.streaming and s.sent == []
    assert any("on the ground" in e.text and "not re-engaging" in e.text for e in s.seq.events), s.seq.events
    # before any engagement (a pilot arming on the ground for the companion to take off) the state is no bar
    s = Script(OffboardConfig(reengage=True), mode=px4.POSCTL)
    s.seq.on_landed_state(0.0, on_ground=True)
    assert s.run(0.5).phase is Phase.PRESTREAM


def test_that_heartbeat_loss_stops_commanding_and_recovery_resumes_only_in_offboard():
    s = Script(OffboardConfig(), mode=px4.OFFBOARD)
    s.run(0.1)
    s.heartbeats = False
    state = s.run(3.5)
    assert state.phase is Phase.LINK_LOST and not state.streaming
    s.heartbeats = True
    assert s.run(1.0).phase is Phase.ENGAGED  # PX4 still in OFFBOARD: never left our control

    s.heartbeats = False
    s.run(4.0)
    s.heartbeats, s.mode = True, px4.AUTO_RTL  # PX4's setpoint-loss failsafe fired meanwhile
    state = s.run(3.0)
    assert state.phase is Phase.PILOT_TOOK_OVER and s.sent == []


def test_that_heartbeat_loss_before_engagement_resumes_the_sequence():
    s = Script(OffboardConfig(), mode=px4.POSCTL)
    s.run(0.5)
    s.heartbeats = False
    s.run(4.0)
    assert s.seq.phase is Phase.LINK_LOST
    s.heartbeats = True
    s.run(0.6)  # next heartbeat at t = 5 s
    assert s.seq.phase is Phase.PRESTREAM


def test_that_without_arm_the_sequencer_waits_for_the_pilot_to_arm():
    s = Script(OffboardConfig(), armed=False)
    state = s.run(10.0)
    assert state.phase is Phase.WAIT_ARMED and not state.streaming and s.sent == []
    s.armed = True
    assert s.run(0.5).phase is Phase.PRESTREAM


def test_that_arming_is_retried_while_denied_after_boot_then_confirmed_from_heartbeat():
    def vehicle(s, msg):
        if msg.command == 400:
            if s.t < 4.0:  # "Arming denied: Resolve system health failures first"
                s.seq.on_ack(s.t, ack(400, 1))
                s.seq.on_statustext(s.t, "Arming denied: Resolve system health failures first")
            else:
                s.seq.on_ack(s.t, ack(400, 0))
                s.armed = True
        elif msg.command == 176:
            s.mode = px4.OFFBOARD

    s = Script(OffboardConfig(arm=True), armed=False)
    state = s.run(8.0, vehicle)
    assert state.phase is Phase.ENGAGED
    cmds = [m.command for _, m in s.sent]
    assert cmds == [400, 400, 400, 400, 176]
    assert all(m.param1 == 1.0 for _, m in s.sent[:4])


def test_that_arming_gives_up_after_max_retries():
    s = Script(OffboardConfig(arm=True, max_retries=2), armed=False)
    state = s.run(6.0, lambda s, m: s.seq.on_ack(s.t, ack(400, 1)))
    assert state.phase is Phase.GAVE_UP and len(s.sent) == 3


def test_that_arming_waits_to_hear_whether_another_autopilot_is_on_the_link():
    s = Script(OffboardConfig(arm=True), armed=False)
    s.run(1.4)
    assert s.seq.phase is Phase.WAIT_AUTOPILOT and s.sent == []  # listening (autopilot_listen_s 1.5)
    s.run(0.2)
    assert s.seq.phase is Phase.ARMING and [m.command for _, m in s.sent] == [400]


def test_that_arm_is_refused_when_several_autopilots_are_heard_and_none_is_named():
    s = Script(OffboardConfig(arm=True), armed=False)
    s.run(0.5)
    s.seq.on_heartbeat(s.t, hb(px4.POSCTL, armed=False, key=(2, 1)))
    state = s.run(2.0)
    assert state.phase is Phase.GAVE_UP and s.sent == []
    assert "systems 1, 2" in state.reason and "--target-system" in state.reason


def test_that_a_named_target_system_is_the_only_one_followed_and_commanded():
    s = Script(OffboardConfig(arm=True, target_system=2), armed=False)
    s.run(3.0)  # system 1's heartbeats only: ignored
    assert s.seq.phase is Phase.WAIT_AUTOPILOT and s.seq.target is None and s.sent == []
    s.seq.on_heartbeat(s.t, hb(px4.POSCTL, armed=False, key=(2, 1)))
    s.run(0.1)
    assert s.seq.target == (2, 1) and s.seq.phase is Phase.ARMING  # named: no listening
    assert [(m.command, m.target_system) for _, m in s.sent] == [(400, 2)]


def test_that_without_arm_the_first_autopilot_is_followed_as_before():
    s = Script(OffboardConfig(), mode=px4.OFFBOARD)
    s.run(0.1)
    s.seq.on_heartbeat(s.t, hb(px4.POSCTL, key=(2, 1)))
    assert s.run(0.5).phase is Phase.ENGAGED and s.seq.target == (1, 1)


def test_that_a_vehicle_found_armed_and_holding_is_not_asked_to_take_off_again():
    s = Script(OffboardConfig(arm=True, takeoff_alt_m=5.0), mode=px4.AUTO_LOITER, armed=True)
    state = s.run(0.5)
    assert state.phase is Phase.PRESTREAM and "already flying, no takeoff" in state.reason
    assert [m.command for _, m in s.sent] == []          # no arm, no takeoff, no HOME_POSITION request


def test_that_a_vehicle_found_armed_in_a_failsafe_is_taken_back_from_a_hover_without_a_takeoff():
    """A restart with ``--arm --takeoff-alt --reengage`` finds PX4 in its offboard-loss RTL
    (armed, airborne, CRITICAL): no takeoff command (PX4 SITL answered one by ending its RTL
    and the old sequencer then waited 30 s for a takeoff that never came), straight to the
    prestream and OFFBOARD."""
    from dataclasses import replace

    seq = OffboardSequencer(OffboardConfig(arm=True, takeoff_alt_m=5.0, reengage=True))
    seq.on_heartbeat(0.0, replace(hb(px4.AUTO_RTL), system_status=5))
    actions = seq.step(0.0)
    assert seq.phase is Phase.PRESTREAM and seq.state.streaming
    assert "armed in a failsafe: already flying, no takeoff" in seq.state.reason
    assert commands(actions) == []                    # no arm, no takeoff, no HOME_POSITION request


def test_that_takeoff_waits_for_auto_loiter_before_prestreaming():
    def vehicle(s, msg):
        if msg.command == 400:
            s.armed = True
        elif msg.command == 22:
            s.seq.on_ack(s.t, ack(22, 0))
            s.mode = px4.AUTO_TAKEOFF

    cfg = OffboardConfig(arm=True, takeoff_alt_m=5.0)
    s = Script(cfg, armed=False)
    s.seq.on_home_altitude(488.0)
    state = s.run(4.0, vehicle)
    assert state.phase is Phase.TAKEOFF and not state.streaming
    (_, to), = [(t, m) for t, m in s.sent if m.command == 22]
    assert to.param7 == pytest.approx(493.0)
    s.mode = px4.AUTO_LOITER
    assert s.run(0.5, vehicle).phase is Phase.PRESTREAM


def test_that_after_the_takeoff_the_vehicle_is_left_in_hold_to_settle_before_streaming():
    def vehicle(s, msg):
        if msg.command == 22:
            s.seq.on_ack(s.t, ack(22, 0))
            s.mode = px4.AUTO_TAKEOFF

    s = Script(OffboardConfig(takeoff_alt_m=5.0, takeoff_settle_s=3.0), armed=True)
    s.seq.on_home_altitude(488.0)
    s.run(2.0, vehicle)
    s.mode = px4.AUTO_LOITER
    state = s.run(2.9, vehicle)   # Hold seen at once (t = 2 s), then 3 s of settling
    assert state.phase is Phase.TAKEOFF and not state.streaming
    state = s.run(0.2, vehicle)
    assert state.phase is Phase.PRESTREAM and state.streaming
    assert "settled 3.0 s" in state.reason


def test_that_takeoff_waits_for_home_position_and_requests_it_until_it_comes():
    s = Script(OffboardConfig(takeoff_alt_m=5.0, retry_period_s=1.0), armed=True)
    s.run(3.0)
    assert s.seq.phase is Phase.TAKEOFF
    requests = [m for _, m in s.sent]
    assert [m.command for m in requests] == [512, 512, 512] and all(m.param1 == 242 for m in requests)
    s.seq.on_home_altitude(488.0)
    s.run(0.1)
    (to,) = [m for _, m in s.sent if m.command == 22]
    assert to.param7 == pytest.approx(493.0)
    assert any("waiting for HOME_POSITION" in e.text for e in s.seq.events)


def test_that_takeoff_gives_up_without_home_position():
    s = Script(OffboardConfig(takeoff_alt_m=2.5, takeoff_timeout_s=5.0), armed=True)
    s.run(6.0)
    assert s.seq.phase is Phase.GAVE_UP
    assert not [m for _, m in s.sent if m.command == 22]
    assert "no HOME_POSITION" in s.seq.state.reason


def test_that_takeoff_times_out():
    s = Script(OffboardConfig(takeoff_alt_m=2.5, takeoff_timeout_s=5.0), armed=True)
    s.seq.on_home_altitude(488.0)
    s.run(8.0, lambda s, m: s.seq.on_ack(s.t, ack(22, 0)))
    assert s.seq.phase is Phase.GAVE_UP and len(s.sent) == 1


def test_that_handing_back_streams_until_the_heartbeat_shows_hold():
    def vehicle(s, msg):
        if msg.command == 176 and msg.param2 == 4 and msg.param3 == 3 and s.t >= 1.5:  # the first request is lost
            s.mode = px4.AUTO_LOITER

    s = Script(OffboardConfig(retry_period_s=1.0), mode=px4.OFFBOARD)
    assert s.run(0.5).phase is Phase.ENGAGED
    s.seq.hand_back(s.t)
    state = s.run(1.5, vehicle)
    assert state.phase is Phase.HANDING_BACK and state.streaming and not state.engaged
    state = s.run(2.0, vehicle)
    assert state.phase is Phase.HELD and not state.streaming
    holds = [m for _, m in s.sent if m.command == 176]
    assert len(holds) == 2 and (holds[0].param1, holds[0].param2, holds[0].param3) == (129.0, 4.0, 3.0)


def test_that_the_goals_hand_back_waits_until_the_vehicle_is_settled_at_the_goal():
    s = Script(OffboardConfig(hold_after_goal_s=1.0), mode=px4.OFFBOARD)
    assert s.run(0.5).phase is Phase.ENGAGED
    s.seq.on_goal_reached(s.t)          # entered the goal's acceptance, still moving: an overshoot follows
    s.seq.on_at_goal(s.t, False)
    assert s.run(3.0).phase is Phase.ENGAGED
    s.seq.on_at_goal(s.t, True)         # back inside, nearly still
    s.run(0.05)
    assert s.seq.phase is Phase.HANDING_BACK
    assert s.seq.events[-1].text.startswith("HANDING_BACK: goal reached; requesting Hold")


def test_that_the_goals_hand_back_waits_no_longer_than_its_bound_and_not_before_the_hold():
    s = Script(OffboardConfig(hold_after_goal_s=1.0), mode=px4.OFFBOARD)
    assert s.run(0.5).phase is Phase.ENGAGED
    t_goal = s.t
    s.seq.on_goal_reached(t_goal)
    s.seq.on_at_goal(t_goal, True)      # settled at once: still held for hold_after_goal_s
    assert s.run(1.0).phase is Phase.ENGAGED   # ticks to 0.95 s after the goal
    s.run(0.05)
    assert s.seq.phase is Phase.HANDING_BACK
    s = Script(OffboardConfig(hold_after_goal_s=1.0, goal_settle_max_s=4.0), mode=px4.OFFBOARD)
    s.run(0.5)
    t_goal = s.t
    s.seq.on_goal_reached(t_goal)
    s.seq.on_at_goal(t_goal, True)
    s.seq.on_at_goal(t_goal + 0.3, False)   # pushed off it (traffic on the goal): never settled again
    assert s.run(1.0 + 4.0).phase is Phase.ENGAGED
    s.run(0.05)
    assert s.seq.phase is Phase.HANDING_BACK
    assert "not settled at it 4 s later" in s.seq.events[-1].text
    s = Script(OffboardConfig(hold_after_goal_s=1.0, goal_settle_max_s=0.0), mode=px4.OFFBOARD)
    s.run(0.5)
    s.seq.on_goal_reached(s.t)          # 0: the rule before the wait, wherever the vehicle is
    s.seq.on_at_goal(s.t, False)
    s.run(1.05)
    assert s.seq.phase is Phase.HANDING_BACK


def test_that_a_link_lost_while_handing_back_ends_held_when_the_vehicle_is_back_in_hold():
    """Found over a 57600-baud line: the Hold request went out, then no HEARTBEAT for 3 s; the vehicle
    came back in AUTO.LOITER, the mode asked for. That is the hand-back done, not PX4's failsafe."""
    s = Script(OffboardConfig(), mode=px4.OFFBOARD)
    assert s.run(0.5).phase is Phase.ENGAGED
    s.seq.hand_back(s.t)
    s.heartbeats = False
    assert s.run(3.5).phase is Phase.LINK_LOST
    s.heartbeats, s.mode = True, px4.AUTO_LOITER
    state = s.run(1.5)
    assert state.phase is Phase.HELD and not state.streaming
    assert "after the hand-back" in state.reason


def test_that_hand_back_does_nothing_before_streaming():
    s = Script(OffboardConfig(), armed=False)
    s.run(0.5)
    s.seq.hand_back(s.t)
    assert s.seq.phase is Phase.WAIT_ARMED and s.sent == []


def test_that_disarm_during_the_request_returns_to_waiting():
    s = Script(OffboardConfig())
    s.run(1.5)
    assert s.seq.phase is Phase.REQUEST_OFFBOARD
    s.armed = False
    assert s.run(1.0).phase is Phase.WAIT_ARMED


def test_that_obstacle_and_companion_heartbeats_do_not_start_the_sequence():
    seq = OffboardSequencer()
    seq.on_heartbeat(0.0, hb(0, armed=False, key=(101, 0), autopilot=8))
    seq.on_heartbeat(0.0, hb(0, armed=False, key=(1, 191), autopilot=8))
    assert seq.step(0.0) == [] and seq.phase is Phase.WAIT_AUTOPILOT and seq.target is None


def test_that_every_transition_is_reported_as_an_event():
    s = Script(OffboardConfig(), mode=px4.OFFBOARD)
    s.run(0.1)
    s.mode = px4.POSCTL
    s.run(1.0)
    phases = [e.phase for e in s.seq.events]
    assert phases == [Phase.PRESTREAM, Phase.ENGAGED, Phase.PILOT_TOOK_OVER]


@pytest.mark.parametrize(
    "kwargs", [{"prestream_s": -1.0}, {"retry_period_s": 0.0}, {"max_retries": -1}, {"takeoff_alt_m": float("nan")},
               {"heartbeat_timeout_s": float("inf")}],
)
def test_that_invalid_config_is_refused(kwargs):
    (key,) = kwargs
    with pytest.raises(ConfigError, match=rf"^{key} = .* must be"):
        OffboardConfig(**kwargs)


# ---------------------------------------------------------------- takeover "watch"

def test_that_watching_with_arm_arms_starts_the_mission_once_and_never_streams():
    def vehicle(s, msg):
        if msg.command == 400:
            s.armed = True
        elif msg.command == 300:     # the first MISSION_START is lost; the retry takes
            if any(m.command == 300 for _, m in s.sent[:-1]):
                s.mode = px4.AUTO_MISSION

    s = Script(OffboardConfig(arm=True, takeover="watch", autopilot_listen_s=0.0), mode=px4.AUTO_LOITER, armed=False)
    state = s.run(6.0, vehicle)
    assert state.phase is Phase.WATCHING and not state.streaming and not state.engaged
    assert [m.command for _, m in s.sent] == [400, 300, 300]
    assert s.seq.vehicle_in_mission
    state = s.run(5.0, vehicle)                       # flying its mission: nothing more is sent
    assert state.phase is Phase.WATCHING and len(s.sent) == 3
    s.armed = False                                   # landed and disarmed at the mission's end
    state = s.run(2.0, vehicle)
    assert state.phase is Phase.WATCH_ENDED and len(s.sent) == 3


def test_that_watching_without_arm_waits_for_the_operator_and_a_link_loss_starts_nothing():
    s = Script(OffboardConfig(takeover="watch"), mode=px4.AUTO_LOITER, armed=False)
    assert s.run(3.0).phase is Phase.WATCHING and s.sent == []
    s.armed, s.mode = True, px4.AUTO_MISSION           # the operator starts the mission
    assert s.run(3.0).phase is Phase.WATCHING and s.seq.vehicle_in_mission
    s.heartbeats = False
    assert s.run(4.0).phase is Phase.LINK_LOST
    s.heartbeats, s.mode = True, px4.AUTO_LOITER        # back, the operator has paused the mission
    assert s.run(2.0).phase is Phase.WATCHING and s.sent == []


def test_that_an_unknown_takeover_is_refused():
    with pytest.raises(ConfigError, match="takeover must be one of always, watch, guard, got 'sometimes'"):
        OffboardConfig(takeover="sometimes")


# ---------------------------------------------------------------- takeover "guard"

def _guarding():
    s = Script(OffboardConfig(takeover="guard"), mode=px4.AUTO_MISSION, armed=True)
    state = s.run(1.5)
    assert state.phase is Phase.GUARDING and state.streaming and not state.engaged and s.sent == []
    return s


def test_that_a_guard_takes_over_and_commands_from_the_request_on():
    s = _guarding()

    def px4_vehicle(sc, msg):
        if msg.command == 176 and msg.param2 == 6:
            sc.mode = px4.OFFBOARD
        elif msg.command == 176 and msg.param2 == 4:
            sc.mode = px4.AUTO_MISSION

    assert s.seq.take_over(s.t, "conflict in 4.0 s")
    assert s.seq.state.engaged and s.seq.phase is Phase.TAKING_OVER      # commanding before the confirmation
    assert s.seq.state.since_s == pytest.approx(1.5)                        # requested
    assert not s.seq.take_over(s.t, "again")                               # one at a time
    state = s.run(1.5, px4_vehicle)
    assert state.phase is Phase.ENGAGED
    assert state.since_s == pytest.approx(2.0)                              # confirmed by the next HEARTBEAT
    assert s.seq.resume_mission(s.t, "mission path clear")
    state = s.run(1.5, px4_vehicle)
    assert state.phase is Phase.GUARDING and not state.engaged and state.streaming
    assert [(m.param2, m.param3) for _, m in s.sent] == [(6.0, 0.0), (4.0, 4.0)]


def test_that_a_takeover_the_autopilot_refuses_goes_back_to_guarding():
    s = _guarding()
    assert s.seq.take_over(s.t, "conflict in 3.0 s")
    state = s.run(8.0)                                   # PX4 stays in AUTO.MISSION whatever is asked
    assert state.phase is Phase.GUARDING and len(s.sent) == 6     # 1 + 5 retries, then back
    assert s.seq.take_over(s.t, "conflict in 1.0 s")   # and may be asked again


def test_that_a_guard_never_takes_over_outside_the_mission_nor_keeps_a_pilots_switch():
    s = _guarding()
    s.mode = px4.AUTO_RTL                                # the operator (or a failsafe) sends it home
    s.run(1.0)
    assert not s.seq.take_over(s.t, "conflict") and s.seq.phase is Phase.GUARDING
    s.mode = px4.AUTO_MISSION
    s.run(1.0)
    assert s.seq.take_over(s.t, "conflict")
    s.mode = px4.OFFBOARD
    s.run(1.0)
    s.mode = px4.POSCTL                                  # a pilot takes the vehicle during the takeover
    assert s.run(1.0).phase is Phase.PILOT_TOOK_OVER


def test_that_a_guard_streams_from_the_missions_start_and_takes_over_only_after_the_prestream():
    """PX4 refuses OFFBOARD ("Switching to Offboard is currently not available") until setpoints have
    streamed a while: a conflict found early waits out ``prestream_s`` from the stream's start."""
    s = Script(OffboardConfig(takeover="guard", arm=True, prestream_s=2.0), mode=px4.AUTO_LOITER, armed=True)
    s.run(0.1)
    assert s.seq.phase is Phase.START_MISSION and s.seq.state.streaming    # streaming before the mission starts
    s.mode = px4.AUTO_MISSION
    s.run(0.95)                                                             # the HEARTBEAT at 1.0 s shows it
    assert s.seq.phase is Phase.GUARDING
    assert not s.seq.take_over(s.t, "conflict") and s.seq.phase is Phase.GUARDING   # 1.05 s of stream
    s.run(1.0)
    assert s.seq.take_over(s.t, "conflict") and s.seq.phase is Phase.TAKING_OVER     # 2.05 s
