"""Which tracks the planner constrains when more are in range than it can afford: the risk order.

The planner's work grows with the number of obstacle rows it carries, so a replan
constrains at most ``[companion] max_constrained_tracks`` tracks (static map obstacles
always count in full and are not part of the limit). The tracks are ranked by risk,
riskiest first:

1. the smallest *predicted clearance* over the horizon: the distance between the
   drone's nominal path and the track's predicted mean at steps 0..N (now included),
   minus both bodies' radii, minus the ``c_min`` confidence radius of the two
   position uncertainties along the line between them (``sqrt(chi2_3.ppf(c_min))``
   standard deviations of the summed covariance's largest eigenvalue), in metres;
2. then the earlier *time of that closest approach* (s after the request);
3. then the track's creation order (deterministic).

The drone's nominal path is the straight line from its position at ``V_0`` (the
velocity the next plan starts from) for the horizon: the same kind of open-loop guess
the tracker makes of the obstacles. A track that is far and slow ranks last; one that
is close now or closing fast ranks first. The tracks left out are counted in the
job (``ReplanJob.tracks_unconstrained``), in the summary and in a rate-limited
STATUSTEXT; they are still tracked, predicted and included in the realised contour of
touch, and are constrained as soon as they rank among the riskiest.

Before any ranking, tracks **beyond a wall** for the whole horizon are set apart
(:func:`beyond_walls`): at every step some wall's plane separates the track's ``c_min``
confidence ellipsoid, grown by its body radius, from the side the drone is kept on.
The drone's plan keeps its own ``c_min`` ellipsoid, grown by its radius, on the free side
of every wall (the wall rows, and the exact recheck every plan without slack passes), so
that plane separates the two grown ellipsoids whatever the plan: it is a hyperplane row
with the wall's normal as separator, with the per-step collision bound ``Phi(-r_min)`` of
any row, and a row for the track would never bind. (The contour of touch reported with
radii is a lower bound taken at the minmax normal, not the wall's; for such a pair it can
read below ``c_min`` although the plane separates them. docs/REALTIME.md has the argument.) In a corridor, 200 systems reporting
from outside its walls then cost the planner nothing (before: the 8 riskiest were
constrained, 8 times the corridor's one obstacle). Such tracks are counted
(``ReplanJob.tracks_beyond_walls``), predicted and included in the realised contour of
touch; they are constrained again at the first replan whose prediction reaches a wall.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy.stats import chi2

logger = logging.getLogger(__name__)


def confidence_radius(c_min: float) -> float:
    """Standard deviations of a 3-D Gaussian's ``c_min`` confidence ellipsoid along its longest axis."""
    return float(math.sqrt(chi2.ppf(c_min, 3)))


def reach_m(radius_m: float, cov: np.ndarray, sigmas: float) -> float:
    """How far (m) a body of ``radius_m`` and its ``c_min`` ellipsoid reach from its mean, at most:
    the radius plus ``sigmas`` (:func:`confidence_radius`) standard deviations of the position
    covariance ``cov`` (3, 3, m^2) along its longest axis."""
    return radius_m + sigmas * float(np.sqrt(max(np.linalg.eigvalsh(cov)[-1], 0.0)))


