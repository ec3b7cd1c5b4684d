"""The autopilot's own flight predicted along its route, and the first predicted conflict on it.

While the autopilot flies its stored mission, the companion does not plan: it predicts where
the autopilot will take the vehicle (:func:`path_along_route`: straight legs through the
route's points at the mission speed, as PX4 and ArduPilot fly waypoint legs) and judges that
path by the planner's own promise (:func:`first_conflict`: the confidence contour at which the
drone's and each obstacle's Gaussians touch, bodies included, may not fall below ``c_min``).
Pure: positions in local NED metres, times in seconds, covariances in m^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.core.overlap import contour_of_touch
from companion.errors import InputError


def path_along_route(position: np.ndarray, route: np.ndarray, speed_mps, times_s: np.ndarray) -> np.ndarray:
    """Where a vehicle at ``position`` (3,) flying straight legs through ``route`` (K, 3) is at the
    times ``times_s`` (N,) after now (s, >= 0): (N, 3), NED m.

    ``speed_mps``: the speed on every leg (m/s), or one speed per leg (K,): leg ``k`` ends at
    ``route[k]`` (the mission's DO_CHANGE_SPEED items change it from one leg to the next). The
    first leg runs from ``position`` to ``route[0]``; after the last point the vehicle stays
    there (the autopilot holds or lands at its last item). An empty route holds at ``position``.
    """
    p0 = np.asarray(position, dtype=float).reshape(3)
    times = np.asarray(times_s, dtype=float).reshape(-1)
    points = np.vstack([p0, np.asarray(route, dtype=float).reshape(-1, 3)])
    legs = np.diff(points, axis=0)
    given = np.asarray(speed_mps, dtype=float)
    if not np.all(np.isfinite(given)) or np.any(given <= 0.0):
        raise InputError(f"speed_mps must be positive, got {speed_mps!r}")
    speeds = np.broadcast_to(given, (len(legs),)) if given.ndim == 0 else given.reshape(-1)
    if speeds.shape != (len(legs),):
        raise InputError(f"speed_mps must be one speed or one per leg ({len(legs)}), got {given.size}")
    if np.any(times < 0.0) or not np.all(np.isfinite(times)):
        raise InputError("times_s must be finite and not negative")
    lengths = np.linalg.norm(legs, axis=1)
    at = np.concatenate([[0.0], np.cumsum(lengths / speeds)])   # time at each point (s)
    out = np.empty((times.size, 3))
    for i, t in enumerate(np.minimum(times, at[-1])):
        k = int(np.searchsorted(at, t, side="right")) - 1
        k = min(max(k, 0), len(legs) - 1) if len(legs) else 0
        if not len(legs) or lengths[k] == 0.0:
            out[i] = points[min(k + 1, len(points) - 1)] if len(legs) else p0
        else:
            out[i] = points[k] + legs[k] * ((t - at[k]) / (at[k + 1] - at[k]))
    return out


@dataclass(frozen=True)
class PredictedConflict:
    """The earliest step of a predicted path whose contour of touch with an obstacle falls below ``c_min``.

    ``obstacle`` is the obstacle's index, ``step`` the step's index (0-based) and ``in_s`` its
    time after now (s); ``contour`` the contour of touch there and ``min_contour`` the smallest
    over the whole path with that obstacle.
    """

    obstacle: int
    step: int
    in_s: float
    contour: float
    min_contour: float


def path_contours(drone_means: np.ndarray, drone_covs: np.ndarray, obstacle_means: np.ndarray,
                  obstacle_covs: np.ndarray, radii_sum: np.ndarray) -> np.ndarray:
    """Contour of touch (M, N) between the drone's predicted Gaussians (N, 3) / (N, 3, 3) and each of
    M obstacles' (M, N, 3) / (M, N, 3, 3), with the bodies' radii summed per obstacle ``radii_sum`` (M,), m."""
    obstacle_means = np.asarray(obstacle_means, dtype=float)
    m, n = obstacle_means.shape[:2]
    if m == 0:
        return np.empty((0, n))
    radius = np.broadcast_to(np.asarray(radii_sum, dtype=float).reshape(m, 1), (m, n))
    ct = contour_of_touch(np.broadcast_to(drone_means, (m, n, 3)), np.broadcast_to(drone_covs, (m, n, 3, 3)),
                          obstacle_means, obstacle_covs, radius)
    return np.asarray(ct, dtype=float).reshape(m, n)


def first_conflict(contours: np.ndarray, times_s: np.ndarray, c_min: float) -> PredictedConflict | None:
    """The earliest step (and, at that step, the obstacle with the smallest contour) where a
    contour of ``contours`` (M, N) is below ``c_min``; None when the whole path keeps the promise."""
    contours = np.asarray(contours, dtype=float)
    if contours.size == 0:
        return None
    below = contours < c_min
    if not below.any():
        return None
    step = int(np.argmax(below.any(axis=0)))
    column = np.where(below[:, step], contours[:, step], np.inf)
    k = int(np.argmin(column))
    return PredictedConflict(obstacle=k, step=step, in_s=float(np.asarray(times_s)[step]),
                             contour=float(contours[k, step]), min_contour=float(contours[k].min()))
