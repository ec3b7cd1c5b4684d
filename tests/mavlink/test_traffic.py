"""Traffic decoding (companion.mavlink.traffic): each kind to a Gaussian in local NED."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages, traffic
from mavsim.geo import ned_to_global

N = 47.3  # geoid above the WGS-84 ellipsoid at the origin, metres (any non-zero value)
ORIGIN = traffic.GlobalOrigin(47.397742, 8.545594, 488.0, N)


def packed(msg, sysid=1, compid=1):
    """The message as it arrives: packed by (sysid, compid) and parsed again."""
    mav = mavlink2.MAVLink(None, sysid, compid)
    return mavlink2.MAVLink(None).parse_char(msg.pack(mav))


def adsb(north, east, down, *, flags=1 | 2 | 4 | 8, icao=0xA00065, heading_cdeg=9000, speed_cms=150, emitter=14, sysid=1):
    lat, lon, alt = ned_to_global(north, east, down, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    return packed(mavlink2.MAVLink_adsb_vehicle_message(icao, int(lat * 1e7), int(lon * 1e7), 1, round(alt * 1000),
                                                        heading_cdeg, speed_cms, 50, b"OB", emitter, 2, flags, 0), sysid)


@pytest.mark.parametrize("ned", [(24.0, 0.3, -5.0), (-300.0, 1200.0, -80.0), (5000.0, -5000.0, 10.0)])
def test_that_the_projection_inverts_px4s_map_to_within_a_centimetre_after_degE7_truncation(ned):
    r = traffic.decode_adsb_vehicle(adsb(*ned), ORIGIN)
    assert np.allclose(r.position_ned, ned, atol=0.012)
    exact = ned_to_global(*ned, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    assert np.allclose(traffic.global_to_ned(*exact, ORIGIN), ned, atol=1e-6)


def test_that_adsb_is_identified_by_icao_timed_by_tslc_and_honours_its_validity_flags():
    r = traffic.decode_adsb_vehicle(adsb(10.0, 0.0, -5.0), ORIGIN)
    assert r.identity == ("icao", 0xA00065) and r.stamp is None and r.age_s == 2.0
    assert np.allclose(r.velocity_ned, [0.0, 1.5, 0.0], atol=1e-9)  # heading 90 deg: east; vz unknown -> 0
    assert r.vertical_velocity_unknown and r.position_cov is None  # configured accuracy applies
    with_vz = traffic.decode_adsb_vehicle(adsb(10.0, 0.0, -5.0, flags=1 | 2 | 4 | 8 | 128), ORIGIN)
    assert with_vz.velocity_ned[2] == pytest.approx(-0.5) and not with_vz.vertical_velocity_unknown  # up is -z
    assert traffic.decode_adsb_vehicle(adsb(10.0, 0.0, -5.0, flags=1 | 2), ORIGIN).velocity_ned is None
    for flags, word in ((2 | 4 | 8, "coordinates"), (1 | 4 | 8, "altitude")):
        rej = traffic.decode_adsb_vehicle(adsb(10.0, 0.0, -5.0, flags=flags), ORIGIN)
        assert isinstance(rej, messages.Rejected) and word in rej.reason
    assert isinstance(traffic.decode_adsb_vehicle(adsb(1, 1, 1), None), messages.Rejected)  # no origin yet


def test_that_the_adsb_emitter_type_sets_a_radius_and_a_uav_leaves_it_to_the_configuration():
    assert traffic.decode_adsb_vehicle(adsb(1, 1, -1, emitter=2), ORIGIN).radius_m == 10.0
    assert traffic.decode_adsb_vehicle(adsb(1, 1, -1, emitter=14), ORIGIN).radius_m is None


def test_that_utm_accuracies_are_standard_deviations():
    lat, lon, alt = ned_to_global(3.0, 4.0, -5.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    msg = packed(mavlink2.MAVLink_utm_global_position_message(
        1_767_226_200_000_000, bytes(18), round(lat * 1e7), round(lon * 1e7), round((alt + N) * 1000), 5000,
        100, -50, 20, 300, 500, 40, 0, 0, 0, 10, 3, 1 | 4 | 8 | 32 | 64), 7)
    r = traffic.decode_utm_global_position(msg, ORIGIN)
    assert np.allclose(r.position_ned, [3.0, 4.0, -5.0], atol=0.01)
    assert np.allclose(np.diag(r.position_cov), [0.09, 0.09, 0.25]) and np.allclose(np.diag(r.velocity_cov), 0.16)
    assert np.allclose(r.velocity_ned, [1.0, -0.5, 0.2]) and r.stamp_unit_s == 1e-6


@pytest.mark.parametrize("hor, ver, speed, sh, sv, svel", [
    (12, 6, 4, 1.0 / 2.4477, 1.0 / 1.96, 0.3 / 2.4477),
    (10, 4, 2, 10.0 / 2.4477, 10.0 / 1.96, 3.0 / 2.4477),
    (7, 1, 1, 185.2 / 2.4477, 150.0 / 1.96, 10.0 / 2.4477),
])
def test_that_remote_id_accuracy_categories_are_95_percent_bounds(hor, ver, speed, sh, sv, svel):
    lat, lon, alt = ned_to_global(-2.0, 6.0, -10.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    msg = packed(mavlink2.MAVLink_open_drone_id_location_message(
        0, 0, b"OB101".ljust(20, b"\0"), 2, 18000, 200, 100, round(lat * 1e7), round(lon * 1e7),
        float(alt), float(alt + N), 0, 10.0, hor, ver, 0, speed, 612.3, 1), 9)
    r = traffic.decode_open_drone_id_location(msg, ORIGIN)
    assert np.allclose(r.position_ned, [-2.0, 6.0, -10.0], atol=0.01)
    assert np.allclose(np.sqrt(np.diag(r.position_cov)), [sh, sh, sv], rtol=1e-3)
    assert np.allclose(np.sqrt(np.diag(r.velocity_cov)), [svel, svel, speed and svel * 2.4477 / 1.96], rtol=1e-3)
    assert np.allclose(r.velocity_ned, [-2.0, 0.0, -1.0], atol=1e-9)  # direction 180 deg: south; 1 m/s up
    assert r.identity[0] == "uas" and r.stamp == pytest.approx(612.3, abs=1e-3)


def test_that_remote_id_with_unknown_accuracy_leaves_it_to_the_configuration_and_unknown_fields_reject():
    lat, lon, alt = ned_to_global(1.0, 1.0, -1.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    args = [0, 0, bytes(20), 2, 36100, 25500, 6300, round(lat * 1e7), round(lon * 1e7), float(alt), float(alt + N), 0, 1.0, 0, 0, 0, 0, 10.0, 0]
    r = traffic.decode_open_drone_id_location(packed(mavlink2.MAVLink_open_drone_id_location_message(*args), 9, 1), ORIGIN)
    assert r.position_cov is None and r.velocity_ned is None and r.identity == ("system", 9, 1)
    args[9] = args[10] = -1000.0
    rej = traffic.decode_open_drone_id_location(packed(mavlink2.MAVLink_open_drone_id_location_message(*args), 9), ORIGIN)
    assert isinstance(rej, messages.Rejected) and "altitude" in rej.reason


def test_that_ellipsoid_heights_are_brought_to_sea_level_by_the_geoid_separation_and_rejected_without_one():
    """UTM ``alt`` and Remote ID ``altitude_geodetic`` are WGS-84 ellipsoid heights; the origin is AMSL."""
    lat, lon, alt = ned_to_global(0.0, 0.0, -5.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)  # 5 m above home
    utm = packed(mavlink2.MAVLink_utm_global_position_message(
        1, bytes(18), round(lat * 1e7), round(lon * 1e7), round((alt + N) * 1000), 5000, 0, 0, 0, 300, 500, 0,
        0, 0, 0, 10, 3, 1 | 4 | 8), 7)
    odid = packed(mavlink2.MAVLink_open_drone_id_location_message(
        0, 0, bytes(20), 2, 36100, 25500, 6300, round(lat * 1e7), round(lon * 1e7), float(alt), float(alt + N),
        0, 5.0, 12, 6, 0, 0, 10.0, 1), 9)
    for msg in (utm, odid):
        r = traffic.decode_traffic(msg, ORIGIN)
        assert r.position_ned[2] == pytest.approx(-5.0, abs=0.01)  # not 47 m lower, as taken for AMSL it would be
        unknown = traffic.decode_traffic(msg, traffic.GlobalOrigin(ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m))
        assert isinstance(unknown, messages.Rejected) and "geoid separation unknown" in unknown.reason
    only_pressure = packed(mavlink2.MAVLink_open_drone_id_location_message(
        0, 0, bytes(20), 2, 36100, 25500, 6300, round(lat * 1e7), round(lon * 1e7), float(alt), -1000.0,
        0, 5.0, 12, 6, 0, 0, 10.0, 1), 9)
    rej = traffic.decode_traffic(only_pressure, ORIGIN)
    assert isinstance(rej, messages.Rejected) and "geodetic altitude unknown" in rej.reason


@pytest.mark.parametrize("fix, alt_ellipsoid, expected", [(3, 488_000 + 47_300, 47.3), (3, 0, None), (2, 535_300, None),
                                                         (3, 488_000 + 500_000, None)])
def test_that_the_geoid_separation_comes_from_gps_raw_int_only_with_a_3d_fix_and_a_plausible_ellipsoid_height(
        fix, alt_ellipsoid, expected):
    msg = mavlink2.MAVLink_gps_raw_int_message(0, fix, 473977420, 85455940, 488_000, 70, 100, 0, 0, 12, alt_ellipsoid)
    got = traffic.geoid_separation(msg)
    assert got == (None if expected is None else pytest.approx(expected))


def test_that_global_position_int_of_another_vehicle_goes_through_the_origin():
    lat, lon, alt = ned_to_global(7.0, -3.0, -12.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    msg = packed(mavlink2.MAVLink_global_position_int_message(4321, round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
                                                              12000, 100, 200, -30, 0), 5)
    r = traffic.decode_traffic(msg, ORIGIN)
    assert np.allclose(r.position_ned, [7.0, -3.0, -12.0], atol=0.01) and np.allclose(r.velocity_ned, [1.0, 2.0, -0.3])
    assert (r.stamp, r.stamp_unit_s) == (4321, 1e-3)


def test_that_odometry_keeps_its_covariance_and_malformed_traffic_is_rejected_not_raised():
    cov = [0.04, 0, 0, 0, 0, 0, 0.05, 0, 0, 0, 0, 0.06] + [0.0] * 9
    msg = packed(mavlink2.MAVLink_odometry_message(123456, 1, 1, 1.0, 2.0, -3.0, [1, 0, 0, 0], math.nan, math.nan, math.nan,
                                                   0, 0, 0, cov, [math.nan] + [0.0] * 20, 0, 0, 0), 101, 197)
    r = traffic.decode_traffic(msg, None)
    assert np.allclose(np.diag(r.position_cov), [0.04, 0.05, 0.06]) and r.stamp == 123456 and r.velocity_ned is None
    assert traffic.decode_traffic(packed(mavlink2.MAVLink_heartbeat_message(0, 8, 0, 0, 4, 3)), ORIGIN) is None
