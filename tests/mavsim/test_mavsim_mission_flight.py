"""mavsim flies AUTO.MISSION as PX4 SITL did (docs/PX4_FACTS.md, "Missions").

The mission measured on PX4 SITL: a takeoff to 5 m, a waypoint 20 m north, DO_CHANGE_SPEED
2 m/s, a waypoint 20 m east of it, one back west at 8 m with a 3 m acceptance radius, and a
landing at home. PX4 flew it in AUTO.MISSION to the ground and disarmed; MISSION_ITEM_REACHED
named items 0, 2, 3, 4, 5 (never 1: the DO_ item after it was done in the same step), the
waypoints were reached 1.9 m (default NAV_ACC_RAD 2 m) and 2.9 m (param2 3 m) short, and the
leg after the speed change flew at no more than 1.93 m/s. MISSION_CURRENT came at 1 Hz, and
each MISSION_ITEM_REACHED eleven times: at once, then with each of the next ten MISSION_CURRENT.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.mission_protocol import MissionItem, MissionUpload
from mavsim.scenario import scenario_from_dict
from mavsim.telemetry import EARTH_RADIUS_M
from tests.support.mavsim_client import GROUND, Client

AP = (1, 1)
REL = mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT
#: (command, params, north m, east m, altitude above home m); None: no position
MISSION = [
    (mavlink2.MAV_CMD_NAV_TAKEOFF, (0.0, 0.0, 0.0, math.nan), 0.0, 0.0, 5.0),     # at home, as QGroundControl writes it
    (mavlink2.MAV_CMD_NAV_WAYPOINT, (0.0, 0.0, 0.0, math.nan), 20.0, 0.0, 5.0),
    (mavlink2.MAV_CMD_DO_CHANGE_SPEED, (1.0, 2.0, -1.0, 0.0), None, None, 0.0),
    (mavlink2.MAV_CMD_NAV_WAYPOINT, (0.0, 0.0, 0.0, math.nan), 20.0, 20.0, 5.0),
    (mavlink2.MAV_CMD_NAV_WAYPOINT, (0.0, 3.0, 0.0, math.nan), 0.0, 20.0, 8.0),
    (mavlink2.MAV_CMD_NAV_LAND, (0.0, 0.0, 0.0, math.nan), 0.0, 0.0, 0.0),
]


def _items(home: tuple[float, float]) -> list[MissionItem]:
    lat0, lon0 = home
    out = []
    for seq, (command, params, north, east, alt) in enumerate(MISSION):
        lat = 0.0 if north is None else lat0 + math.degrees(north / EARTH_RADIUS_M)
        lon = 0.0 if east is None else lon0 + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
        frame = mavlink2.MAV_FRAME_MISSION if command == mavlink2.MAV_CMD_DO_CHANGE_SPEED else REL
        out.append(MissionItem(seq=seq, frame=frame, command=command, params=params, x=lat, y=lon, z=alt))
    return out


def _upload(c: Client, items: list[MissionItem]) -> None:
    up = MissionUpload(AP, items)
    for msg in up.start(c.sim.time_s):
        c.send(msg)
    while not up.over and c.sim.time_s < 10.0:
        for m in c.run(0.05):
            for answer in up.on_message(c.sim.time_s, m):
                c.send(answer)
        for msg in up.step(c.sim.time_s):
            c.send(msg)
    assert up.done


def _fly() -> tuple[Client, list]:
    sim = scenario_from_dict(GROUND).sim
    c = Client(GROUND)
    _upload(c, _items((sim.home_lat_deg, sim.home_lon_deg)))
    assert [m.result for m in c.command(400, 1) if m.get_type() == "COMMAND_ACK"] == [0]
    started = c.sim.time_s
    acks = [m for m in c.command(300, 0, 0) if m.get_type() == "COMMAND_ACK"]
    assert [(a.command, a.result) for a in acks] == [(300, 0)]
    for _ in range(1200):                      # at most 120 s
        c.run(0.1)
        if not c.heartbeat().base_mode & 128 and c.sim.time_s > started + 5.0:
            break
    c.run(12.0)                                # the last MISSION_ITEM_REACHED sent again, ten times
    return c, [(t - started, m) for t, m in c.log if t >= started]


def test_that_the_measured_mission_flies_to_the_ground_in_auto_mission():
    c, log = _fly()
    sent = [(t, m.seq) for t, m in log if m.get_type() == "MISSION_ITEM_REACHED"]
    reached = [(t, seq) for k, (t, seq) in enumerate(sent) if k == 0 or sent[k - 1][1] != seq]   # each first time
    assert [seq for _, seq in reached] == [0, 2, 3, 4, 5]                  # as PX4 named them
    last = [t for t, seq in sent if seq == 5]
    assert len(last) == 11 and 0.0 < last[1] - last[0] <= 1.01 and np.diff(last[1:]).min() > 0.99 and np.diff(last[1:]).max() < 1.01
    for seq, (t_next, _) in zip((0, 2, 3, 4), reached[1:]):   # again at 1 Hz until the next is reached
        times = [t for t, s in sent if s == seq]
        assert 1 <= len(times) <= 11 and times[-1] < t_next and np.diff(times).max() <= 1.01
    modes = {(m.custom_mode >> 16 & 0xFF, m.custom_mode >> 24 & 0xFF) for t, m in log
             if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1 and m.base_mode & 128}
    assert modes == {(4, 4)}                                                # AUTO.MISSION to the end
    assert not c.heartbeat().base_mode & 128 and c.sim.simulator.truth.drone_position_ned_m[2] == pytest.approx(0.0, abs=0.05)
    pos = [(t, np.array([m.x, m.y, m.z]), np.array([m.vx, m.vy, m.vz])) for t, m in log if m.get_type() == "LOCAL_POSITION_NED"]

    def at(t_s):
        return min(pos, key=lambda p: abs(p[0] - t_s))

    t_wp2, t_wp3 = reached[2][0], reached[3][0]
    assert np.hypot(*(at(t_wp2)[1][:2] - [20.0, 20.0])) == pytest.approx(2.0, abs=0.15)    # NAV_ACC_RAD
    assert np.hypot(*(at(t_wp3)[1][:2] - [0.0, 20.0])) == pytest.approx(3.0, abs=0.15)     # param2
    assert at(t_wp3)[1][2] == pytest.approx(-8.0, abs=0.8)
    fast = max(np.hypot(*v[:2]) for t, _, v in pos if reached[0][0] < t < reached[1][0])
    slow = max(np.hypot(*v[:2]) for t, _, v in pos if reached[1][0] + 1.0 < t < reached[3][0])
    assert 4.0 < fast <= 5.2 and slow <= 2.1     # MPC_XY_CRUISE (5 m/s), then DO_CHANGE_SPEED; the estimate's velocity noise on top
    current = [(t, m.seq, m.total, m.mission_state, m.mission_mode) for t, m in log if m.get_type() == "MISSION_CURRENT"]
    assert {(seq, total, state, mode) for t, seq, total, state, mode in current if t < reached[-1][0]} >= {
        (0, 6, 3, 1), (1, 6, 3, 1), (3, 6, 3, 1), (4, 6, 3, 1)}
    assert current[-1][1:] == (5, 6, 5, 1)                                 # complete once on the ground
    gaps = np.diff([t for t, *_ in current])
    assert gaps.min() > 0.9 and gaps.max() < 1.1                           # 1 Hz


def test_that_a_mission_start_without_a_mission_is_denied_by_name():
    c = Client(GROUND)
    msgs = c.command(300, 0, 0)
    assert [(m.command, m.result) for m in msgs if m.get_type() == "COMMAND_ACK"] == [(300, mavlink2.MAV_RESULT_DENIED)]
    assert any(m.get_type() == "STATUSTEXT" and m.text == "Mission start denied! No valid mission" for m in msgs)
    assert c.sim.simulator.commander.mode == "POSCTL"


def test_that_set_current_jumps_the_flying_mission_and_a_return_to_the_mode_resumes_it():
    sim = scenario_from_dict(GROUND).sim
    c = Client(GROUND)
    _upload(c, _items((sim.home_lat_deg, sim.home_lon_deg)))
    c.command(400, 1)
    c.command(300, 0, 0)
    while not any(m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 0 for _, m in c.log):
        c.run(0.1)
        assert c.sim.time_s < 30.0
    c.send(mavlink2.MAVLink_mission_set_current_message(1, 1, 4))     # skip to the waypoint at (0, 20), 8 m
    c.run(3.0)
    assert c.sim.simulator.commander.mission.current == 4
    c.command(176, 1, 4, 3)                                            # Hold (AUTO.LOITER)
    held = c.sim.simulator.truth.drone_position_ned_m.copy()
    c.run(2.0)
    assert c.sim.simulator.commander.mode == "AUTO.LOITER"
    c.command(176, 1, 4, 4)                                            # back to the mission: item 4 again
    for _ in range(300):                                               # at most 30 s
        c.run(0.1)
        if c.sim.simulator.commander.mission.current == 5:             # item 4 reached: the landing next
            break
    p = c.sim.simulator.truth.drone_position_ned_m
    assert c.sim.simulator.commander.mission.current == 5 and np.hypot(p[0] - 0.0, p[1] - 20.0) < 3.2, (p, held)
    reached = [m.seq for _, m in c.log if m.get_type() == "MISSION_ITEM_REACHED"]
    assert 1 not in reached and 2 not in reached and 3 not in reached and 4 in reached
