"""mavsim plays traffic the field's ways: ADSB re-streamed by the autopilot, obstacle-link messages, sender clocks."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.errors import ScenarioError
from mavsim.lockstep import LockstepSimulator
from mavsim.scenario import scenario_from_dict
from tests.support.mavsim_client import Client, with_obstacles

AIRBORNE = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]}}


def _parse(packets):
    dec = mavlink2.MAVLink(None)
    return [m for _, p in packets for m in dec.parse_buffer(p) or []]


def test_that_adsb_traffic_is_restreamed_by_the_autopilot_under_its_own_id_and_forwarded_under_the_senders():
    vel_cov = [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]]
    sim = LockstepSimulator(with_obstacles(AIRBORNE, 2, transport="adsb", velocity_cov_m2ps2=vel_cov))
    msgs = _parse(sim.advance(1.0))
    assert sim.take_obstacle_packets() == [] and not sim.has_obstacle_link
    adsb = [m for m in msgs if m.get_type() == "ADSB_VEHICLE"]
    restream = [m for m in adsb if m.get_srcSystem() == 1]
    original = [m for m in adsb if m.get_srcSystem() in (101, 102)]
    assert len(restream) == len(original) >= 18 and {m.ICAO_address for m in restream} == {0xA00065, 0xA00066}
    assert all(not m.flags & 128 for m in restream) and all(m.flags & 128 for m in original)  # PX4 strips vz validity
    assert not any(m.get_type() == "HEARTBEAT" and m.get_srcSystem() in (101, 102) for m in msgs)  # not forwarded


def test_that_gps_global_origin_is_answered_when_requested():
    c = Client(AIRBORNE)
    got = c.command(mavlink2.MAV_CMD_REQUEST_MESSAGE, 49)
    origin = [m for m in got if m.get_type() == "GPS_GLOBAL_ORIGIN"]
    assert origin and (origin[0].latitude, origin[0].longitude, origin[0].altitude) == (473977420, 85455940, 488000)


def test_that_gps_raw_int_reports_the_ellipsoid_height_and_ellipsoid_kinds_carry_it():
    """GPS_RAW_INT ``alt_ellipsoid - alt`` is the geoid separation; UTM and Remote ID send ellipsoid heights."""
    scenario = with_obstacles(AIRBORNE, 2, transport="link", message="UTM_GLOBAL_POSITION")
    scenario["world"]["obstacles"][1]["message"] = "OPEN_DRONE_ID_LOCATION"
    scenario.setdefault("sim", {})["geoid_separation_m"] = 31.5
    c = Client(AIRBORNE | {"sim": {"geoid_separation_m": 31.5}})
    (raw,) = [m for m in c.command(mavlink2.MAV_CMD_REQUEST_MESSAGE, 24) if m.get_type() == "GPS_RAW_INT"]
    assert raw.fix_type == 3 and raw.alt_ellipsoid - raw.alt == 31_500
    sim = LockstepSimulator(scenario)
    sim.advance(1.0)
    reports = _parse(sim.take_obstacle_packets())
    utm = next(m for m in reports if m.get_type() == "UTM_GLOBAL_POSITION")
    odid = next(m for m in reports if m.get_type() == "OPEN_DRONE_ID_LOCATION")
    assert utm.alt - utm.relative_alt - 488_000 == 31_500  # relative_alt is above home, alt is ellipsoid height
    assert odid.altitude_geodetic - odid.altitude_barometric == pytest.approx(31.5, abs=1e-3)


@pytest.mark.parametrize("message", ["ODOMETRY", "LOCAL_POSITION_NED", "UTM_GLOBAL_POSITION", "OPEN_DRONE_ID_LOCATION"])
def test_that_link_obstacles_send_their_message_on_the_obstacle_link_only(message):
    sim = LockstepSimulator(with_obstacles(AIRBORNE, 1, transport="link", message=message))
    api = _parse(sim.advance(1.0))
    obstacle = _parse(sim.take_obstacle_packets())
    assert not any(m.get_srcSystem() == 101 for m in api)
    assert {m.get_type() for m in obstacle} == {"HEARTBEAT", message} and all(m.get_srcSystem() == 101 for m in obstacle)


def test_that_a_sender_clock_has_its_offset_drift_reboot_and_garbage_stamp():
    sim = LockstepSimulator(with_obstacles(AIRBORNE, 1, message="LOCAL_POSITION_NED", clock_offset_s=-100.0,
                                           clock_drift=0.01, clock_reboot_at_s=2.0, garbage_stamp_at_s=1.0))
    sim.advance(3.0)
    stamps = [m.time_boot_ms for m in _parse(sim.take_obstacle_packets()) if m.get_type() == "LOCAL_POSITION_NED"]
    assert stamps[0] == round((-100.0 + 1.01 * 0.01) * 1e3) % (1 << 32)  # first step; a clock before its zero wraps
    assert 0xFFFFFFFF in stamps and stamps.count(0xFFFFFFFF) == 1
    after = stamps[stamps.index(0xFFFFFFFF) + 1:]
    assert min(after) < 1020  # rebooted at 2 s: the boot clock starts again from 0


def test_that_bad_transport_settings_name_the_obstacle_and_key():
    with pytest.raises(ScenarioError, match=r"world\.obstacles\[0\].*transport"):
        scenario_from_dict(with_obstacles(AIRBORNE, 1, transport="carrier-pigeon"))
    with pytest.raises(ScenarioError, match=r"message"):
        scenario_from_dict(with_obstacles(AIRBORNE, 1, transport="adsb", message="ODOMETRY"))
    with pytest.raises(ScenarioError, match=r"clock_drift"):
        scenario_from_dict(with_obstacles(AIRBORNE, 1, clock_drift=0.5))
