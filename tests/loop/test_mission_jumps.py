"""DO_JUMP in a mission: patrols (a jump back, N times or for ever), file numbering, bad jumps refused.

The navigation is driven with positions directly (pure: no link, no flight); one lockstep
flight in mavsim flies two laps of a square and ends at its final item.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import ConfigError
from companion.loop.config import MissionConfig
from companion.loop.mission_file import parse_plan, parse_wpl
from companion.loop.mission_goal import REACHED_KEPT, MissionGoal
from companion.loop.vehicle_reference import VehicleReference
from companion.mavlink.messages import HomePosition
from companion.mavlink.traffic import GlobalOrigin
from tests.support.missions import MAVSIM_ORIGIN, plan_dict

ROOT = Path(__file__).resolve().parents[2]
SQUARE = [(8.0, 0.0, -5.0), (8.0, 8.0, -5.0), (0.0, 8.0, -5.0), (0.0, 0.0, -5.0)]


def _jump(target_jump_id: int, repeat: float) -> dict:
    return {"type": "SimpleItem", "command": mavlink2.MAV_CMD_DO_JUMP, "frame": 2, "autoContinue": True,
            "params": [target_jump_id, repeat, 0, 0, 0, 0, 0]}


def _reference() -> VehicleReference:
    """mavsim's origin and home (the same point)."""
    ref = VehicleReference()
    o = MAVSIM_ORIGIN
    ref.on_origin(GlobalOrigin(o.lat_deg, o.lon_deg, o.alt_m))
    ref.on_home(HomePosition((1, 1), o.alt_m, 0.0, o.lat_deg, o.lon_deg, (0.0, 0.0, 0.0)))
    return ref


def _placed(plan: dict) -> MissionGoal:
    """The mission of ``plan`` placed about mavsim's origin (as a flight places it)."""
    parsed = parse_plan(json.dumps(plan), "patrol.plan")
    ref = _reference()
    goal = MissionGoal(MissionConfig(None, 0.3, plan_file="patrol.plan"), ref, parsed, upload=False)
    assert goal.prepare(0.0, (1, 1)).ready
    return goal


def _visit(goal: MissionGoal, max_visits: int) -> list[int]:
    """Put the drone on each waypoint it is sent to in turn; the item seqs announced as reached."""
    goal.start(np.zeros(3))
    for _ in range(max_visits):
        position = goal.goal.copy()
        goal.target(position)
        if goal.reached(position):
            break
    goal.take_outbound(1.0, engaged=True, held=False)
    return [seq for _, seq in goal.reached_items]


def test_that_a_jump_back_flies_the_loop_again_as_many_times_as_it_says_then_goes_on():
    # items: takeoff (id 1), four waypoints (ids 2-5), DO_JUMP to id 2 twice (seq 5), RTL (seq 6)
    goal = _placed(plan_dict(SQUARE, extra_items=[_jump(2, 2)]))
    assert goal.items[5].params[0] == 1.0                      # doJumpId 2 is the vehicle's item 1
    assert _visit(goal, 100) == [1, 2, 3, 4] * 3               # the lap, then the two jumps back
    assert goal.finished and goal.summary()["mission_jumps_taken"] == 2
    assert goal.summary()["mission_items_skipped"] == []       # the jump is followed, not skipped
    assert goal.summary()["mission_final"] == "return"


def test_that_a_jump_repeated_for_ever_is_a_patrol_that_never_finishes_in_bounded_memory():
    goal = _placed(plan_dict(SQUARE, final=None, extra_items=[_jump(2, -1)]))
    reached = _visit(goal, 4 * 700)                            # 700 laps
    assert not goal.finished and goal.reached_count == 2800
    assert len(goal.reached_items) == REACHED_KEPT and reached[-4:] == [1, 2, 3, 4]
    assert goal.summary()["mission_items_reached_count"] == 2800


def test_that_the_autopilots_current_item_follows_the_jump():
    goal = _placed(plan_dict(SQUARE, extra_items=[_jump(3, 1)]))    # back to the second waypoint, once
    goal.start(np.zeros(3))
    currents = []
    for _ in range(20):
        position = goal.goal.copy()
        goal.target(position)
        done = goal.reached(position)
        out, _ = goal.take_outbound(1.0, engaged=True, held=False)
        currents += [m.seq for m in out if m.get_type() == "MISSION_SET_CURRENT"]
        if done:
            break
    # first waypoint current at engagement, then after each: 2, 3, 4, (jump) 2, 3, 4, then the RTL (seq 6)
    assert currents == [1, 2, 3, 4, 2, 3, 4, 6]


def test_that_a_jump_before_the_first_waypoint_makes_its_target_the_first_current_item():
    """A DO_JUMP between the takeoff and the first waypoint (once, to the third): the first
    waypoint flown is the jump's target, and that is the item made current at engagement."""
    plan = plan_dict(SQUARE)
    items = plan["mission"]["items"]
    items.insert(1, {**_jump(4, 1), "doJumpId": 7})               # to doJumpId 4: the third waypoint
    goal = _placed(plan)
    assert goal.items[1].command == mavlink2.MAV_CMD_DO_JUMP and goal.items[1].params[0] == 4.0
    goal.start(np.zeros(3))
    first_goal = goal.goal.copy()
    out, _ = goal.take_outbound(1.0, engaged=True, held=False)
    assert [m.seq for m in out if m.get_type() == "MISSION_SET_CURRENT"] == [4]   # the third waypoint's seq
    assert np.allclose(first_goal, goal.waypoints[2].position)