def rank_by_risk(
    drone_path: np.ndarray,
    track_means: np.ndarray,
    track_cov_max_eig: np.ndarray,
    drone_cov_max_eig: float,
    radius_sum: float | np.ndarray,
    step_s: float,
    sigmas: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the tracks, riskiest first, with each track's predicted clearance and its time.

    Parameters
    ----------
    drone_path : (N+1, 3) array
        The drone's nominal positions at steps 0..N, NED m.
    track_means : (P, N+1, 3) array
        Each track's predicted mean at the same steps, NED m.
    track_cov_max_eig : (P, N+1) array
        Largest eigenvalue (an upper bound is fine) of each track's predicted position covariance, m^2.
    drone_cov_max_eig : float
        The same for the drone's planning covariance, m^2.
    radius_sum : float or (P, 1) array
        Drone radius plus obstacle radius (one per track when they differ), m.
    step_s : float
        Seconds per step.
    sigmas : float
        Confidence radius in standard deviations (:func:`confidence_radius`).

    Returns
    -------
    order : (P,) int array
        Track indices, riskiest first.
    clearance_m : (P,) array
        Smallest predicted clearance over the steps, m (negative: the confidence regions overlap).
    t_closest_s : (P,) array
        Seconds after the request of that smallest clearance.
    """
    p = track_means.shape[0]
    if p == 0:
        return np.zeros(0, dtype=int), np.zeros(0), np.zeros(0)
    distance = np.linalg.norm(track_means - drone_path[None, :, :], axis=2)
    spread = sigmas * np.sqrt(np.maximum(track_cov_max_eig, 0.0) + max(drone_cov_max_eig, 0.0))
    clearance = distance - radius_sum - spread
    step = np.argmin(clearance, axis=1)
    best = clearance[np.arange(p), step]
    t_closest = step * step_s
    order = np.lexsort((np.arange(p), t_closest, best))  # last key is primary
    return order, best, t_closest


def choose(order: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``limit`` riskiest indices in their original order, and the rest (riskiest first)."""
    chosen = np.sort(order[:limit])
    return chosen, order[limit:]


def beyond_walls(
    mean: np.ndarray,
    cov: np.ndarray,
    lags_s: np.ndarray,
    accel_noise_psd_m2ps3: float,
    walls_normal: np.ndarray,
    walls_offset: np.ndarray,
    radius_m: np.ndarray,
    sigmas: float,
) -> np.ndarray:
    """Which tracks stay beyond a wall, with their confidence ellipsoid, at every step of the horizon.

    Track ``j`` is beyond the walls when for every lag ``tau`` some wall ``(a, b)`` (free
    space ``a . p <= b``) has::

        a . m(tau) - b >= sigmas sqrt(a' C(tau) a) + R_j

    with ``m(tau) = p + tau v`` and ``C(tau) = Ppp + tau (Ppv + Ppv') + tau^2 Pvv + q tau^3 / 3 I``
    the tracker's own prediction (:func:`estimator.models.propagate_position`), written
    along each wall's normal only, so 200 tracks cost a few whole-array operations.

    Parameters
    ----------
    mean : (P, 6) array
        Each track's state (position NED m, velocity NED m/s) at its last estimate.
    cov : (P, 6, 6) array
        Its covariance.
    lags_s : (P, N) array
        Seconds from each track's estimate to each step of the request (negative taken as 0).
    accel_noise_psd_m2ps3 : float
        The tracker's white acceleration noise PSD ``q``.
    walls_normal : (W, 3) array
        Unit outward normals (free space ``a . p <= b``).
    walls_offset : (W,) array
        Offsets ``b``, m.
    radius_m : (P,) array
        Body radius of each track, m.
    sigmas : float
        Confidence radius in standard deviations (:func:`confidence_radius` of ``c_min``).

    Returns
    -------
    (P,) bool array
        True where the track is beyond some wall at every step (False for every track
        when there are no walls).
    """
    p = mean.shape[0]
    a = np.asarray(walls_normal, dtype=float).reshape(-1, 3)
    if p == 0 or a.shape[0] == 0:
        return np.zeros(p, dtype=bool)
    tau = np.maximum(np.asarray(lags_s, dtype=float), 0.0)[:, None, :]       # (P, 1, N)
    along_p = mean[:, :3] @ a.T                                               # (P, W)
    along_v = mean[:, 3:] @ a.T
    var_pp = np.einsum("wi,pij,wj->pw", a, cov[:, :3, :3], a)
    cross = np.einsum("wi,pij,wj->pw", a, cov[:, :3, 3:], a)                  # a' Ppv a = a' Ppv' a
    var_vv = np.einsum("wi,pij,wj->pw", a, cov[:, 3:, 3:], a)
    centre = along_p[..., None] + tau * along_v[..., None]                    # (P, W, N)
    var = (var_pp[..., None] + 2.0 * tau * cross[..., None] + tau**2 * var_vv[..., None]
           + accel_noise_psd_m2ps3 / 3.0 * tau**3)
    clear = (centre - np.asarray(walls_offset, dtype=float)[None, :, None]
             - sigmas * np.sqrt(np.maximum(var, 0.0)) - np.asarray(radius_m, dtype=float)[:, None, None])
    return np.all(np.any(clear >= 0.0, axis=1), axis=1)
