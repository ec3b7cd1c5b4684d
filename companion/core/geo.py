"""Geodetic positions to the autopilot's local frame and back: PX4's azimuthal equidistant map.

PX4 places latitude and longitude in its local frame with an azimuthal equidistant
projection on a sphere of radius 6,371 km about the local origin (its ``MapProjection``,
``lib/geo``; MathWorld's "Azimuthal Equidistant Projection"): the distance and bearing
from the origin are kept exactly on the sphere. :func:`project` is its forward map
(``project``: geodetic to north/east metres), :func:`reproject` the inverse. Altitudes are
not part of the map: local down is the origin's altitude less the point's (AMSL).

Pure: no clock, no I/O, floats in and out (degrees, metres).
"""

from __future__ import annotations

import math

__all__ = ["EARTH_RADIUS_M", "project", "reproject"]

#: PX4's CONSTANTS_RADIUS_OF_EARTH, metres.
EARTH_RADIUS_M = 6_371_000.0


def project(lat_deg: float, lon_deg: float, lat0_deg: float, lon0_deg: float) -> tuple[float, float]:
    """(north m, east m) of (lat, lon) about the origin (lat0, lon0), degrees in.

    The angular distance ``c`` from the origin comes from the spherical law of cosines
    (its cosine clamped to [-1, 1] against rounding); north and east are the unit
    direction to the point scaled by ``c / sin c`` (1 at the origin) and the radius.
    """
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    lat0, lon0 = math.radians(lat0_deg), math.radians(lon0_deg)
    sin_lat, cos_lat = math.sin(lat), math.cos(lat)
    sin_lat0, cos_lat0 = math.sin(lat0), math.cos(lat0)
    cos_dlon = math.cos(lon - lon0)
    cos_c = min(1.0, max(-1.0, sin_lat0 * sin_lat + cos_lat0 * cos_lat * cos_dlon))
    c = math.acos(cos_c)
    scale = c / math.sin(c) if c != 0.0 else 1.0
    north = scale * (cos_lat0 * sin_lat - sin_lat0 * cos_lat * cos_dlon) * EARTH_RADIUS_M
    east = scale * cos_lat * math.sin(lon - lon0) * EARTH_RADIUS_M
    return north, east


def reproject(north_m: float, east_m: float, lat0_deg: float, lon0_deg: float) -> tuple[float, float]:
    """(lat deg, lon deg) of the local point (north, east) about the origin: the inverse of :func:`project`."""
    x, y = north_m / EARTH_RADIUS_M, east_m / EARTH_RADIUS_M
    lat0, lon0 = math.radians(lat0_deg), math.radians(lon0_deg)
    c = math.hypot(x, y)
    if c == 0.0:
        return lat0_deg, lon0_deg
    sin_c, cos_c = math.sin(c), math.cos(c)
    lat = math.asin(cos_c * math.sin(lat0) + x * sin_c * math.cos(lat0) / c)
    lon = lon0 + math.atan2(y * sin_c, c * math.cos(lat0) * cos_c - x * math.sin(lat0) * sin_c)
    return math.degrees(lat), math.degrees(lon)
