"""Scripted obstacles: motion as a function of time, and their MAVLink systems.

Each obstacle moves with a constant velocity or along ``start -> waypoints`` at
``speed_mps`` (stopping at the last waypoint, or looping back to the start with
``loop = true``), after an optional ``start_delay_s``. Positions are closed-form in
time (no integration error). Each obstacle is its own MAVLink system (system id
``obstacle_sysid_base + i``, component ``obstacle_compid``, never 1) sending

- HEARTBEAT at 1 Hz with autopilot MAV_AUTOPILOT_INVALID (8) and type
  MAV_TYPE_GENERIC (0), so autopilot discovery (pymavlink ``wait_heartbeat``
  target selection, MAVSDK, QGroundControl) never takes it for a vehicle, and
- reports at ``report_rate_hz``: true position plus Gaussian noise of
  ``measurement_cov_m2``, white or, with ``measurement_correlation_s`` > 0, Gauss-Markov
  with that correlation time and the same covariance at every report (:mod:`mavsim.noise`;
  what a tracker's or a GNSS receiver's error does), so the covariance reported stays the
  error's true covariance either way; velocity (true plus noise of ``velocity_cov_m2ps2``) only if
  that is given. How they travel depends on ``transport`` (see :mod:`mavsim.scenario`):

  ``"link"``   the obstacle's own system on the obstacle link, as ``message``: ODOMETRY
               (``pose_covariance`` reports the noise), LOCAL_POSITION_NED,
               UTM_GLOBAL_POSITION (``h_acc``/``v_acc``/``vel_acc`` = the noise's standard
               deviations) or OPEN_DRONE_ID_LOCATION (the smallest accuracy category whose
               95 % bound covers the noise);
  ``"adsb"``   ADSB_VEHICLE re-streamed by the autopilot under its own system id on every
               vehicle link (lat/lon truncated to degE7, no VERTICAL_VELOCITY_VALID, as PX4),
               plus the original packet under the obstacle's id on the API link;
  ``"api"``    ODOMETRY on the API link (the old same-socket way).

  Stamps come from the sender's own clock: ``clock_offset_s + (1 + clock_drift) t``.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.geo import ned_to_global
from mavsim.noise import GaussMarkovError
from mavsim.scenario import Obstacle
from mavsim.telemetry import odometry_message, upper_triangle_6x6

logger = logging.getLogger(__name__)

__all__ = ["ObstacleTrack", "ObstacleSystem", "noise_factor"]

MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GENERIC = 0
_NAN = float("nan")
#: Routes of an obstacle's messages: its own id on the obstacle link or on the API link, or
#: the autopilot's id on every vehicle link (ADSB re-stream).
OWN_OBSTACLE_LINK, OWN_API_LINK, AUTOPILOT_ALL_LINKS = "own_obstacle", "own_api", "autopilot_all"
_UTC_AT_BOOT_S = 1_767_226_200.0  # 2026-01-01T00:10:00Z: UTM (Unix us) and Remote ID (s after the hour) stamps
_K95_2D, _K95_1D = 2.4477, 1.96
_ODID_HOR_BOUNDS = ((12, 1.0), (11, 3.0), (10, 10.0), (9, 30.0), (8, 92.6))
_ODID_VER_BOUNDS = ((6, 1.0), (5, 3.0), (4, 10.0), (3, 25.0), (2, 45.0))
_ODID_SPEED_BOUNDS = ((4, 0.3), (3, 1.0), (2, 3.0), (1, 10.0))


def noise_factor(cov: np.ndarray) -> np.ndarray:
    """A matrix L with L L^T = cov (cov symmetric positive semi-definite)."""
    w, v = np.linalg.eigh(cov)
    return v * np.sqrt(np.clip(w, 0.0, None))


class ObstacleTrack:
    """Closed-form motion of one obstacle (NED metres, seconds)."""

    def __init__(self, ob: Obstacle) -> None:
        self.delay = ob.start_delay_s
        self.start = ob.start_ned_m.astype(float)
        self.const_v = ob.velocity_ned_mps
        if ob.waypoints_ned_m is not None:
            pts = np.vstack([self.start, ob.waypoints_ned_m])
            if ob.loop:
                pts = np.vstack([pts, self.start])
            seg = np.diff(pts, axis=0)
            length = np.linalg.norm(seg, axis=1)
            keep = length > 1e-9
            self.pts, self.seg, self.length = pts[np.r_[True, keep]], seg[keep], length[keep]
            self.cum = np.r_[0.0, np.cumsum(self.length)]
            self.speed = ob.speed_mps
            self.loop = ob.loop

    def position(self, t_s: float) -> np.ndarray:
        """True position at ``t_s`` (NED, m): :meth:`state`'s first part, without the velocity
        (the truth recorder asks at every physics step)."""
        if self.const_v is not None:
            return self.start + self.const_v * max(0.0, t_s - self.delay)
        return self.state(t_s)[0]

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """True (position, velocity) at ``t_s``."""
        tau = max(0.0, t_s - self.delay)
        moving = t_s > self.delay
        if self.const_v is not None:
            return self.position(t_s), (self.const_v.copy() if moving else np.zeros(3))
        total = self.cum[-1]
        if total <= 0.0:
            return self.start.copy(), np.zeros(3)
        s = self.speed * tau
        if self.loop:
            s = math.fmod(s, total)
        elif s >= total:
            return self.pts[-1].copy(), np.zeros(3)
        i = min(int(np.searchsorted(self.cum, s, side="right")) - 1, len(self.length) - 1)
        u = self.seg[i] / self.length[i]
        return self.pts[i] + u * (s - self.cum[i]), (u * self.speed if moving else np.zeros(3))


def _category(std: float, k95: float, table) -> int:
    """The smallest accuracy category whose 95 % bound covers ``k95 * std`` (0: unknown)."""
    for code, bound in table:
        if k95 * std <= bound:
            return code
    return 0


class ObstacleSystem:
    """One obstacle as a MAVLink sender: its track, noise, clock and report schedule.

    Parameters
    ----------
    ob : Obstacle
    sysid, compid : its MAVLink identity.
    rng : its own noise generator.
    index : its position in the scenario (spreads the report phases).
    origin : (lat deg, lon deg, alt m AMSL) of the local frame, for global reports.
    geoid_separation_m : geoid height above the WGS-84 ellipsoid (m): the messages whose
        altitude MAVLink defines as WGS-84 ellipsoid height (UTM_GLOBAL_POSITION ``alt``,
        OPEN_DRONE_ID_LOCATION ``altitude_geodetic``) carry AMSL + this.
    """

    def __init__(self, ob: Obstacle, sysid: int, compid: int, rng: np.random.Generator, index: int,
                 origin: tuple[float, float, float] = (47.397742, 8.545594, 488.0),
                 geoid_separation_m: float = 0.0) -> None:
        self.config = ob
        self.name = ob.name
        self.radius_m = ob.radius_m
        self.sysid, self.compid = sysid, compid
        self.transport, self.message = ob.transport, ob.message
        self.icao = ob.icao_address if ob.icao_address is not None else 0xA00000 + sysid
        self.origin = origin
        #: where the frame of local reports (ODOMETRY, LOCAL_POSITION_NED) lies in the obstacle's
        #: frame (NED m): the receiver's frame when its origin is not the scenario's (a fleet)
        self.local_offset_m = np.zeros(3)
        self.geoid_separation_m = float(geoid_separation_m)
        self.track = ObstacleTrack(ob)
        self.rng = rng
        self._position_error = GaussMarkovError(noise_factor(ob.measurement_cov_m2), ob.measurement_correlation_s)
        self._Lv = None if ob.velocity_cov_m2ps2 is None else noise_factor(ob.velocity_cov_m2ps2)
        self._pose_cov = upper_triangle_6x6(ob.measurement_cov_m2, _NAN)
        if ob.velocity_cov_m2ps2 is None:
            self._vel_cov = [_NAN] + [0.0] * 20
        else:
            self._vel_cov = upper_triangle_6x6(ob.velocity_cov_m2ps2, _NAN)
        var = np.diag(ob.measurement_cov_m2)
        self._h_std, self._v_std = math.sqrt(max(var[0], var[1])), math.sqrt(var[2])
        self._vel_std = None if ob.velocity_cov_m2ps2 is None else math.sqrt(float(np.max(np.diag(ob.velocity_cov_m2ps2))))
        self.report_us = max(1, round(1e6 / ob.report_rate_hz))
        # Phases spread the systems apart and keep the vehicle's HEARTBEAT first at boot.
        self.next_report_us = 1000 * (index + 1)
        self.next_heartbeat_us = 500_000 + 1000 * index
        self._garbage_sent = False

    def clock_s(self, now_us: int) -> float:
        """The sender's own clock at simulated time ``now_us`` (seconds; may be negative)."""
        t, cfg = now_us * 1e-6, self.config
        if cfg.clock_reboot_at_s is not None and t >= cfg.clock_reboot_at_s:
            return (1.0 + cfg.clock_drift) * (t - cfg.clock_reboot_at_s)  # rebooted: a boot clock from 0
        return cfg.clock_offset_s + (1.0 + cfg.clock_drift) * t

    def _garbage_due(self, now_us: int) -> bool:
        at = self.config.garbage_stamp_at_s
        if at is None or self._garbage_sent or now_us * 1e-6 < at:
            return False
        self._garbage_sent = True
        return True

    def due(self, now_us: int, motion_s: float | None = None) -> list[tuple[str, object]]:
        """(route, message) pairs due at ``now_us`` (call once per step, in time order).

        ``motion_s``: the time (s) on the obstacle's scripted track, when its motion does not
        start at boot (mavsim's ``--obstacles-start offboard``, the traffic player); default
        ``now_us`` in seconds. The report schedule and the stamps keep ``now_us``."""
        if now_us < self.next_heartbeat_us and now_us < self.next_report_us:    # most physics steps
            return []
        out: list[tuple[str, object]] = []
        own = OWN_OBSTACLE_LINK if self.transport == "link" else OWN_API_LINK
        if now_us >= self.next_heartbeat_us:
            if self.transport != "adsb":  # PX4 does not forward other systems' heartbeats
                out.append((own, mavlink2.MAVLink_heartbeat_message(MAV_TYPE_GENERIC, MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)))
            while self.next_heartbeat_us <= now_us:
                self.next_heartbeat_us += 1_000_000
        if now_us >= self.next_report_us:
            p, v = self.track.state(now_us * 1e-6 if motion_s is None else motion_s)
            p_meas = p + self._position_error.sample(now_us, self.rng.standard_normal(3))  # white: p + L w, w ~ N(0, I)
            v_meas = np.full(3, _NAN) if self._Lv is None else v + self._Lv @ self.rng.standard_normal(3)
            out.extend(self._reports(now_us, p_meas, v_meas, own))
            while self.next_report_us <= now_us:
                self.next_report_us += self.report_us
        return out

    def _reports(self, now_us: int, p: np.ndarray, v: np.ndarray, own: str) -> list[tuple[str, object]]:
        clock = self.clock_s(now_us)
        if self.transport == "adsb":
            return [(AUTOPILOT_ALL_LINKS, self._adsb(p, v, truncate=True)), (OWN_API_LINK, self._adsb(p, v, truncate=False))]
        garbage = self.message in ("ODOMETRY", "LOCAL_POSITION_NED") and self._garbage_due(now_us)
        if self.message in ("ODOMETRY", "LOCAL_POSITION_NED"):
            p = p - self.local_offset_m
        if self.message == "ODOMETRY":
            stamp = 0xFFFFFFFF if garbage else round(clock * 1e6) % (1 << 64)
            return [(own, odometry_message(stamp, p, v, [1.0, 0.0, 0.0, 0.0], (_NAN, _NAN, _NAN),
                                           self._pose_cov, self._vel_cov, 0))]
        if self.message == "LOCAL_POSITION_NED":
            stamp = 0xFFFFFFFF if garbage else round(clock * 1e3) % (1 << 32)
            return [(own, mavlink2.MAVLink_local_position_ned_message(stamp, *map(float, p), *map(float, v)))]
        lat, lon, alt = ned_to_global(float(p[0]), float(p[1]), float(p[2]), *self.origin)
        if self.message == "UTM_GLOBAL_POSITION":
            return [(own, self._utm(clock, lat, lon, alt, v))]
        return [(own, self._remote_id(clock, lat, lon, alt, v))]

    def _adsb(self, p: np.ndarray, v: np.ndarray, *, truncate: bool):
        lat, lon, alt = ned_to_global(float(p[0]), float(p[1]), float(p[2]), *self.origin)
        to_int = int if truncate else round  # PX4 truncates what it re-streams (about 1 cm)
        flags = 1 | 2  # VALID_COORDS, VALID_ALTITUDE
        heading = speed = climb = 0
        if np.all(np.isfinite(v)):
            flags |= 4 | 8  # VALID_HEADING, VALID_VELOCITY (PX4 strips VERTICAL_VELOCITY_VALID)
            heading = round(math.degrees(math.atan2(v[1], v[0])) * 100) % 36000
            speed, climb = round(math.hypot(v[0], v[1]) * 100), round(-v[2] * 100)
            if not truncate:
                flags |= 128
        return mavlink2.MAVLink_adsb_vehicle_message(
            self.icao, to_int(lat * 1e7), to_int(lon * 1e7), 1, round(alt * 1000), heading, speed, climb,
            f"OB{self.sysid}".encode(), self.config.emitter_type, 0, flags, 0)

    def _utm(self, clock: float, lat: float, lon: float, alt: float, v: np.ndarray):
        flags = 1 | 4 | 8  # TIME_VALID, POSITION_AVAILABLE, ALTITUDE_AVAILABLE
        vel = [0, 0, 0]
        vel_acc = 0
        if np.all(np.isfinite(v)):
            flags |= 32 | 64
            vel = [round(float(x) * 100) for x in v]
            vel_acc = max(1, round((self._vel_std or 0.0) * 100))
        time_us = round((_UTC_AT_BOOT_S + clock) * 1e6) % (1 << 64)
        return mavlink2.MAVLink_utm_global_position_message(
            time_us, bytes(18), round(lat * 1e7), round(lon * 1e7), round((alt + self.geoid_separation_m) * 1000),
            round(alt * 1000) - round(self.origin[2] * 1000),
            *vel, max(1, round(self._h_std * 1000)), max(1, round(self._v_std * 1000)), vel_acc,
            0, 0, 0, 10, 3, flags)

    def _remote_id(self, clock: float, lat: float, lon: float, alt: float, v: np.ndarray):
        direction, speed_h, speed_v, speed_acc = 36100, 25500, 6300, 0
        if np.all(np.isfinite(v)):
            direction = round(math.degrees(math.atan2(v[1], v[0])) * 100) % 36000
            speed_h, speed_v = round(math.hypot(v[0], v[1]) * 100), round(-v[2] * 100)
            speed_acc = _category(self._vel_std or 0.0, _K95_2D, _ODID_SPEED_BOUNDS)
        seconds_after_hour = round((_UTC_AT_BOOT_S + clock) % 3600.0, 1)
        uas_id = f"OB{self.sysid:03d}".encode().ljust(20, b"\0")
        return mavlink2.MAVLink_open_drone_id_location_message(
            0, 0, uas_id, 2, direction, speed_h, speed_v, round(lat * 1e7), round(lon * 1e7),
            float(alt), float(alt + self.geoid_separation_m), 0, float(alt - self.origin[2]),
            _category(self._h_std, _K95_2D, _ODID_HOR_BOUNDS), _category(self._v_std, _K95_1D, _ODID_VER_BOUNDS),
            0, speed_acc, seconds_after_hour, 1)
