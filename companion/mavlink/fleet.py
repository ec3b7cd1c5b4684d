"""A fleet's announcements in standard MAVLink: a vehicle's state (ODOMETRY) and its intent
(TRAJECTORY_REPRESENTATION_WAYPOINTS).

State. ODOMETRY in LOCAL_NED (``frame_id`` 1, velocity in the same frame, ``child_frame_id``
1), ``time_usec`` the sender's clock in microseconds, the position and velocity covariances
in the x/y/z blocks of ``pose_covariance`` / ``velocity_covariance`` (row-major upper
triangles of 6x6 matrices; the attitude blocks NaN: unknown). Received, it is any other
ODOMETRY traffic report (:func:`companion.mavlink.traffic.decode_odometry`).

Intent. TRAJECTORY_REPRESENTATION_WAYPOINTS with up to five points: point k is the plan's
position (``pos_x/y/z``, NED m) and velocity (``vel_x/y/z``, m/s) at ``time_usec + k *
spacing`` with the fleet's knot spacing (``[fleet] intent_knot_spacing_s``; the message
has no per-point time). Accelerations and yaw are NaN and ``command`` UINT16_MAX (unused,
as the message defines them). ``valid_points`` 0 withdraws an intent (the sender has no
plan in force).

Pure: the encoders build messages (the link packs them under its own system and
component id); decoding never raises and returns :class:`IntentReport` or
:class:`~companion.mavlink.messages.Rejected`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages

__all__ = ["IntentReport", "encode_state", "encode_intent", "decode_intent", "MAX_POINTS"]

MAX_POINTS = 5
_NAN5 = [math.nan] * MAX_POINTS
_UNUSED_COMMANDS = [65535] * MAX_POINTS
#: An intent further than this from the origin is garbage, not a plan (m).
MAX_INTENT_RANGE_M = 1.0e6
#: A planned speed above this is garbage (m/s).
MAX_INTENT_SPEED_MPS = 1.0e3


@dataclass(frozen=True)
class IntentReport:
    """One decoded intent.

    Attributes
    ----------
    key : (system id, component id) of the sender.
    stamp : ``time_usec`` as sent (sender's clock, microseconds).
    positions : (K, 3) NED m, K in 0 .. 5 (0: the intent is withdrawn).
    velocities : (K, 3) NED m/s.
    """

    key: tuple
    stamp: int
    positions: np.ndarray
    velocities: np.ndarray


def _upper_triangle(position_cov: np.ndarray | None, block: int) -> list[float]:
    """21 row-major upper-triangle entries of a 6x6 whose block ``block`` (0: x/y/z) is ``position_cov``."""
    out = [math.nan] * 21
    if position_cov is None:
        return out
    c = np.asarray(position_cov, dtype=float)
    full = np.full((6, 6), math.nan)
    full[3 * block:3 * block + 3, 3 * block:3 * block + 3] = c
    k = 0
    for i in range(6):
        for j in range(i, 6):
            out[k] = float(full[i, j])
            k += 1
    return out


def encode_state(time_usec: int, position: np.ndarray, velocity: np.ndarray,
                 position_cov: np.ndarray, velocity_cov: np.ndarray | None,
                 reset_counter: int = 0) -> mavlink2.MAVLink_odometry_message:
    """ODOMETRY of the sender's own vehicle (NED m, m/s; covariances m^2, m^2/s^2)."""
    p = np.asarray(position, dtype=float)
    v = np.asarray(velocity, dtype=float)
    return mavlink2.MAVLink_odometry_message(
        int(time_usec), mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_LOCAL_NED,
        float(p[0]), float(p[1]), float(p[2]), [math.nan, math.nan, math.nan, math.nan],
        float(v[0]), float(v[1]), float(v[2]), math.nan, math.nan, math.nan,
        _upper_triangle(position_cov, 0), _upper_triangle(velocity_cov, 0),
        int(reset_counter) & 0xFF, mavlink2.MAV_ESTIMATOR_TYPE_NAIVE, 0,
    )


def encode_intent(time_usec: int, positions: np.ndarray | None,
                  velocities: np.ndarray | None) -> mavlink2.MAVLink_trajectory_representation_waypoints_message:
    """TRAJECTORY_REPRESENTATION_WAYPOINTS of up to five knots ((K, 3) NED m and m/s);
    ``None`` (or K = 0) withdraws the intent."""
    k = 0 if positions is None else int(np.asarray(positions).shape[0])
    if k > MAX_POINTS:
        raise ValueError(f"an intent has at most {MAX_POINTS} knots, got {k}")
    cols = []
    for arr in (positions, velocities):
        a = np.full((MAX_POINTS, 3), math.nan)
        if k:
            a[:k] = np.asarray(arr, dtype=float)
        cols.extend(a[:, i].tolist() for i in range(3))
    return mavlink2.MAVLink_trajectory_representation_waypoints_message(
        int(time_usec), k, *cols, _NAN5, _NAN5, _NAN5, _NAN5, _NAN5, _UNUSED_COMMANDS)


def decode_intent(msg: mavlink2.MAVLink_trajectory_representation_waypoints_message) -> IntentReport | messages.Rejected:
    """An :class:`IntentReport`, or Rejected: more than five points, a non-finite or
    out-of-range position or velocity among the valid points."""
    key = messages.source_key(msg)
    k = int(msg.valid_points)
    if k > MAX_POINTS:
        return messages.Rejected(key, msg.get_type(), f"valid_points {k} > {MAX_POINTS}")
    p = np.array([msg.pos_x[:k], msg.pos_y[:k], msg.pos_z[:k]], dtype=float).T.reshape(k, 3)
    v = np.array([msg.vel_x[:k], msg.vel_y[:k], msg.vel_z[:k]], dtype=float).T.reshape(k, 3)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
        return messages.Rejected(key, msg.get_type(), "non-finite position or velocity among the valid points")
    if k and (np.max(np.abs(p)) > MAX_INTENT_RANGE_M or np.max(np.abs(v)) > MAX_INTENT_SPEED_MPS):
        return messages.Rejected(key, msg.get_type(), "position or velocity out of range")
    return IntentReport(key=key, stamp=int(msg.time_usec), positions=p, velocities=v)
