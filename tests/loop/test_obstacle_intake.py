"""The obstacle intake (companion.loop.intake.obstacles): routing by link, system and ICAO; counted rejections."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import ConfigError
from companion.loop.intake.obstacles import ObstacleIntake
from companion.loop.intake.traffic_config import TrafficConfig, traffic_from_toml
from companion.mavlink.link import Received
from estimator import ObstacleTracker, TrackerConfig
from mavsim.geo import ned_to_global

AP = (1, 1)
ORIGIN = (47.397742, 8.545594, 488.0)


def rx(msg, sysid, compid, t_s, link="autopilot"):
    mav = mavlink2.MAVLink(None, sysid, compid)
    parsed = mavlink2.MAVLink(None).parse_char(msg.pack(mav))
    return Received(t_s, parsed, b"", link)


def intake(config: TrafficConfig | None = None) -> ObstacleIntake:
    return ObstacleIntake(config or TrafficConfig(), ObstacleTracker(TrackerConfig()), lambda t: t - 100.0, 0.5)


def origin_msg():
    return mavlink2.MAVLink_gps_global_origin_message(round(ORIGIN[0] * 1e7), round(ORIGIN[1] * 1e7), round(ORIGIN[2] * 1e3), 0)


def adsb(north, icao=0xA00065, emitter=14, truncate=True):
    lat, lon, alt = ned_to_global(north, 0.0, -5.0, *ORIGIN)
    f = int if truncate else round
    return mavlink2.MAVLink_adsb_vehicle_message(icao, f(lat * 1e7), f(lon * 1e7), 1, round(alt * 1000), 0, 150, 0,
                                                 b"X", emitter, 0, 1 | 2 | 4 | 8, 0)


def odometry(t_us, x):
    nan = math.nan
    return mavlink2.MAVLink_odometry_message(t_us, 1, 1, x, 0.0, -5.0, [1, 0, 0, 0], nan, nan, nan, 0, 0, 0,
                                             [0.02, 0, 0, 0, 0, 0, 0.02, 0, 0, 0, 0, 0.02] + [0.0] * 9, [nan] * 21, 0, 0, 0)


def test_that_adsb_waits_for_the_origin_requests_it_and_then_tracks_one_aircraft_from_both_copies():
    it = intake()
    assert it.claims(rx(adsb(10.0), 1, 1, 200.0), AP)
    assert it.summary()["rejected"] == {}                   # early, not wrong: counted as waiting
    assert it.summary()["waiting"] == {"autopilot ICAO A00065: ADSB_VEHICLE: no GPS_GLOBAL_ORIGIN yet": 1}
    requests, _ = it.outbound(200.0, AP)
    (cmd,) = requests
    assert cmd.command == mavlink2.MAV_CMD_REQUEST_MESSAGE and cmd.param1 == 49 and (cmd.target_system, cmd.target_component) == AP
    assert it.outbound(200.5, AP)[0] == []  # not more often than every 2 s
    assert it.claims(rx(origin_msg(), 1, 1, 200.6), AP) and it.origin is not None
    assert it.outbound(203.0, AP)[0] == []  # heard: no more requests
    for k in range(5):
        t = 201.0 + 0.1 * k
        it.claims(rx(adsb(10.0 + 0.15 * k), 1, 1, t), AP)  # PX4's re-stream, under its own id
        it.claims(rx(adsb(10.0 + 0.15 * k, truncate=False), 101, 1, t + 0.001), AP)  # the forwarded original
    assert it.tracker.keys() == [("icao", 0xA00065)] and it.summary()["adsb_duplicates"] == 5
    assert np.allclose(it.tracker.state(("icao", 0xA00065)).position, [10.6, 0.0, -5.0], atol=0.05)


def test_that_the_adsb_emitter_type_sets_the_radius_unless_a_source_rule_does():
    it = intake()
    it.claims(rx(origin_msg(), 1, 1, 0.0), AP)
    it.claims(rx(adsb(10.0, icao=0x1, emitter=2), 1, 1, 200.0), AP)
    it.claims(rx(adsb(30.0, icao=0x2, emitter=14), 1, 1, 200.0), AP)
    assert it.radius(("icao", 0x1)) == 10.0 and it.radius(("icao", 0x2)) == 0.5
    ruled = intake(traffic_from_toml({"source": [{"link": "autopilot", "icao": 1, "radius_m": 3.0, "kinds": ["ADSB_VEHICLE"]}]}, "t"))
    ruled.claims(rx(origin_msg(), 1, 1, 0.0), AP)
    ruled.claims(rx(adsb(10.0, icao=0x1, emitter=2), 1, 1, 200.0), AP)
    assert ruled.radius(("icao", 0x1)) == 3.0


def test_that_obstacle_odometry_on_the_autopilot_link_is_warned_about_counted_and_not_used():
    it = intake()
    for k in range(3):
        assert it.claims(rx(odometry(1_000_000 + 100_000 * k, 5.0), 101, 197, 200.0 + 0.1 * k), AP)
    s = it.summary()
    assert len(it.tracker) == 0 and s["rejected"] == {"autopilot sys 101: wrong link: ODOMETRY": 3}
    assert len(s["warnings"]) == 1 and "EKF2_EV_CTRL" in s["warnings"][0] and "--obstacles" in s["warnings"][0]
    _, texts = it.outbound(200.3, AP)
    assert [t for _, t in texts] == ["ODOMETRY sys 101 on AP link: EV risk", "obstacles: 3 rejected, autopilot sys 101: wrong link: ODOMETRY"]
    assert it.outbound(201.0, AP)[1] == []  # nothing new; and at most one summary per period
    it.claims(rx(odometry(2_000_000, 5.0), 101, 197, 201.5), AP)
    assert it.outbound(202.0, AP)[1] == []
    assert [t for _, t in it.outbound(205.4, AP)[1]] == ["obstacles: 1 rejected, autopilot sys 101: wrong link: ODOMETRY"]


def test_that_the_autopilots_own_messages_on_an_obstacle_link_are_wrong_link_and_never_reach_the_vehicle_side():
    it = intake()
    hb = mavlink2.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3)
    assert it.claims(rx(hb, 1, 1, 200.0, "obstacles1"), AP)  # claimed: the caller never sees it
    assert it.claims(rx(odometry(5_000_000, 5.0), 1, 1, 200.0, "obstacles1"), AP)
    assert it.summary()["rejected"] == {"obstacles1 sys 1: wrong link: HEARTBEAT of the autopilot's system": 1,
                                        "obstacles1 sys 1: wrong link: ODOMETRY of the autopilot's system": 1}
    assert it.claims(rx(odometry(5_000_000, 5.0), 101, 197, 200.0, "obstacles1"), AP)
    assert it.tracker.keys() == [(101, 197, "obstacles1")]
    assert not it.claims(rx(hb, 1, 1, 200.0), AP)  # on its own link the autopilot is the caller's


def test_that_kinds_a_source_does_not_accept_are_counted():
    it = intake(traffic_from_toml({"obstacle_link_kinds": ["LOCAL_POSITION_NED"]}, "t"))
    it.claims(rx(odometry(5_000_000, 5.0), 101, 197, 200.0, "obstacles1"), AP)
    assert it.summary()["rejected"] == {"obstacles1 sys 101: kind not accepted: ODOMETRY": 1} and len(it.tracker) == 0


def test_that_a_report_before_the_vehicle_clock_is_known_is_counted_as_waiting_not_rejected():
    it = ObstacleIntake(TrafficConfig(), ObstacleTracker(TrackerConfig()), lambda t: None, 0.5)
    it.claims(rx(odometry(5_000_000, 5.0), 101, 197, 200.0, "obstacles1"), AP)
    summary = it.summary()
    assert summary["rejected"] == {} and summary["rejected_total"] == 0
    assert summary["waiting"] == {"obstacles1 sys 101: vehicle time unknown": 1} and summary["waiting_total"] == 1


def utm(north, geoid_m):
    lat, lon, alt = ned_to_global(north, 0.0, -5.0, *ORIGIN)
    return mavlink2.MAVLink_utm_global_position_message(
        1_767_226_200_000_000, bytes(18), round(lat * 1e7), round(lon * 1e7), round((alt + geoid_m) * 1000), 5000,
        0, 0, 0, 300, 500, 0, 0, 0, 0, 10, 3, 1 | 4 | 8)


def gps_raw_int(geoid_m):
    return mavlink2.MAVLink_gps_raw_int_message(0, 3, round(ORIGIN[0] * 1e7), round(ORIGIN[1] * 1e7), round(ORIGIN[2] * 1e3),
                                                70, 100, 0, 0, 12, round((ORIGIN[2] + geoid_m) * 1e3))


def test_that_ellipsoid_height_traffic_waits_for_the_autopilots_geoid_separation_and_asks_for_it():
    it = intake()
    it.claims(rx(origin_msg(), 1, 1, 200.0), AP)
    it.claims(rx(utm(10.0, 47.3), 101, 1, 200.1, link="obstacles1"), AP)
    assert "geoid separation unknown" in next(iter(it.summary()["rejected"]))
    (cmd,) = it.outbound(200.2, AP)[0]
    assert cmd.command == mavlink2.MAV_CMD_REQUEST_MESSAGE and cmd.param1 == 24 and (cmd.target_system, cmd.target_component) == AP
    assert not it.claims(rx(gps_raw_int(47.3), 1, 1, 200.3), AP)  # read, and left to the vehicle side too
    assert it.summary()["geoid_separation_m"] == pytest.approx(47.3)
    it.claims(rx(utm(10.0, 47.3), 101, 1, 200.4, link="obstacles1"), AP)
    (key,) = it.tracker.keys()
    assert np.allclose(it.tracker.state(key).position, [10.0, 0.0, -5.0], atol=0.05)  # 5 m up, not 42 m below ground
    assert it.outbound(203.0, AP)[0] == []  # measured: no more requests


def test_that_a_configured_geoid_separation_serves_until_the_autopilot_gives_one_and_requests_are_bounded():
    it = intake(TrafficConfig(geoid_separation_m=20.0))
    it.claims(rx(origin_msg(), 1, 1, 200.0), AP)
    it.claims(rx(utm(10.0, 20.0), 101, 1, 200.1, link="obstacles1"), AP)
    assert it.summary()["rejected"] == {} and it.summary()["geoid_separation_m"] == 20.0
    sent = sum(len(it.outbound(200.0 + 2.0 * k, AP)[0]) for k in range(20))
    assert sent == 5 and any("geoid" in w for w in it.warnings)  # asked 5 times, then said so once
    with pytest.raises(ConfigError, match=r"geoid_separation_m = 300\.0"):
        traffic_from_toml({"geoid_separation_m": 300.0}, "f.toml [traffic]")


def test_that_bad_traffic_settings_name_the_file_and_key():
    with pytest.raises(ConfigError, match=r"f\.toml \[traffic\]: position_std_m = -1\.0 must be positive"):
        traffic_from_toml({"position_std_m": -1.0}, "f.toml [traffic]")
    with pytest.raises(ConfigError, match="unknown kind"):
        traffic_from_toml({"autopilot_link_kinds": ["HEARTBEAT"]}, "f.toml [traffic]")
    with pytest.raises(ConfigError, match=r"f\.toml \[traffic\] \[\[traffic\.source\]\] #1: link = 'gcs'"):
        traffic_from_toml({"source": [{"link": "gcs"}]}, "f.toml [traffic]")
    with pytest.raises(ConfigError, match=r"f\.toml \[traffic\]: unknown key\(s\) radius"):
        traffic_from_toml({"radius": 1.0}, "f.toml [traffic]")
    with pytest.raises(ConfigError, match=r"#2: system = 0 must be >= 1"):
        traffic_from_toml({"source": [{"link": "*"}, {"system": 0}]}, "f.toml [traffic]")
    with pytest.raises(ConfigError, match="at most 64 allowed"):  # bounded: a file cannot ask for any number of rules
        traffic_from_toml({"source": [{"link": "*"}] * 65}, "f.toml [traffic]")
    with pytest.raises(ConfigError, match="obstacle_links"):
        traffic_from_toml({"obstacle_links": ["udpin:0.0.0.0:1"] * 17}, "f.toml [traffic]")


def test_that_each_source_sets_how_far_out_its_obstacles_are_planned_around():
    """``range_m``: ``[traffic]``'s for every report, a ``[[traffic.source]]`` rule's for its own
    (the fleet link's too); None without either (the planner's ``sensing_range_m``)."""
    plain = intake()
    plain.claims(rx(odometry(1_000_000, 5.0), 101, 197, 200.0, link="obstacles1"), AP)
    assert plain.tracker.keys() and plain.planning_range(plain.tracker.keys()[0]) is None
    ruled = intake(traffic_from_toml({"range_m": 40.0, "source": [
        {"link": "obstacles", "system": 102, "range_m": 8.0},
        {"link": "fleet", "range_m": math.inf}]}, "t"))
    for sysid, link in ((101, "obstacles1"), (102, "obstacles1"), (2, "fleet")):
        ruled.claims(rx(odometry(1_000_000, 5.0), sysid, 197, 200.0, link=link), AP)
    ranges = {key[0]: ruled.planning_range(key) for key in ruled.tracker.keys()}
    assert ranges == {101: 40.0, 102: 8.0, 2: math.inf}


@pytest.mark.parametrize(("table", "match"), [
    ({"range_m": 0.0}, r"t: range_m = 0.0 must be positive"),
    ({"range_m": "far"}, r"t: range_m = 'far' is not a number"),
    ({"source": [{"link": "fleet", "range_m": -5}]}, r"t \[\[traffic.source\]\] #1: range_m = -5 must be positive"),
    ({"source": [{"link": "peers"}]}, r"link = 'peers' must be .*\"fleet\""),
])
def test_that_a_bad_range_is_named(table, match):
    with pytest.raises(ConfigError, match=match):
        traffic_from_toml(table, "t")
