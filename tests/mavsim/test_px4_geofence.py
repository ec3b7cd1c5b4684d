"""mavsim's PX4 keeps its geofence as PX4 SITL did (docs/PX4_FACTS.md, "Geofence").

Measured on PX4 SITL: with GF_MAX_HOR_DIST 15 m, flown north at 2 m/s in OFFBOARD, PX4 took the
vehicle to Hold at 15.95 and 16.29 m from home ("Geofence: exceeding maximum distance to Home",
"Failsafe activated") and, left outside, returned 9.1 and 10.1 s later; with GF_MAX_VER_DIST
10 m, climbing at 1 m/s, to Hold at 10.62 and 10.75 m above home.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavsim.params import ParamStore
from mavsim.personalities.px4 import PARAMS
from mavsim.personalities.px4_geofence import (DELAY_S, TEXT_ALTITUDE, TEXT_DISTANCE, TEXT_FAILSAFE, TEXT_ZONE,
                                               FenceZones, GeofenceWatch)
from mavsim.missions import MissionItem
from tests.support.mavsim_client import AIRBORNE, Client, of_type, texts, vel_sp


def _airborne(**params) -> dict:
    return {**AIRBORNE, "sim": {"params": params}}


def _fly_until_hold(c: Client, setpoint, max_s: float = 30.0) -> tuple[float, np.ndarray]:
    c.run(1.0, setpoint)                       # the stream first: PX4 enters OFFBOARD only with one
    c.set_mode_offboard(setpoint)
    assert c.mode() == "OFFBOARD"
    while c.sim.time_s < max_s:
        msgs = c.run(0.1, setpoint)
        if c.mode(msgs if of_type(msgs, "HEARTBEAT") else None) != "OFFBOARD":
            break
    # where the vehicle was when PX4's commander switched (the HEARTBEAT says so up to 1 s later)
    t_switch = c.sim._sim.commander.mode_changes[-1][0]
    pos = min(((t, m) for t, m in c.log if m.get_type() == "LOCAL_POSITION_NED"), key=lambda tm: abs(tm[0] - t_switch))[1]
    return t_switch, np.array([pos.x, pos.y, pos.z])


def test_flown_out_of_gf_max_hor_dist_the_vehicle_is_held_then_returned_as_px4_did():
    c = Client(_airborne(GF_MAX_HOR_DIST=15.0))
    t_hold, p = _fly_until_hold(c, vel_sp(vx=2.0))
    assert c.mode() == "LOITER"
    print(f"held at {math.hypot(p[0], p[1]):.2f} m from home")
    assert 15.4 < math.hypot(p[0], p[1]) < 16.6, p           # PX4: 15.95 and 16.29 m
    said = texts([m for _, m in c.log])
    assert said[-2:] == [TEXT_DISTANCE, TEXT_FAILSAFE], said
    c.run(t_hold + 9.0 - c.sim.time_s)
    assert c.sim._sim.commander.mode == "AUTO.LOITER"        # still outside, still holding
    msgs = c.run(1.0)
    assert c.sim._sim.commander.mode == "AUTO.RTL" and texts(msgs) == [TEXT_DISTANCE, TEXT_FAILSAFE]
    assert c.sim._sim.commander.mode_changes[-1][0] - t_hold == pytest.approx(9.5, abs=0.02)  # PX4: 9.1, 10.1 s


def test_climbing_through_gf_max_ver_dist_the_vehicle_is_held():
    c = Client(_airborne(GF_MAX_VER_DIST=10.0))
    _, p = _fly_until_hold(c, vel_sp(vz=-1.0))
    print(f"held at {-p[2]:.2f} m above home")
    assert c.mode() == "LOITER" and 10.2 < -p[2] < 11.0, p   # PX4: 10.62 and 10.75 m
    assert texts([m for _, m in c.log])[-2:] == [TEXT_ALTITUDE, TEXT_FAILSAFE]


def test_without_limits_or_zones_nothing_is_kept():
    c = Client(_airborne())
    c.run(1.0, vel_sp(vx=3.0))
    c.set_mode_offboard(vel_sp(vx=3.0))
    c.run(12.0, vel_sp(vx=3.0))
    assert c.mode() == "OFFBOARD" and not any(t.startswith("Geofence") for t in texts([m for _, m in c.log]))


def _item(seq, command, north, east, p1=0.0):
    return MissionItem(seq, command, (p1, 0.0, 0.0, 0.0), np.array([north, east, 0.0]))


def _watch(**params) -> GeofenceWatch:
    return GeofenceWatch(ParamStore(PARAMS, params))


def test_zones_inclusion_polygon_and_exclusion_circle():
    ring = [(-5, -5), (-5, 5), (20, 5), (20, -5)]
    items = [_item(k, 5001, n, e, 4) for k, (n, e) in enumerate(ring)] + [_item(4, 5004, 10, 0, 2.0)]
    watch = _watch()
    watch.load(FenceZones.from_items(items))
    assert watch.breach(np.array([0.0, 0.0, -5.0])) is None
    assert watch.breach(np.array([10.5, 0.5, -5.0])) == TEXT_ZONE         # in the exclusion circle
    assert watch.breach(np.array([21.0, 0.0, -5.0])) == TEXT_ZONE         # out of the inclusion polygon
    assert watch.breach(np.array([5.0, 4.9, -50.0])) is None              # a zone covers every altitude


@pytest.mark.parametrize("action, expected", [(0, None), (1, ((TEXT_DISTANCE,), None)),
                                              (2, ((TEXT_DISTANCE, TEXT_FAILSAFE), "AUTO.LOITER")),
                                              (3, ((TEXT_DISTANCE, TEXT_FAILSAFE), "AUTO.RTL")),
                                              (5, ((TEXT_DISTANCE, TEXT_FAILSAFE), "AUTO.LAND"))])
def test_gf_action_chooses_what_is_done_after_the_delay_and_back_inside_it_starts_afresh(action, expected):
    watch = _watch(GF_MAX_HOR_DIST=10.0, GF_ACTION=action)
    out = np.array([10.5, 0.0, -5.0])
    assert watch.step(1.0, out, "OFFBOARD") is None
    got = watch.step(1.0 + DELAY_S, out, "OFFBOARD")
    assert (None if got is None else (got.texts, got.mode)) == expected
    assert watch.step(1.1 + DELAY_S, out, "OFFBOARD") is None                 # once
    assert watch.step(2.0 + DELAY_S, np.array([9.0, 0.0, -5.0]), "OFFBOARD") is None
    assert watch.step(3.0, out, "OFFBOARD") is None                           # a new breach waits again
