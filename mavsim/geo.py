"""PX4's local-to-global map: azimuthal equidistant projection on a 6,371 km sphere (PX4 ``lib/geo``).

PX4 turns local NED positions into latitude and longitude (and back) with this projection
about the local origin (GPS_GLOBAL_ORIGIN), so traffic it re-streams as ADSB_VEHICLE carries
coordinates made this way. mavsim uses the same map for the ADSB, UTM and Remote ID reports
of its obstacles. Altitudes are AMSL metres: alt = origin altitude - z.
"""

from __future__ import annotations

import math

__all__ = ["EARTH_RADIUS_M", "ned_to_global", "global_to_ned"]

#: PX4's CONSTANTS_RADIUS_OF_EARTH, metres.
EARTH_RADIUS_M = 6_371_000.0


def ned_to_global(north_m: float, east_m: float, down_m: float, lat0_deg: float, lon0_deg: float,
                  alt0_m: float) -> tuple[float, float, float]:
    """(lat deg, lon deg, alt m AMSL) of a local NED position about the origin (lat0, lon0, alt0)."""
    x, y = north_m / EARTH_RADIUS_M, east_m / EARTH_RADIUS_M
    lat0, lon0 = math.radians(lat0_deg), math.radians(lon0_deg)
    c = math.hypot(x, y)
    if c > 0.0:
        sin_c, cos_c = math.sin(c), math.cos(c)
        lat = math.asin(cos_c * math.sin(lat0) + x * sin_c * math.cos(lat0) / c)
        lon = lon0 + math.atan2(y * sin_c, c * math.cos(lat0) * cos_c - x * math.sin(lat0) * sin_c)
    else:
        lat, lon = lat0, lon0
    return math.degrees(lat), math.degrees(lon), alt0_m - down_m


def global_to_ned(lat_deg: float, lon_deg: float, alt_m: float, lat0_deg: float, lon0_deg: float,
                  alt0_m: float) -> tuple[float, float, float]:
    """Local NED metres of (lat deg, lon deg, alt m AMSL) about the origin: the inverse of
    :func:`ned_to_global` (PX4's ``map_projection_project``)."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    lat0, lon0 = math.radians(lat0_deg), math.radians(lon0_deg)
    cos_dlon = math.cos(lon - lon0)
    arg = max(-1.0, min(1.0, math.sin(lat0) * math.sin(lat) + math.cos(lat0) * math.cos(lat) * cos_dlon))
    c = math.acos(arg)
    k = c / math.sin(c) if abs(c) > 0.0 else 1.0
    north = k * (math.cos(lat0) * math.sin(lat) - math.sin(lat0) * math.cos(lat) * cos_dlon) * EARTH_RADIUS_M
    east = k * math.cos(lat) * math.sin(lon - lon0) * EARTH_RADIUS_M
    return north, east, alt0_m - alt_m
