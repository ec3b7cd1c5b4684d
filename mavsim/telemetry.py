"""Telemetry: the messages the autopilot streams, built from simulated state.

Which streams it sends and at what rates is its personality's
(:attr:`mavsim.personalities.base.Personality.stream_rates_hz`, PX4's defaults on the
offboard link for PX4), as are the HEARTBEAT's identity and mode fields; a client
changes rates per link with MAV_CMD_SET_MESSAGE_INTERVAL. Timestamps are simulated
time since boot (``time_boot_ms`` ms, ``time_usec`` us). Reported positions and
velocities are the noisy estimate; ODOMETRY carries the noise covariance itself
(position block of ``pose_covariance`` and velocity block of ``velocity_covariance``,
row-major upper triangle of 6x6: x, y, z variances at indices 0, 6, 11; the full 3x3
block is filled, so off-diagonal noise terms are reported too).
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.personalities.base import Commander, Personality
from mavsim.vehicle import VehicleState

logger = logging.getLogger(__name__)

__all__ = ["STREAM_IDS", "TelemetryBuilder", "odometry_message", "upper_triangle_6x6"]

#: Stream name -> MAVLink message id.
STREAM_IDS: dict[str, int] = {
    "HEARTBEAT": 0, "SYS_STATUS": 1, "ATTITUDE": 30, "LOCAL_POSITION_NED": 32, "GLOBAL_POSITION_INT": 33,
    "HOME_POSITION": 242, "EXTENDED_SYS_STATE": 245, "ODOMETRY": 331, "GPS_RAW_INT": 24,
    "TIMESYNC": 111, "GPS_GLOBAL_ORIGIN": 49, "POSITION_TARGET_LOCAL_NED": 85, "EKF_STATUS_REPORT": 193,
    "MISSION_CURRENT": 42,
}
MSG_AUTOPILOT_VERSION = 148

EARTH_RADIUS_M = 6378137.0
# gyro | accel | mag | abs pressure | GPS | angular rate ctl | attitude ctl | yaw pos | z/alt ctl | xy ctl | motors
_SENSORS = 0x1 | 0x2 | 0x4 | 0x8 | 0x20 | 0x400 | 0x800 | 0x1000 | 0x2000 | 0x4000 | 0x8000
_PREARM = 0x10000000
# MAV_PROTOCOL_CAPABILITY: MISSION_FLOAT 1, PARAM_FLOAT 2, MISSION_INT 4, COMMAND_INT 8,
# SET_POSITION_TARGET_LOCAL_NED 128, SET_POSITION_TARGET_GLOBAL_INT 256, MAVLINK2 8192
_CAPABILITIES = 1 | 2 | 4 | 8 | 128 | 8192


def upper_triangle_6x6(block3: np.ndarray, rest: float = 0.0) -> list[float]:
    """21 floats of a 6x6 row-major upper triangle with ``block3`` in the top-left 3x3.

    ``rest`` fills the diagonal of the lower-right block (e.g. NaN for unknown attitude).
    """
    m = np.zeros((6, 6))
    m[:3, :3] = block3
    m[3, 3] = m[4, 4] = m[5, 5] = rest
    return [float(m[i, j]) for i in range(6) for j in range(i, 6)]


def _yaw_quat(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]


def odometry_message(time_us: int, pos: np.ndarray, vel: np.ndarray, q: list[float],
                     rates: tuple[float, float, float], pose_cov: list[float], vel_cov: list[float],
                     estimator_type: int, reset_counter: int = 0) -> mavlink2.MAVLink_odometry_message:
    """ODOMETRY in LOCAL_NED (frame_id = child_frame_id = 1), velocity in NED."""
    return mavlink2.MAVLink_odometry_message(
        time_us, 1, 1, float(pos[0]), float(pos[1]), float(pos[2]), q,
        float(vel[0]), float(vel[1]), float(vel[2]), rates[0], rates[1], rates[2],
        pose_cov, vel_cov, int(reset_counter), estimator_type, 100)


class TelemetryBuilder:
    """Builds the autopilot's telemetry messages.

    Parameters
    ----------
    position_cov_m2, velocity_cov_m2ps2 : ndarray (3, 3)
        Noise covariances of the reported estimate (reported in ODOMETRY).
    home_lat_deg, home_lon_deg, home_alt_m : float
        Geodetic position of the local origin (NED (0, 0, 0), on the ground); altitude AMSL.
    geoid_separation_m : float
        Height of the geoid above the WGS-84 ellipsoid, metres: GPS_RAW_INT reports
        ``alt_ellipsoid = alt + geoid_separation_m`` as a GNSS receiver does.
    personality : Personality
        The autopilot: HEARTBEAT type and autopilot, AUTOPILOT_VERSION's version and ids.
    """

    def __init__(self, position_cov_m2: np.ndarray, velocity_cov_m2ps2: np.ndarray,
                 home_lat_deg: float, home_lon_deg: float, home_alt_m: float,
                 geoid_separation_m: float, personality: Personality) -> None:
        self.personality = personality
        self._pose_cov = upper_triangle_6x6(position_cov_m2, 1e-4)
        self._vel_cov = upper_triangle_6x6(velocity_cov_m2ps2, 1e-4)
        self.home = (home_lat_deg, home_lon_deg, home_alt_m)
        self._cos_lat = math.cos(math.radians(home_lat_deg))
        self.geoid_separation_m = float(geoid_separation_m)
        #: ODOMETRY's reset_counter: the estimator's resets so far (set by the simulator, ``[sim] estimator_resets``
        #: and the ends of ``gps_outages``)
        self.reset_counter = 0
        #: whether the GPS has a fix (False in a ``[sim] gps_outages`` outage: GPS_RAW_INT shows none)
        self.gps_fix = True
        #: variance added to ODOMETRY's reported x and y (m^2): the growth of a dead-reckoned estimate
        self.extra_horizontal_var_m2 = 0.0
        #: a degraded GPS's extra horizontal standard deviation (m; ``[sim] gps_degradations``), in GPS_RAW_INT's h_acc
        self.gps_degraded_sd_m = 0.0

    def _pose_cov_now(self) -> list[float]:
        """ODOMETRY's pose covariance: the noise's, plus a dead-reckoning outage's growth in x and y."""
        if self.extra_horizontal_var_m2 <= 0.0:
            return self._pose_cov
        cov = list(self._pose_cov)
        cov[0] += self.extra_horizontal_var_m2   # x (row-major upper triangle of 6x6: x 0, y 6, z 11)
        cov[6] += self.extra_horizontal_var_m2
        return cov

    def global_from_local(self, p: np.ndarray) -> tuple[int, int, int]:
        """(lat degE7, lon degE7, alt mm AMSL) of a local NED point (flat earth)."""
        lat = self.home[0] + math.degrees(p[0] / EARTH_RADIUS_M)
        lon = self.home[1] + math.degrees(p[1] / (EARTH_RADIUS_M * self._cos_lat))
        return round(lat * 1e7), round(lon * 1e7), round((self.home[2] - p[2]) * 1000)

    def build(self, msg_id: int, now_us: int, cmdr: Commander, veh: VehicleState,
              est_pos: np.ndarray, est_vel: np.ndarray):
        """The message with id ``msg_id`` at simulated time ``now_us``, or None if unknown."""
        ms = now_us // 1000
        own = cmdr.message(msg_id, now_us, veh, est_pos, est_vel)
        if own is not None:
            return own
        if msg_id == 0:
            p = self.personality
            return mavlink2.MAVLink_heartbeat_message(
                p.mav_type, p.mav_autopilot, cmdr.base_mode, cmdr.custom_mode, cmdr.system_status, 3)
        if msg_id == 32:
            return mavlink2.MAVLink_local_position_ned_message(
                ms, float(est_pos[0]), float(est_pos[1]), float(est_pos[2]),
                float(est_vel[0]), float(est_vel[1]), float(est_vel[2]))
        if msg_id == 331:
            roll, pitch = veh.roll_pitch_rad
            return odometry_message(now_us, est_pos, est_vel, _yaw_quat(roll, pitch, veh.yaw_rad),
                                    (0.0, 0.0, veh.yaw_rate_radps), self._pose_cov_now(), self._vel_cov, 8,
                                    self.reset_counter)
        if msg_id == 30:
            roll, pitch = veh.roll_pitch_rad
            return mavlink2.MAVLink_attitude_message(ms, roll, pitch, veh.yaw_rad, 0.0, 0.0, veh.yaw_rate_radps)
        if msg_id == 33:
            lat, lon, alt = self.global_from_local(est_pos)
            hdg = round(math.degrees(veh.yaw_rad) % 360.0 * 100) % 36000
            return mavlink2.MAVLink_global_position_int_message(
                ms, lat, lon, alt, round(-est_pos[2] * 1000), *(int(round(x * 100)) for x in est_vel), hdg)
        if msg_id == 24:
            lat, lon, alt = self.global_from_local(est_pos)
            speed = math.hypot(float(est_vel[0]), float(est_vel[1]))
            cog = round(math.degrees(math.atan2(est_vel[1], est_vel[0])) % 360.0 * 100) % 36000
            if not self.gps_fix:   # an outage: no fix, nothing measured (unknown: UINT16_MAX)
                return mavlink2.MAVLink_gps_raw_int_message(now_us, 1, 0, 0, 0, 65535, 65535, 65535, 65535, 0)
            return mavlink2.MAVLink_gps_raw_int_message(
                now_us, 3, lat, lon, alt, 70, 100, round(speed * 100), cog, 12,
                alt + round(self.geoid_separation_m * 1000), round(1000 * math.hypot(0.7, self.gps_degraded_sd_m)),
                1000, 200, 0, 0)
        if msg_id == 1:
            health = _SENSORS | _PREARM
            return mavlink2.MAVLink_sys_status_message(health, health, health, 150, 16200, 500, 90,
                                                       0, 0, 0, 0, 0, 0)
        if msg_id == 245:
            return mavlink2.MAVLink_extended_sys_state_message(0, cmdr.landed_state(veh))
        if msg_id == 242:
            lat, lon, alt = self.global_from_local(np.zeros(3))
            return mavlink2.MAVLink_home_position_message(lat, lon, alt, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                                          0.0, 0.0, 0.0, now_us)
        if msg_id == 111:
            return mavlink2.MAVLink_timesync_message(0, now_us * 1000)
        if msg_id == 49:
            lat, lon, alt = self.home
            return mavlink2.MAVLink_gps_global_origin_message(round(lat * 1e7), round(lon * 1e7), round(alt * 1000), now_us)
        if msg_id == MSG_AUTOPILOT_VERSION:
            p = self.personality
            return mavlink2.MAVLink_autopilot_version_message(
                _CAPABILITIES, p.flight_sw_version, 0, 0, 0,
                [0] * 8, [0] * 8, [0] * 8, p.vendor_id, p.product_id, 1, [0] * 18)
        return None
