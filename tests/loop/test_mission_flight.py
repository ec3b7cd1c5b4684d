"""A mission flown as a goal source in mavsim lockstep: waypoints in order, progress on the autopilot."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.offline.harness import run_lockstep
from tests.support.missions import plan_text

ROOT = Path(__file__).resolve().parents[2]
WPS = [(8.0, 0.0, -5.0), (8.0, 8.0, -6.0), (0.0, 8.0, -5.0), (0.0, 0.0, -5.0)]


def _scenario(plan_path: Path, duration_s: float = 40.0, **mission) -> dict:
    data = tomllib.loads((ROOT / "configs" / "antipodal.toml").read_text())
    data.pop("world", None)
    data["scenario"]["duration_s"] = duration_s
    data["mission"] = {"goal_tolerance_m": 0.3, "plan_file": str(plan_path), **mission}
    return data


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    plan = tmp_path_factory.mktemp("m") / "square.plan"
    plan.write_text(plan_text(WPS, extra_items=[{"type": "SimpleItem", "command": 178, "frame": 2, "autoContinue": True,
                                                 "params": [1, 2.0, -1, 0, 0, 0, 0]}]))
    sent = []
    run = run_lockstep(_scenario(plan, plan_upload=False), seed=0, stop_after_goal_s=None, tlog_path=None,
                       drop=lambda t, d, p: sent.append((t, d, p)) and False)
    return run, sent


def test_that_every_waypoint_is_reached_in_order_and_listed(flown):
    run, _ = flown
    c = run.companion
    summary = c.goal.summary()
    assert summary["mission_items_reached"] == [1, 2, 3, 4]
    assert summary["mission_items_skipped"] == [5]          # DO_CHANGE_SPEED: not applied yet
    assert summary["mission_final"] == "return"
    times = summary["mission_items_reached_t_s"]
    assert times == sorted(times) and c.state.goal_reached_t_s is not None
    texts = [text for _, text in c.state.events]
    assert [t for t in texts if "reached" in t and "item" in t] == [f"companion: mission item {k} reached" for k in (1, 2, 3, 4)]
    # each waypoint was passed within its acceptance radius (1 m) in the companion's records
    positions = np.array([r.drone_position for r in c.records])
    for n, e, d in WPS:
        assert np.min(np.linalg.norm(positions - [n, e, d], axis=1)) < 1.0


def test_that_the_autopilots_current_item_is_kept_in_step(flown):
    run, sent = flown
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    current = []
    for _, direction, packet in sent:
        if direction != "to_vehicle":
            continue
        for m in mav.parse_buffer(packet) or []:
            if m.get_type() == "MISSION_SET_CURRENT":
                current.append(m.seq)
    assert current == [1, 2, 3, 4, 5]   # the first waypoint on engaging, then the item after each reached one


def test_that_a_mission_file_is_uploaded_before_it_is_flown(tmp_path):
    """mavsim stores what the companion uploads (mission protocol), then the same waypoints are flown."""
    plan = tmp_path / "square.plan"
    plan.write_text(plan_text(WPS[:2]))
    sent = []
    run = run_lockstep(_scenario(plan, duration_s=20.0), seed=0, stop_after_goal_s=None,
                       drop=lambda t, d, p: sent.append((t, d, p)) and False)
    c = run.companion
    assert c.goal.transfer is not None and c.goal.transfer.done and c.goal.transfer.resent == 0
    assert c.goal.summary()["mission_items_reached"] == [1, 2]
    texts = [text for _, text in c.state.events]
    assert texts.index("companion: uploading mission, 4 items") < texts.index("companion: mission of 2 waypoints placed")
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    acks = [m for _, d, p in sent if d == "to_companion" for m in (mav.parse_buffer(p) or []) if m.get_type() == "MISSION_ACK"]
    assert [a.type for a in acks] == [mavlink2.MAV_MISSION_ACCEPTED]


def test_that_a_vehicle_without_a_mission_is_one_error_and_nothing_flown(tmp_path, monkeypatch):
    """--mission vehicle: the download (mavsim holds no mission) ends the run before anything is armed or streamed."""
    import companion.offline.harness as harness
    from companion.loop.mission_goal import MissionGoal
    from companion.loop.vehicle_reference import VehicleReference
    from companion.mavlink.offboard import Phase

    made = harness.Companion

    def with_download(config, offboard=None, **keywords):
        reference = VehicleReference()
        return made(config, offboard=offboard, goal=MissionGoal(config.mission, reference, None), reference=reference,
                    **keywords)

    monkeypatch.setattr(harness, "Companion", with_download)
    plan = tmp_path / "unused.plan"
    plan.write_text(plan_text(WPS[:1]))
    run = run_lockstep(_scenario(plan, duration_s=4.0), seed=0, stop_after_goal_s=None)
    c = run.companion
    assert c.goal.transfer.done and c.goal.transfer.count == 0
    assert c.sequencer.phase is Phase.GAVE_UP and "the vehicle's mission: mission.items: the mission is empty" in c.goal_error
    assert c.records == [] and run.truth["final_mode"] == "AUTO.LOITER"


def test_that_a_mission_ending_in_a_return_is_handed_to_the_autopilot_a_second_after_its_last_waypoint(flown):
    """Flown in OFFBOARD with no --exit-after-goal, the final RTL still ends the flight: Hold a second
    after the last waypoint, then the return commanded (not a hover in OFFBOARD until the run ends)."""
    run, sent = flown
    c = run.companion
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    commands = [(t, m.command) for t, direction, packet in sent if direction == "to_vehicle"
                for m in (mav.parse_buffer(packet) or []) if m.get_type() == "COMMAND_LONG"]
    rtl = [t for t, cmd in commands if cmd == mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH]
    assert len(rtl) == 1, commands
    events = [(t, text) for t, text in c.state.events]
    handing = [t for t, text in events if text.startswith("HANDING_BACK")]
    assert handing and 1.0 - 1e-6 <= handing[0] - c.state.goal_reached_t_s <= 1.0 + 4.0   # (settling allowed)
    assert "companion: mission ends, return (autopilot)" in [text for _, text in events]
    assert run.truth["final_mode"] == "AUTO.RTL"