def test_that_waypoints_all_within_each_others_acceptance_do_not_spin_the_loop():
    goal = _placed(plan_dict([(1.0, 0.0, -5.0), (1.2, 0.0, -5.0)], final=None, extra_items=[_jump(2, -1)]))
    goal.start(np.zeros(3))
    goal.target(np.array([1.1, 0.0, -5.0]))                   # both within 1 m: one pass over them, no more
    assert goal.reached_count + len(goal._newly_reached) <= 2


def test_that_wpl_jumps_count_home_as_item_zero():
    text = "QGC WPL 110\n" + "\n".join("\t".join(str(v) for v in row) for row in [
        (0, 1, 0, 16, 0, 0, 0, 0, 47.397742, 8.545594, 488.0, 1),
        (1, 0, 3, 16, 0, 1, 0, 0, 47.39780, 8.54560, 5.0, 1),
        (2, 0, 3, 16, 0, 1, 0, 0, 47.39790, 8.54560, 5.0, 1),
        (3, 0, 2, 177, 1, -1, 0, 0, 0, 0, 0, 1),
    ])
    plan = parse_wpl(text, "patrol.waypoints")
    assert plan.items[2].command == mavlink2.MAV_CMD_DO_JUMP and plan.items[2].params[:2] == (0.0, -1.0)


@pytest.mark.parametrize("jump, message", [
    (_jump(99, 1), "patrol.plan: mission item 6 (MAV_CMD 177): DO_JUMP to item 99: no item has that number"),
    (_jump(2, 1.5), "patrol.plan: mission item 6 (MAV_CMD 177): DO_JUMP repeat 1.5: a whole number of times, or -1 for ever"),
    (_jump(2, -3), "patrol.plan: mission item 6 (MAV_CMD 177): DO_JUMP repeat -3: a whole number of times, or -1 for ever"),
    (_jump(6, 1), "patrol.plan: mission item 6 (MAV_CMD 177): DO_JUMP to itself"),
])
def test_that_a_bad_jump_is_one_error_naming_the_file_and_item(jump, message):
    with pytest.raises(ConfigError) as err:
        parse_plan(json.dumps(plan_dict(SQUARE, final=None, extra_items=[{**jump, "doJumpId": 6}])), "patrol.plan")
    assert str(err.value) == message


def test_that_a_jump_past_the_last_waypoint_is_refused_when_placed():
    goal_plan = plan_dict(SQUARE, extra_items=[_jump(7, 1)])    # to the RTL: no waypoint after it
    parsed = parse_plan(json.dumps(goal_plan), "p.plan")
    ref = _reference()
    prep = MissionGoal(MissionConfig(None, 0.3, plan_file="p.plan"), ref, parsed, upload=False).prepare(0.0, (1, 1))
    assert not prep.ready and prep.failed == "mission item 5: DO_JUMP to item 6, after which there is no waypoint"


def test_that_two_laps_are_flown_in_mavsim_and_the_mission_ends_as_it_says(tmp_path):
    from companion.offline.harness import run_lockstep
    plan = tmp_path / "laps.plan"
    plan.write_text(json.dumps(plan_dict(SQUARE, extra_items=[_jump(2, 1)])))
    data = tomllib.loads((ROOT / "configs" / "antipodal.toml").read_text())
    data.pop("world", None)
    data["scenario"]["duration_s"] = 90.0
    data["mission"] = {"goal_tolerance_m": 0.3, "plan_file": str(plan), "plan_upload": False}
    run = run_lockstep(data, seed=0, stop_after_goal_s=None, tlog_path=None)
    summary = run.companion.goal.summary()
    assert summary["mission_items_reached"] == [1, 2, 3, 4, 1, 2, 3, 4]
    assert summary["mission_jumps_taken"] == 1
    assert run.companion.state.goal_reached_t_s is not None
    positions = np.array([r.drone_position for r in run.companion.records])
    corner = np.array(SQUARE[1])
    # the corner (8, 8) is passed twice, within its 1 m acceptance, on separate laps
    near = np.flatnonzero(np.linalg.norm(positions - corner, axis=1) < 1.0)
    assert near.size and (np.diff(near) > 10).sum() >= 1


def test_that_the_route_the_autopilot_flies_from_an_item_follows_a_jump_once():
    """What a watching companion predicts the autopilot flies (``MissionGoal.route_from``): from the
    current item on, through a jump back once (the next lap), ending where the mission ends."""
    patrol = _placed(plan_dict(SQUARE, final=None, extra_items=[_jump(2, -1)]))
    np.testing.assert_allclose(patrol.route_from(3), [SQUARE[2], SQUARE[3], *SQUARE], atol=1e-6)
    assert len(patrol.route_from(0)) == 8                     # a takeoff current: the first lap and the next
    once = _placed(plan_dict(SQUARE))
    np.testing.assert_allclose(once.route_from(2), SQUARE[1:], atol=1e-6)
    assert once.route_from(5).shape == (0, 3)                 # the return: past the last waypoint
    _visit(once, 100)
    assert once.route_from(1).shape == (4, 3)                 # flying it does not change the route
