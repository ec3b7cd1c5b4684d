"""Traffic reports: the messages other aircraft reach the companion with, as Gaussians in local NED.

Pure decoding, like :mod:`companion.mavlink.messages` (whose ODOMETRY and
LOCAL_POSITION_NED decoders are reused). Each decoder returns a
:class:`TrafficReport` or a :class:`~companion.mavlink.messages.Rejected`, never raises.

The Gaussian of each kind (NED metres; None means "unknown: the source's configured
accuracy applies", see :mod:`companion.loop.intake.obstacles`):

==========================  ==================================================================
ODOMETRY                    ``pose_covariance`` / ``velocity_covariance`` x/y/z blocks
LOCAL_POSITION_NED          none in the message: configured accuracy
GLOBAL_POSITION_INT         none in the message: configured accuracy; lat/lon/alt through the
                            autopilot's GPS_GLOBAL_ORIGIN
ADSB_VEHICLE                none in the message: configured accuracy; lat/lon/alt through the
                            origin; only fields whose ADSB_FLAGS validity bit is set are used
                            (no VALID_COORDS or VALID_ALTITUDE: rejected; velocity needs
                            VALID_HEADING and VALID_VELOCITY; vertical velocity needs
                            VERTICAL_VELOCITY_VALID, else 0 with the configured vertical
                            velocity variance)
UTM_GLOBAL_POSITION         ``h_acc``, ``v_acc`` (mm) and ``vel_acc`` (cm/s), which MAVLink
                            defines as standard deviations; fields used per UTM_DATA_AVAIL_FLAGS
OPEN_DRONE_ID_LOCATION      accuracy categories (MAV_ODID_HOR_ACC, _VER_ACC, _SPEED_ACC). ASTM
                            F3411 (and the ADS-B NACp/NACv they come from) define each category
                            as a bound containing the true value with 95 % probability: a
                            horizontal bound R gives sigma = R / 2.448 per axis (95 % of a
                            circular 2-D Gaussian lies within 2.448 sigma), a vertical bound
                            sigma = R / 1.960; the speed bound is taken per horizontal axis as
                            R / 2.448 and vertically as R / 1.960. Category 0 (unknown): configured.
==========================  ==================================================================

Global to local. PX4 maps its local frame to latitude and longitude with an azimuthal
equidistant projection on a sphere of 6,371 km about the local origin (PX4
``lib/geo``). :func:`global_to_ned` is the same projection (the forward map is
``mavsim.geo.ned_to_global``), so a position PX4 re-streams comes back where PX4 had it
(a WGS-84 model would differ by 0.29 %).
Altitudes. NED z = origin altitude - altitude above mean sea level (AMSL).
GPS_GLOBAL_ORIGIN, GLOBAL_POSITION_INT and ADSB_VEHICLE carry AMSL altitudes;
UTM_GLOBAL_POSITION ``alt`` and OPEN_DRONE_ID_LOCATION ``altitude_geodetic`` carry heights
above the WGS-84 ellipsoid (MAVLink: "Altitude (WGS84)"), which exceed AMSL by the geoid
separation N (-106 to +85 m on Earth): AMSL = ellipsoid height - N, with N from
:attr:`GlobalOrigin.geoid_separation_m`. Without it such reports are rejected: taken as
AMSL, traffic at the drone's own altitude would be placed up to a hundred metres away
vertically. A Remote ID report with only a barometric (pressure) altitude is rejected
too: pressure altitude is referenced to 1013.25 hPa, not to sea level.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Hashable, Union

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages

logger = logging.getLogger(__name__)

#: PX4's CONSTANTS_RADIUS_OF_EARTH (lib/geo), metres.
EARTH_RADIUS_M = 6_371_000.0

ADSB_VALID_COORDS = 1
ADSB_VALID_ALTITUDE = 2
ADSB_VALID_HEADING = 4
ADSB_VALID_VELOCITY = 8
ADSB_VERTICAL_VELOCITY_VALID = 128

UTM_POSITION_AVAILABLE = 4
UTM_ALTITUDE_AVAILABLE = 8
UTM_HORIZONTAL_VELO_AVAILABLE = 32
UTM_VERTICAL_VELO_AVAILABLE = 64
UTM_UAS_ID_AVAILABLE = 2

#: 95 % containment radius -> standard deviation per axis (2-D circular, 1-D).
K95_2D = math.sqrt(-2.0 * math.log(0.05))  # 2.4477
K95_1D = 1.959964

#: MAV_ODID_HOR_ACC category -> 95 % horizontal bound, metres (ASTM F3411 table, NM = 1852 m).
ODID_HORIZONTAL_BOUND_M = {1: 18520.0, 2: 7408.0, 3: 3704.0, 4: 1852.0, 5: 926.0, 6: 555.6,
                           7: 185.2, 8: 92.6, 9: 30.0, 10: 10.0, 11: 3.0, 12: 1.0}
#: MAV_ODID_VER_ACC category -> 95 % vertical bound, metres.
ODID_VERTICAL_BOUND_M = {1: 150.0, 2: 45.0, 3: 25.0, 4: 10.0, 5: 3.0, 6: 1.0}
#: MAV_ODID_SPEED_ACC category -> 95 % speed bound, m/s.
ODID_SPEED_BOUND_MPS = {1: 10.0, 2: 3.0, 3: 1.0, 4: 0.3}
ODID_UNKNOWN_DIRECTION = 36100
ODID_UNKNOWN_SPEED_H = 25500
ODID_UNKNOWN_SPEED_V = 6300
ODID_UNKNOWN_ALTITUDE = -1000.0
ODID_UNKNOWN_TIMESTAMP = 0xFFFF

#: ADSB_EMITTER_TYPE -> default body radius, metres (rough half-spans; configurable).
ADSB_EMITTER_RADIUS_M = {1: 6.0, 2: 10.0, 3: 20.0, 4: 30.0, 5: 35.0, 6: 6.0, 7: 8.0, 9: 10.0,
                         10: 15.0, 11: 2.0, 12: 5.0}

#: The kinds this module decodes (message type names).
TRAFFIC_KINDS = ("ODOMETRY", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "ADSB_VEHICLE",
                 "UTM_GLOBAL_POSITION", "OPEN_DRONE_ID_LOCATION")
#: The reason a global report is refused while the autopilot's GPS_GLOBAL_ORIGIN is unknown
#: (the intake counts it as waiting, not as a rejection: the origin is being asked for).
NO_ORIGIN_YET = "no GPS_GLOBAL_ORIGIN yet"
#: Kinds that need the autopilot's GPS_GLOBAL_ORIGIN.
GLOBAL_KINDS = frozenset({"GLOBAL_POSITION_INT", "ADSB_VEHICLE", "UTM_GLOBAL_POSITION", "OPEN_DRONE_ID_LOCATION"})


@dataclass(frozen=True)
class GlobalOrigin:
    """The local frame's origin (GPS_GLOBAL_ORIGIN): degrees and metres AMSL.

    ``geoid_separation_m`` is the geoid's height above the WGS-84 ellipsoid (metres; from
    the autopilot's GPS_RAW_INT ``alt_ellipsoid - alt`` or configured), None while unknown.
    """

    lat_deg: float
    lon_deg: float
    alt_m: float
    geoid_separation_m: float | None = None


@dataclass(frozen=True, eq=False)
class TrafficReport:
    """One report of another aircraft, in the local NED frame.

    Attributes
    ----------
    kind : str
        MAVLink message name.
    identity : hashable
        Who it is, within its link: ``("icao", address)`` for ADSB, ``("uas", id)`` for
        UTM/Remote ID reports carrying an id, else ``("system", sysid, compid)``.
    key : (int, int)
        (system, component) of the sender (for ADSB re-streamed by PX4: PX4's own).
    stamp : int, float or None
        The sender's timestamp in units of ``stamp_unit_s``; None when the message has
        none (ADSB_VEHICLE: its time is arrival minus ``age_s``).
    stamp_unit_s : float
        Seconds per unit of ``stamp``.
    age_s : float
        Seconds between the report's validity and its arrival, when ``stamp`` is None.
    position_ned : ndarray (3,)
        Metres.
    velocity_ned : ndarray (3,) or None
        Metres per second.
    position_cov, velocity_cov : ndarray (3, 3) or None
        m^2 and (m/s)^2; None: unknown, the configured accuracy applies.
    vertical_velocity_unknown : bool
        The velocity is horizontal only (vz set to 0): the configured vertical velocity
        variance applies to its z entry.
    radius_m : float or None
        Body radius the message implies (ADSB emitter type), metres.
    """

    kind: str
    identity: Hashable
    key: messages.Key
    stamp: int | float | None
    stamp_unit_s: float
    age_s: float
    position_ned: np.ndarray
    velocity_ned: np.ndarray | None
    position_cov: np.ndarray | None
    velocity_cov: np.ndarray | None
    vertical_velocity_unknown: bool = False
    radius_m: float | None = None


Decoded = Union[TrafficReport, messages.Rejected]


# --------------------------------------------------------------------------- projection



def _before_origin(msg) -> messages.Rejected:
    """A global report that came before the origin: refused for now, logged quietly (expected at start)."""
    key = messages.source_key(msg)
    logger.debug("%s from system %d component %d before the origin is known", msg.get_type(), key[0], key[1])
    return messages.Rejected(key=key, msg_type=msg.get_type(), reason=NO_ORIGIN_YET)

def global_to_ned(lat_deg: float, lon_deg: float, alt_m: float, origin: GlobalOrigin) -> np.ndarray:
    """Geodetic position to local NED metres about ``origin`` (PX4's azimuthal equidistant map)."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    lat0, lon0 = math.radians(origin.lat_deg), math.radians(origin.lon_deg)
    sin_lat, cos_lat = math.sin(lat), math.cos(lat)
    cos_dlon = math.cos(lon - lon0)
    arg = max(-1.0, min(1.0, math.sin(lat0) * sin_lat + math.cos(lat0) * cos_lat * cos_dlon))
    c = math.acos(arg)
    k = c / math.sin(c) if abs(c) > 0.0 else 1.0
    north = k * (math.cos(lat0) * sin_lat - math.sin(lat0) * cos_lat * cos_dlon) * EARTH_RADIUS_M
    east = k * cos_lat * math.sin(lon - lon0) * EARTH_RADIUS_M
    return np.array([north, east, origin.alt_m - alt_m])


def decode_origin(msg: mavlink2.MAVLink_gps_global_origin_message,
                  geoid_separation_m: float | None = None) -> GlobalOrigin:
    """GPS_GLOBAL_ORIGIN (degE7, mm AMSL) to :class:`GlobalOrigin`."""
    return GlobalOrigin(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3, geoid_separation_m)


def geoid_separation(msg: mavlink2.MAVLink_gps_raw_int_message) -> float | None:
    """Geoid above ellipsoid (m) from GPS_RAW_INT, or None when the receiver gives no ``alt_ellipsoid``.

    ``alt_ellipsoid`` is 0 when not provided; a fix without 3-D (``fix_type`` < 3) carries no altitude.
    """
    if int(msg.fix_type) < 3 or int(msg.alt_ellipsoid) == 0:
        return None
    n = (int(msg.alt_ellipsoid) - int(msg.alt)) * 1e-3
    return n if -120.0 <= n <= 120.0 else None


def _ellipsoid_to_ned(msg, lat_e7: int, lon_e7: int, height_m: float, origin: GlobalOrigin) -> np.ndarray | messages.Rejected:
    """A WGS-84 ellipsoid height to NED through the origin's geoid separation (rejected while unknown)."""
    if origin.geoid_separation_m is None:
        return messages._reject(msg, "geoid separation unknown for an ellipsoid altitude (no GPS_RAW_INT "
                                     "alt_ellipsoid from the autopilot, no [traffic] geoid_separation_m)")
    return global_to_ned(lat_e7 * 1e-7, lon_e7 * 1e-7, height_m - origin.geoid_separation_m, origin)


# --------------------------------------------------------------------------- decoders


def _system(msg) -> tuple:
    key = messages.source_key(msg)
    return ("system", key[0], key[1])


def _from_pose(obs: messages.PoseObservation, msg, stamp: int, unit: float) -> TrafficReport:
    return TrafficReport(obs.source, _system(msg), obs.key, stamp, unit, 0.0, obs.position_ned,
                         obs.velocity_ned, obs.position_cov, obs.velocity_cov)


def decode_odometry(msg, origin: GlobalOrigin | None = None) -> Decoded:
    """ODOMETRY: its pose and velocity covariances (``time_usec``, microseconds)."""
    obs = messages.decode_odometry(msg)
    return obs if isinstance(obs, messages.Rejected) else _from_pose(obs, msg, int(msg.time_usec), 1e-6)


def decode_local_position_ned(msg, origin: GlobalOrigin | None = None) -> Decoded:
    """LOCAL_POSITION_NED of another vehicle sharing the frame (``time_boot_ms``)."""
    obs = messages.decode_local_position_ned(msg)
    return obs if isinstance(obs, messages.Rejected) else _from_pose(obs, msg, int(msg.time_boot_ms), 1e-3)


def decode_global_position_int(msg, origin: GlobalOrigin | None) -> Decoded:
    """GLOBAL_POSITION_INT of another vehicle: lat/lon degE7, alt mm AMSL, v cm/s NED."""
    if origin is None:
        return _before_origin(msg)
    pos = global_to_ned(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3, origin)
    vel = np.array([msg.vx, msg.vy, msg.vz], dtype=float) * 0.01
    return TrafficReport("GLOBAL_POSITION_INT", _system(msg), messages.source_key(msg), int(msg.time_boot_ms),
                         1e-3, 0.0, pos, vel, None, None)


def decode_adsb_vehicle(msg, origin: GlobalOrigin | None) -> Decoded:
    """ADSB_VEHICLE: identity by ICAO address, time = arrival - ``tslc``; flags honoured."""
    if origin is None:
        return _before_origin(msg)
    flags = int(msg.flags)
    if not flags & ADSB_VALID_COORDS:
        return messages._reject(msg, "coordinates not valid (ADSB_FLAGS_VALID_COORDS clear)")
    if not flags & ADSB_VALID_ALTITUDE:
        return messages._reject(msg, "altitude not valid (ADSB_FLAGS_VALID_ALTITUDE clear)")
    pos = global_to_ned(msg.lat * 1e-7, msg.lon * 1e-7, msg.altitude * 1e-3, origin)
    vel, vz_unknown = None, False
    if flags & ADSB_VALID_HEADING and flags & ADSB_VALID_VELOCITY:
        heading = math.radians(msg.heading * 0.01)
        speed = msg.hor_velocity * 0.01
        vz_unknown = not flags & ADSB_VERTICAL_VELOCITY_VALID
        vz = 0.0 if vz_unknown else -msg.ver_velocity * 0.01  # ADSB: up positive
        vel = np.array([speed * math.cos(heading), speed * math.sin(heading), vz])
    radius = ADSB_EMITTER_RADIUS_M.get(int(msg.emitter_type))
    return TrafficReport("ADSB_VEHICLE", ("icao", int(msg.ICAO_address)), messages.source_key(msg), None, 1.0,
                         float(msg.tslc), pos, vel, None, None, vz_unknown, radius)


def _uas_id(raw) -> bytes:
    return bytes(raw) if not isinstance(raw, str) else raw.encode("latin-1")


def decode_utm_global_position(msg, origin: GlobalOrigin | None) -> Decoded:
    """UTM_GLOBAL_POSITION: h_acc, v_acc (mm) and vel_acc (cm/s) as standard deviations."""
    if origin is None:
        return _before_origin(msg)
    flags = int(msg.flags)
    if not flags & UTM_POSITION_AVAILABLE or not flags & UTM_ALTITUDE_AVAILABLE:
        return messages._reject(msg, "position or altitude not available (UTM_DATA_AVAIL_FLAGS)")
    pos = _ellipsoid_to_ned(msg, msg.lat, msg.lon, msg.alt * 1e-3, origin)  # alt: WGS-84 ellipsoid height
    if isinstance(pos, messages.Rejected):
        return pos
    h, v = msg.h_acc * 1e-3, msg.v_acc * 1e-3
    pos_cov = np.diag([h * h, h * h, v * v]) if h > 0 and v > 0 else None
    vel, vel_cov, vz_unknown = None, None, False
    if flags & UTM_HORIZONTAL_VELO_AVAILABLE:
        vz_unknown = not flags & UTM_VERTICAL_VELO_AVAILABLE
        vel = np.array([msg.vx, msg.vy, 0.0 if vz_unknown else msg.vz], dtype=float) * 0.01
        va = msg.vel_acc * 0.01
        vel_cov = va * va * np.eye(3) if va > 0 else None
    uid = _uas_id(msg.uas_id)
    identity = ("uas", uid) if flags & UTM_UAS_ID_AVAILABLE and any(uid) else _system(msg)
    return TrafficReport("UTM_GLOBAL_POSITION", identity, messages.source_key(msg), int(msg.time), 1e-6, 0.0,
                         pos, vel, pos_cov, vel_cov, vz_unknown)


def _odid_std(category: int, bounds: dict, k: float) -> float | None:
    bound = bounds.get(int(category))
    return None if bound is None else bound / k


def decode_open_drone_id_location(msg, origin: GlobalOrigin | None) -> Decoded:
    """OPEN_DRONE_ID_LOCATION: accuracy categories as 95 % bounds (see the module docstring).

    Time: ``timestamp`` is seconds after the full hour (0.1 s resolution); crossing the
    hour is a jump that restarts the source's clock mapping.
    """
    if origin is None:
        return _before_origin(msg)
    if msg.latitude == 0 and msg.longitude == 0:
        return messages._reject(msg, "position unknown (latitude and longitude 0)")
    if not msg.altitude_geodetic > ODID_UNKNOWN_ALTITUDE:  # also NaN
        return messages._reject(msg, "geodetic altitude unknown (-1000; pressure altitude has no sea-level datum)")
    if msg.timestamp >= ODID_UNKNOWN_TIMESTAMP or not math.isfinite(msg.timestamp):
        return messages._reject(msg, "timestamp unknown (0xFFFF)")
    pos = _ellipsoid_to_ned(msg, msg.latitude, msg.longitude, float(msg.altitude_geodetic), origin)
    if isinstance(pos, messages.Rejected):
        return pos
    sh = _odid_std(msg.horizontal_accuracy, ODID_HORIZONTAL_BOUND_M, K95_2D)
    sv = _odid_std(msg.vertical_accuracy, ODID_VERTICAL_BOUND_M, K95_1D)
    pos_cov = np.diag([sh * sh, sh * sh, sv * sv]) if sh is not None and sv is not None else None
    vel, vel_cov, vz_unknown = None, None, False
    if msg.direction < ODID_UNKNOWN_DIRECTION and msg.speed_horizontal < ODID_UNKNOWN_SPEED_H:
        direction = math.radians(msg.direction * 0.01)
        speed = msg.speed_horizontal * 0.01
        vz_unknown = msg.speed_vertical >= ODID_UNKNOWN_SPEED_V
        vz = 0.0 if vz_unknown else -msg.speed_vertical * 0.01  # Remote ID: up positive
        vel = np.array([speed * math.cos(direction), speed * math.sin(direction), vz])
        bound = ODID_SPEED_BOUND_MPS.get(int(msg.speed_accuracy))
        if bound is not None:
            sh_v, sv_v = bound / K95_2D, bound / K95_1D
            vel_cov = np.diag([sh_v * sh_v, sh_v * sh_v, sv_v * sv_v])
    uid = _uas_id(msg.id_or_mac)
    identity = ("uas", uid) if any(uid) else _system(msg)
    return TrafficReport("OPEN_DRONE_ID_LOCATION", identity, messages.source_key(msg), float(msg.timestamp), 1.0,
                         0.0, pos, vel, pos_cov, vel_cov, vz_unknown)


_DECODERS = {
    "ODOMETRY": decode_odometry,
    "LOCAL_POSITION_NED": decode_local_position_ned,
    "GLOBAL_POSITION_INT": decode_global_position_int,
    "ADSB_VEHICLE": decode_adsb_vehicle,
    "UTM_GLOBAL_POSITION": decode_utm_global_position,
    "OPEN_DRONE_ID_LOCATION": decode_open_drone_id_location,
}


def decode_traffic(msg, origin: GlobalOrigin | None) -> Decoded | None:
    """Decode one traffic message; None if it is not a traffic kind. Never raises."""
    handler = _DECODERS.get(msg.get_type())
    if handler is None:
        return None
    try:
        return handler(msg, origin)
    except Exception as exc:  # malformed content must never stop the loop
        return messages._reject(msg, f"malformed: {type(exc).__name__}: {exc}")
