"""How a live run ends (companion/realtime/run_end.py): a stop hands the vehicle back before the stream stops."""

from types import SimpleNamespace

import pytest

from companion.loop.records import CompanionState
from companion.realtime.run_end import Outcome, RunEnd, RunEndConfig
from companion.mavlink.autopilots import px4
from companion.mavlink.offboard import OffboardConfig, Phase
from tests.mavlink.test_offboard import Script


def _engaged(**config):
    s = Script(OffboardConfig(**config), mode=px4.OFFBOARD)
    assert s.run(0.5).phase is Phase.ENGAGED
    return s, _companion(s.seq)


def _companion(seq):
    """What RunEnd uses of a Companion: its sequencer, its state, and the outside hand-back."""
    return SimpleNamespace(sequencer=seq, state=CompanionState(), hand_back=seq.hand_back)


def _until_end(s, companion, end, limit_s=30.0, vehicle=None):
    """Tick the script at 20 Hz, checking ``end`` after each tick as the stream does; the link time it ended."""
    for _ in range(int(limit_s / 0.05)):
        s.run(0.05, vehicle)
        if end(companion, s.t):
            return s.t
    raise AssertionError("the run did not end")


def _holds(s, msg):
    if msg.command == 176 and msg.param2 == 4 and msg.param3 == 3:  # PX4 AUTO.LOITER
        s.mode = px4.AUTO_LOITER


def test_that_a_signal_while_engaged_hands_back_and_ends_once_the_heartbeat_shows_hold():
    s, companion = _engaged()
    end = RunEnd()
    end.request_stop("SIGINT")
    t_end = _until_end(s, companion, end, vehicle=_holds)
    assert s.seq.phase is Phase.HELD and end.handed_back
    assert t_end == pytest.approx(1.05)  # the tick after the next 1 Hz HEARTBEAT (t = 1 s), which shows Hold
    assert end.outcome(companion) is Outcome.STOPPED and Outcome.STOPPED.code == 3


def test_that_the_stream_goes_on_while_the_hand_back_waits():
    s, companion = _engaged()
    end = RunEnd(RunEndConfig(hand_back_timeout_s=5.0))
    end.request_stop("SIGTERM")
    assert not end(companion, s.t)
    assert s.seq.state.streaming and s.seq.phase is Phase.HANDING_BACK


def test_that_a_vehicle_that_never_shows_hold_ends_the_run_after_the_timeout_unconfirmed():
    s, companion = _engaged(max_retries=100)
    end = RunEnd(RunEndConfig(hand_back_timeout_s=2.0))
    end.request_stop("SIGINT")
    t_end = _until_end(s, companion, end)  # the vehicle ignores the Hold requests
    assert t_end - end.stop_requested_s == pytest.approx(2.0, abs=0.06)
    assert end.outcome(companion) is Outcome.STOPPED_NOT_HELD and Outcome.STOPPED_NOT_HELD.code == 4


def test_that_a_second_signal_ends_the_run_at_once():
    s, companion = _engaged()
    end = RunEnd()
    end.request_stop("SIGINT")
    assert not end(companion, s.t)
    end.request_stop("SIGINT")
    assert end(companion, s.t) and end.forced
    assert end.outcome(companion) is Outcome.STOPPED_NOT_HELD


def test_that_a_stop_before_anything_streams_ends_at_once():
    s = Script(OffboardConfig(), armed=False)
    s.run(2.0)
    companion = _companion(s.seq)
    end = RunEnd()
    end.request_stop("SIGTERM")
    assert end(companion, s.t) and not end.handed_back and s.sent == []
    assert end.outcome(companion) is Outcome.STOPPED


def test_that_the_duration_is_a_stop_request_that_hands_back_too():
    s, companion = _engaged()
    end = RunEnd(RunEndConfig(duration_s=3.0))
    t_first = s.t + 0.05
    _until_end(s, companion, end, vehicle=_holds)
    assert end.stop_reason == "duration" and end.stop_requested_s == pytest.approx(t_first + 3.0, abs=1e-6)
    assert s.seq.phase is Phase.HELD and end.outcome(companion) is Outcome.STOPPED


def test_that_after_the_pilot_takes_over_the_run_lingers_then_ends():
    s, companion = _engaged()
    end = RunEnd(RunEndConfig(linger_s=2.0))
    s.mode = px4.POSCTL
    s.run(1.0)
    assert s.seq.phase is Phase.PILOT_TOOK_OVER
    t_seen = s.t + 0.05
    t_end = _until_end(s, companion, end)
    assert t_end - t_seen == pytest.approx(2.0, abs=1e-6)
    assert end.outcome(companion) is Outcome.PILOT_TOOK_OVER and Outcome.PILOT_TOOK_OVER.code == 5


def test_that_the_goal_held_after_exit_after_goal_is_a_success():
    s, companion = _engaged(hold_after_goal_s=0.0)
    companion.state.goal_reached_t_s = s.t
    s.seq.on_goal_reached(s.t)
    s.seq.on_at_goal(s.t, True)
    _until_end(s, companion, RunEnd(), vehicle=_holds)
    assert RunEnd().outcome(companion) is Outcome.GOAL_REACHED and Outcome.GOAL_REACHED.code == 0


def test_that_a_lost_link_or_no_autopilot_at_all_is_its_own_outcome():
    s, companion = _engaged()
    s.heartbeats = False
    s.run(4.0)
    assert s.seq.phase is Phase.LINK_LOST and RunEnd().outcome(companion) is Outcome.LINK_LOST
    silent = Script(OffboardConfig())
    silent.heartbeats = False
    silent.run(1.0)
    assert RunEnd().outcome(_companion(silent.seq)).code == 6


@pytest.mark.parametrize("kwargs", [{"duration_s": 0.0}, {"duration_s": float("inf")}, {"hand_back_timeout_s": -1.0},
                                    {"linger_s": float("nan")}])
def test_that_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        RunEndConfig(**kwargs)
