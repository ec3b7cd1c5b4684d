"""A drone's intent: its plan in force, as a few knots another drone can predict it from.

A companion in a fleet announces where its vehicle is going: the means of its current
plan over the horizon. A MAVLink message carries at most five points
(TRAJECTORY_REPRESENTATION_WAYPOINTS), so the plan goes out as *knots*: positions and
velocities at ``t0 + k * spacing_s`` (k = 0 .. K-1, K <= 5), the fleet-wide
``spacing_s`` (``[fleet] intent_knot_spacing_s``) standing in for the per-point times the
message does not have. A receiver rebuilds the path with cubic Hermite interpolation
between knots (positions and velocities match at every knot) and carries it on at the
last knot's velocity beyond it.

Covariance. The intent carries means only; a receiver gives it the peer's own position
covariance (from its state announcement, ODOMETRY) growing linearly with the time since
the intent was made (``growth_m2ps``, isotropic, m^2 per second): how far a vehicle
strays from a plan it keeps replanning, documented and shared by the fleet.

Frames and units: NED metres, m/s, seconds on the receiver's vehicle time base (the
caller maps the sender's stamp). Pure: no clock, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_KNOTS", "Intent", "intent_from_plan", "intent_means", "intent_covariances", "hermite"]

#: Points a TRAJECTORY_REPRESENTATION_WAYPOINTS message carries.
MAX_KNOTS = 5


@dataclass(frozen=True)
class Intent:
    """A plan as knots.

    Attributes
    ----------
    t0_s : time of the first knot (the plan's start), s.
    spacing_s : time between knots, s (> 0).
    positions : (K, 3) NED m, K in 1 .. 5.
    velocities : (K, 3) NED m/s.
    """

    t0_s: float
    spacing_s: float
    positions: np.ndarray
    velocities: np.ndarray

    def __post_init__(self) -> None:
        p = np.asarray(self.positions, dtype=float)
        v = np.asarray(self.velocities, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or not 1 <= p.shape[0] <= MAX_KNOTS:
            raise ValueError(f"intent positions must be (K, 3) with K in 1..{MAX_KNOTS}, got {p.shape}")
        if v.shape != p.shape:
            raise ValueError(f"intent velocities {v.shape} do not match positions {p.shape}")
        if not (np.isfinite(self.spacing_s) and self.spacing_s > 0.0):
            raise ValueError(f"intent knot spacing must be positive, got {self.spacing_s}")
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v)) and np.isfinite(self.t0_s)):
            raise ValueError("intent knots must be finite")
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "velocities", v)

    @property
    def knots(self) -> int:
        return self.positions.shape[0]

    @property
    def end_s(self) -> float:
        """Time of the last knot, s."""
        return self.t0_s + (self.knots - 1) * self.spacing_s

    def knot_times(self) -> np.ndarray:
        return self.t0_s + self.spacing_s * np.arange(self.knots)


def hermite(p0: np.ndarray, v0: np.ndarray, p1: np.ndarray, v1: np.ndarray, h: float | np.ndarray,
            s: np.ndarray) -> np.ndarray:
    """Cubic Hermite positions at fractions ``s`` (M,) of segments of duration ``h`` s.

    ``p0, v0, p1, v1`` are (M, 3) (or (3,), broadcast): the segment's end positions (m)
    and velocities (m/s).
    """
    s = np.asarray(s, dtype=float)[:, None]
    h = np.asarray(h, dtype=float)
    h = h[:, None] if h.ndim == 1 else h
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0
            + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * v1)


def intent_means(intent: Intent, times_s: np.ndarray) -> np.ndarray:
    """Positions (M, 3) NED m of the intent at ``times_s`` (M,) s.

    Between knots: cubic Hermite. Before the first knot and after the last: straight on at
    that knot's velocity.
    """
    t = np.asarray(times_s, dtype=float)
    rel = (t - intent.t0_s) / intent.spacing_s
    out = np.empty((t.size, 3))
    before = rel <= 0.0
    after = rel >= intent.knots - 1
    inside = ~(before | after)
    if np.any(before):
        out[before] = intent.positions[0] + (t[before] - intent.t0_s)[:, None] * intent.velocities[0]
    if np.any(after):
        out[after] = intent.positions[-1] + (t[after] - intent.end_s)[:, None] * intent.velocities[-1]
    if np.any(inside):
        k = np.minimum(np.floor(rel[inside]).astype(int), intent.knots - 2)
        s = rel[inside] - k
        out[inside] = hermite(intent.positions[k], intent.velocities[k], intent.positions[k + 1],
                              intent.velocities[k + 1], intent.spacing_s, s)
    return out


def intent_covariances(position_cov: np.ndarray, t_cov_s: float, times_s: np.ndarray,
                       growth_m2ps: float) -> np.ndarray:
    """Covariances (M, 3, 3) m^2 along an intent: ``position_cov`` (3, 3) at ``t_cov_s``
    plus ``growth_m2ps * max(0, t - t_cov_s)`` on the diagonal."""
    t = np.asarray(times_s, dtype=float)
    grow = growth_m2ps * np.maximum(t - t_cov_s, 0.0)
    return np.asarray(position_cov, dtype=float)[None, :, :] + grow[:, None, None] * np.eye(3)[None, :, :]


def intent_from_plan(t0_s: float, step_s: float, start_position: np.ndarray, start_velocity: np.ndarray,
                     positions: np.ndarray, velocities: np.ndarray, spacing_s: float) -> Intent:
    """The knots of a plan that starts at ``t0_s`` from ``start_position`` / ``start_velocity``
    and reaches ``positions[i]`` (N, 3) NED m with ``velocities[i]`` (N, 3) m/s at
    ``t0_s + (i + 1) * step_s``.

    Knots every ``spacing_s`` from ``t0_s`` up to the plan's end (at most five); a knot
    between the plan's steps is read from the Hermite cubic through the two steps around it.
    """
    p = np.vstack([np.asarray(start_position, dtype=float)[None, :], np.asarray(positions, dtype=float)])
    v = np.vstack([np.asarray(start_velocity, dtype=float)[None, :], np.asarray(velocities, dtype=float)])
    span = (p.shape[0] - 1) * step_s
    count = int(min(MAX_KNOTS, np.floor(span / spacing_s + 1e-9) + 1))
    rel = spacing_s * np.arange(count) / step_s          # knot times in plan steps
    k = np.minimum(np.floor(rel + 1e-9).astype(int), p.shape[0] - 2)
    s = np.clip(rel - k, 0.0, 1.0)
    knot_p = hermite(p[k], v[k], p[k + 1], v[k + 1], step_s, s)
    # velocity of the cubic at the knot, d/dt of the Hermite basis
    s_ = s[:, None]
    dp = ((6 * s_ * s_ - 6 * s_) * (p[k] - p[k + 1]) / step_s
          + (3 * s_ * s_ - 4 * s_ + 1) * v[k] + (3 * s_ * s_ - 2 * s_) * v[k + 1])
    return Intent(t0_s=float(t0_s), spacing_s=float(spacing_s), positions=knot_p, velocities=dp)
