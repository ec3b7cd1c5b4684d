"""``takeover = "guard"`` in mavsim lockstep: the autopilot flies its mission through the antipodal
encounter; the companion takes over on the predicted conflict, flies round it and gives back."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.autopilots import px4
from companion.mavlink.offboard import Phase
from tests.loop.test_mission_watch import fly_mission

OFFBOARD_MAIN = 6


@pytest.fixture(scope="module")
def guarded(tmp_path_factory):
    """The mission straight through the encounter (24 m north at 1.5 m/s, landing there), guarded."""
    return fly_mission(tmp_path_factory.mktemp("g"), [(24.0, 0.0, -5.0)], duration_s=40.0, final=21, takeover="guard")


def test_that_the_guard_takes_over_once_flies_clear_and_gives_back(guarded):
    run, to_vehicle = guarded
    c = run.companion
    assert not run.truth["collided"]
    (taken,) = c.guard.summary()["takeovers"]
    # decided on the predicted conflict, seconds before the encounter (the watch alone collides at 8.0 s)
    assert taken["start_s"] < 3.0 and taken["item"] == 2
    # OFFBOARD requested in the decision's tick; the HEARTBEAT showing it within one HEARTBEAT period
    # (mavsim sends it at 1 Hz, as PX4 does)
    first_request = min(t for t, m in to_vehicle if m.get_type() == "COMMAND_LONG" and m.command == 176)
    assert first_request == pytest.approx(taken["start_s"])
    assert 0.0 < taken["decision_to_offboard_s"] <= 1.0 + 1e-6
    assert taken["end_s"] is not None and taken["end_s"] < 12.0
    # the promise held while the companion flew: every replan's realised contour at least c_min
    assert c.state.min_realised_contour >= c.planner_config.c_min
    # the mode requests: OFFBOARD once, then the mission mode once, and its current item made the waypoint first
    modes = [(t, m.param2, m.param3) for t, m in to_vehicle if m.get_type() == "COMMAND_LONG" and m.command == 176]
    assert [(p2, p3) for _, p2, p3 in modes] == [(OFFBOARD_MAIN, 0), (px4.MainMode.AUTO, px4.AutoSubMode.MISSION)]
    current = [(t, m.seq) for t, m in to_vehicle if m.get_type() == "MISSION_SET_CURRENT"]
    assert [seq for _, seq in current] == [2] and current[0][0] <= modes[1][0]


def test_that_the_mission_is_flown_to_its_end_after_the_hand_back(guarded):
    run, _ = guarded
    c = run.companion
    assert c.progress.summary()["autopilot_items_reached"] == [1, 2, 3]
    assert c.sequencer.phase is Phase.WATCH_ENDED
    texts = [text for _, text in c.state.events]
    assert "companion: taking over, conflict in" in " ".join(texts)
    assert any(t.startswith("companion: giving back, mission item 2") for t in texts)


def test_that_the_stream_carries_the_vehicles_own_velocity_while_guarding(guarded):
    """Before the takeover the setpoints are the vehicle's estimated velocity: a hover while the
    mission starts (MISSION_START at 1.35 s, once the stream has run ``prestream_s``), then north,
    speeding up to the mission's 1.5 m/s; so OFFBOARD entered before a plan would not stop it dead."""
    run, to_vehicle = guarded
    taken = run.companion.guard.summary()["takeovers"][0]["start_s"]
    stream = [(t, np.array([m.vx, m.vy, m.vz])) for t, m in to_vehicle
              if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED" and t < taken]
    assert stream[0][0] <= 0.4                                          # streamed from START_MISSION on
    started = min(t for t, m in to_vehicle if m.get_type() == "COMMAND_LONG" and m.command == 300)
    assert started - stream[0][0] >= run.companion.sequencer.config.prestream_s - 1e-9
    assert all(np.linalg.norm(v) < 0.3 for t, v in stream if t < 1.35)
    leg = [v for t, v in stream if t >= 1.6]
    assert len(leg) >= 10 and all(v[0] > 0.5 and abs(v[1]) < 0.3 for v in leg) and leg[-1][0] > 1.2


def test_that_a_clear_mission_is_never_taken_over(tmp_path):
    run, to_vehicle = fly_mission(tmp_path, [(0.0, -20.0, -5.0)], duration_s=20.0, takeover="guard")
    assert run.companion.guard.summary()["takeovers_count"] == 0
    assert run.companion.watch.summary()["watch_evaluations"] > 30
    assert not [m for _, m in to_vehicle if m.get_type() == "COMMAND_LONG" and m.command == mavlink2.MAV_CMD_DO_SET_MODE]


def test_that_a_mission_ending_at_its_last_waypoint_is_guarded_to_its_end(tmp_path):
    """No landing nor return after the waypoint: taken over, given back, and the autopilot holds
    at the end of its mission (AUTO.MISSION, complete)."""
    run, _ = fly_mission(tmp_path, [(24.0, 0.0, -5.0)], duration_s=40.0, final=None, takeover="guard")
    c = run.companion
    (taken,) = c.guard.summary()["takeovers"]
    assert taken["end_s"] is not None and not run.truth["collided"]
    assert c.sequencer.phase is Phase.GUARDING and run.truth["final_mode"] == "AUTO.MISSION"
    assert c.progress.mission_state == 5                       # MISSION_STATE_COMPLETE


def test_that_a_vehicle_taken_over_past_the_last_waypoint_is_given_back_with_it_current():
    """Taken over on the last leg and flown to the last waypoint (nothing after it), the companion
    gives the vehicle back with that waypoint current (reached: the mission ends, the autopilot
    holds) rather than holding it in OFFBOARD for ever."""
    from types import SimpleNamespace

    from companion.loop.mission_guard import MissionGuard
    from companion.loop.mission_goal import Waypoint

    asked = []
    sequencer = SimpleNamespace(target=(1, 1), phase=Phase.ENGAGED,
                                resume_mission=lambda t, why: asked.append((t, why)) or True)
    goal = SimpleNamespace(current_seq=None, waypoints=[Waypoint(2, np.array([24.0, 0.0, -5.0]), 1.0)])
    supervisor = SimpleNamespace(say=lambda t, sev, text: text)
    guard = MissionGuard(SimpleNamespace(), sequencer, goal, SimpleNamespace(), supervisor)
    sent = guard._give_back(12.0)
    assert asked == [(12.0, "mission path clear")]
    assert sent[0].get_type() == "MISSION_SET_CURRENT" and sent[0].seq == 2
    assert sent[1] == "companion: giving back, mission item 2"
