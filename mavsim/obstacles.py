"""Scripted obstacles: motion as a function of time, and their MAVLink systems.

Each obstacle moves with a constant velocity or along ``start -> waypoints`` at
``speed_mps`` (stopping at the last waypoint, or looping back to the start with
``loop = true``), after an optional ``start_delay_s``. Positions are closed-form in
time (no integration error). Each obstacle is its own MAVLink system (system id
``obstacle_sysid_base + i``, component ``obstacle_compid``, never 1) sending

- HEARTBEAT at 1 Hz with autopilot MAV_AUTOPILOT_INVALID (8) and type
  MAV_TYPE_GENERIC (0), so autopilot discovery (pymavlink ``wait_heartbeat``
  target selection, MAVSDK, QGroundControl) never takes it for a vehicle, and
- ODOMETRY at ``report_rate_hz`` in LOCAL_NED: true position plus Gaussian noise of
  ``measurement_cov_m2`` (which ``pose_covariance`` reports); velocity only if
  ``velocity_cov_m2ps2`` is given, else NaN with ``velocity_covariance[0]`` NaN.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.scenario import Obstacle
from mavsim.telemetry import odometry_message, upper_triangle_6x6

logger = logging.getLogger(__name__)

__all__ = ["ObstacleTrack", "ObstacleSystem", "noise_factor"]

MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GENERIC = 0
_NAN = float("nan")


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

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """True (position, velocity) at ``t_s``."""
        tau = max(0.0, t_s - self.delay)
        moving = t_s > self.delay
        if self.const_v is not None:
            return self.start + self.const_v * tau, (self.const_v.copy() if moving else np.zeros(3))
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


class ObstacleSystem:
    """One obstacle as a MAVLink system: its track, noise and report schedule."""

    def __init__(self, ob: Obstacle, sysid: int, compid: int, rng: np.random.Generator, index: int) -> None:
        self.config = ob
        self.name = ob.name
        self.radius_m = ob.radius_m
        self.sysid, self.compid = sysid, compid
        self.track = ObstacleTrack(ob)
        self.rng = rng
        self._L = noise_factor(ob.measurement_cov_m2)
        self._Lv = None if ob.velocity_cov_m2ps2 is None else noise_factor(ob.velocity_cov_m2ps2)
        self._pose_cov = upper_triangle_6x6(ob.measurement_cov_m2, _NAN)
        if ob.velocity_cov_m2ps2 is None:
            self._vel_cov = [_NAN] + [0.0] * 20
        else:
            self._vel_cov = upper_triangle_6x6(ob.velocity_cov_m2ps2, _NAN)
        self.report_us = max(1, round(1e6 / ob.report_rate_hz))
        # Phases spread the systems apart and keep the vehicle's HEARTBEAT first at boot.
        self.next_report_us = 1000 * (index + 1)
        self.next_heartbeat_us = 500_000 + 1000 * index

    def due(self, now_us: int) -> list:
        """Messages due at ``now_us`` (call once per simulation step, in time order)."""
        out = []
        if now_us >= self.next_heartbeat_us:
            out.append(mavlink2.MAVLink_heartbeat_message(MAV_TYPE_GENERIC, MAV_AUTOPILOT_INVALID, 0, 0, 4, 3))
            while self.next_heartbeat_us <= now_us:
                self.next_heartbeat_us += 1_000_000
        if now_us >= self.next_report_us:
            p, v = self.track.state(now_us * 1e-6)
            p_meas = p + self._L @ self.rng.standard_normal(3)  # p + L w, w ~ N(0, I)
            if self._Lv is None:
                v_meas = np.full(3, _NAN)
            else:
                v_meas = v + self._Lv @ self.rng.standard_normal(3)
            out.append(odometry_message(now_us, p_meas, v_meas, [1.0, 0.0, 0.0, 0.0], (_NAN, _NAN, _NAN),
                                        self._pose_cov, self._vel_cov, 0))
            while self.next_report_us <= now_us:
                self.next_report_us += self.report_us
        return out
