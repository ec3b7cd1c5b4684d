"""Linearised collision rows, one per obstacle and step, for each formulation.

Every formulation returns the same shape of row (so all share one QP layout)::

    coef_p . p_i  (+ coef_lam * lam_ji)  + s_lo - s_hi   in   [lower, upper]

evaluated around the SCP iterate ``p_bar`` (and ``lam_bar`` for ``paper``). Arrays are
(P, N, ...) over obstacles ``j`` and steps ``i``, computed in one vectorised call each.
``R = R_drone + R_obstacle`` (metres), ``r_min = sqrt(chi2_3.ppf(c_min))`` and
``r_max`` likewise from ``c_max``.

- ``hyperplane``: minmax normal ``n`` and ``s_k = sqrt(n' S_k n)`` at the iterate; the
  row ``n.(o_i - p_i) >= r_min (s1 + s2) + R`` is linear in ``p_i`` and, with ``n`` fixed,
  exact: any ``p_i`` meeting it has support margin >= ``r_min`` along ``n``, hence a
  contour of touch >= ``c_min`` (docs/METHOD.md sections 1.4-1.5). With ``c_max`` the same row is bounded
  above by ``r_max (s1 + s2) + R`` (the linearisation of ``eta <= r_max``, gradient
  ``eta_grad_mu1 = -n/(s1+s2)`` scaled by ``s1 + s2``).
- ``paper``: ``h(p, lam) >= r_min`` (and ``<= r_max``) and the admissibility residual
  ``g(p, lam) = 0`` linearised in ``(p_i, lam)`` with the analytic gradients of
  :func:`companion.core.overlap.paper_terms`.
- ``deterministic``: ``|o_i - p_i| >= R`` linearised: ``n.(o_i - p_i) >= R`` with
  ``n = (o_i - p_bar_i)/|o_i - p_bar_i|`` (means and radii only).
- ``bhattacharyya``: ``D_B >= D_min = r_min^2 / 2`` linearised in ``p_i`` (for equal
  covariances ``D_B = eta^2 / 2``). Radii enter by shrinking the mean separation by ``R``
  along the line of centres (:func:`signed_bhattacharyya`).

Row scaling: OSQP runs without its own equilibration (:mod:`companion.core.planner.osqp_qp`),
so the rows are written with gradients of order one. ``hyperplane`` and ``deterministic``
rows have unit normals already; ``bhattacharyya`` rows are divided by ``sqrt(q)`` (metres
of separation) and each ``paper`` row (``h`` bounds and admissibility) by the norm of its
gradient in ``(p_i, lam)``. The feasible set is the same; slacks are in those units.
Unscaled, the ``paper`` cold start of the planner benchmark ran OSQP to its iteration
cap on an infeasible first QP (OSQP did not detect the infeasibility): 240 ms; with
unit rows it is detected in 600 iterations, 49 ms.

Obstacles out of sensing range get ``lower = -inf``, ``upper = +inf`` and zero
coefficients (the pattern stays the same).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from companion.core import jit, overlap
from companion.core.planner import pair_kernels
from companion.core.planner.request import PlanRequest
from companion.core.planner.safety import RECHECK_TOL_M, RECHECK_TOL_SIGMA, SafetyFigures, exact_safety

logger = logging.getLogger(__name__)

#: The rows ask for ``r_min + BACKOFF_SIGMA`` (Mahalanobis units) so that a solution
#: within OSQP's tolerance (primal residual ~ eps_abs + eps_rel |Ax|, a few mm for
#: positions of tens of metres, over s1 + s2 ~ 0.3 m) still meets ``r_min`` exactly on the
#: returned positions. 0.01 sigma costs about 0.005 in the contour of touch at c = 0.6.
BACKOFF_SIGMA = 1e-2
#: Same, in metres, for the deterministic baseline and for ``deterministic`` walls.
BACKOFF_M = 3e-3
#: ``lam`` is kept inside ``[LAM_EPS, 1 - LAM_EPS]`` (``paper``).
LAM_EPS = 1e-3
#: Separations below this (metres) have no defined direction; a fixed one is used.
_TINY_M = 1e-9


@dataclass(frozen=True)
class ObstacleRows:
    """Linearised obstacle rows at one SCP iterate (arrays over (P, N)).

    Attributes
    ----------
    coef_p : (P, N, 3) coefficients on ``p_i``.
    lower, upper : (P, N) bounds of the row (``-inf``/``inf`` where absent).
    coef_lam : (P, N) coefficients on ``lam`` (``paper``), else None.
    adm_p : (P, N, 3) admissibility row coefficients on ``p_i`` (``paper``), else None.
    adm_lam : (P, N) admissibility row coefficients on ``lam`` (``paper``), else None.
    adm_rhs : (P, N) admissibility right-hand side (``paper``), else None.
    """

    coef_p: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    coef_lam: np.ndarray | None = None
    adm_p: np.ndarray | None = None
    adm_lam: np.ndarray | None = None
    adm_rhs: np.ndarray | None = None


def _unit_separation(p_bar: np.ndarray, means: np.ndarray) -> np.ndarray:
    """Unit vectors from the drone iterate towards each obstacle mean, (P, N, 3)."""
    d = means - p_bar[None]
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    fallback = np.array([1.0, 0.0, 0.0])
    return np.where(norm > _TINY_M, d / np.maximum(norm, _TINY_M), fallback)


#: A drone iterate this close to an obstacle mean (metres) is nudged off it (:func:`_nudge`).
_NUDGE_M = 1e-6


def _coincident(p_bar: np.ndarray, means: np.ndarray) -> np.ndarray:
    """(P, N) booleans: the drone iterate ``p_bar`` (N, 3) within :data:`_NUDGE_M` of an obstacle mean (P, N, 3)."""
    return np.linalg.norm(means - p_bar[None], axis=-1) <= _NUDGE_M


def _nudge(p_bar: np.ndarray, means: np.ndarray, close: np.ndarray | None = None) -> np.ndarray:
    """Drone iterate moved off any obstacle mean it coincides with (minmax needs a direction).

    ``close``: :func:`_coincident` of these arguments, if the caller has it.
    """
    close = _coincident(p_bar, means) if close is None else close
    if not np.any(close):
        return np.broadcast_to(p_bar[None], means.shape)
    out = np.broadcast_to(p_bar[None], means.shape).copy()
    out[close] -= np.array([1e-4, 1e-4, 0.0])
    return out


def _same_values(kept: np.ndarray, positions: np.ndarray) -> bool:
    """``np.array_equal(kept, positions)`` for float (N, 3) arrays (the same test, without its Python layer).

    A new SCP iterate differs from the kept one in its last position as a rule, so that
    entry is compared first (a NaN there is unequal either way).
    """
    positions = np.asarray(positions)
    if kept.shape != positions.shape or (kept.ndim == 2 and kept.size and kept[-1, -1] != positions[-1, -1]):
        return False
    return bool((kept == positions).all())


def _iterate_pairs_signature(t):
    """Iterate (N, 3) and obstacle means (P, N, 3) in, the pairs' means as (3, P N) components out."""
    w2 = t.float64[:, ::1]
    return t.boolean(jit.readonly(t, 2), jit.readonly(t, 3), t.float64, w2, w2)


@jit.lazy(_iterate_pairs_signature)
def _iterate_pairs(p_bar, means, nudge_m, m1, m2):
    """:func:`_coincident`, :func:`_nudge` and the batch-last layout of the minmax's means in one pass.

    Writes the (nudged) drone iterate ``p_bar`` (N, 3) against every obstacle mean ``means``
    (P, N, 3) as components ``m1`` and ``m2`` (3, P N), pair ``j N + i``; returns whether any
    iterate point was within ``nudge_m`` of a mean. The numpy functions' operations in their
    order (the distance is numpy's norm over the last axis, ``sqrt((dx^2 + dy^2) + dz^2)``; the
    nudge subtracts ``[1e-4, 1e-4, 0]``), so the same bits, without their dozen small arrays.
    """
    n_obs, n_steps = means.shape[0], means.shape[1]
    nudged = False
    for j in range(n_obs):
        for i in range(n_steps):
            k = j * n_steps + i
            px, py, pz = p_bar[i, 0], p_bar[i, 1], p_bar[i, 2]
            ox, oy, oz = means[j, i, 0], means[j, i, 1], means[j, i, 2]
            dx, dy, dz = ox - px, oy - py, oz - pz
            if math.sqrt(dx * dx + dy * dy + dz * dz) <= nudge_m:
                px, py, pz = px - 1e-4, py - 1e-4, pz - 0.0
                nudged = True
            m1[0, k], m1[1, k], m1[2, k] = px, py, pz
            m2[0, k], m2[1, k], m2[2, k] = ox, oy, oz
    return nudged


def hyperplane_rows(p_bar, drone_covs, means, covs, radius_sum, r_min, r_max, separator=None):
    """Rows of the ``hyperplane`` formulation; also returns the minmax result at the iterate.

    ``separator``: the minmax result at the (nudged) iterate if already computed.
    """
    if separator is None:
        separator = overlap.minmax(_nudge(p_bar, means), np.broadcast_to(drone_covs[None], covs.shape), means, covs)
    res = separator
    # -n.p >= r_min (s1 + s2) + R - n.o, and <= r_max (s1 + s2) + R - n.o with c_max
    coef_p, lower, upper = pair_kernels.hyperplane_rows(res.normal, res.s1, res.s2, means, radius_sum,
                                                        r_min + BACKOFF_SIGMA, r_max)
    return ObstacleRows(coef_p=coef_p, lower=lower, upper=upper), res


def deterministic_rows(p_bar, means, radius_sum):
    """Rows of the ``deterministic`` baseline: ``n.(o - p) >= R`` with ``n`` from the iterate."""
    n = _unit_separation(p_bar, means)
    n_o = np.einsum("pnk,pnk->pn", n, means)
    lower = radius_sum[:, None] + BACKOFF_M - n_o
    return ObstacleRows(coef_p=-n, lower=lower, upper=np.full_like(lower, np.inf))


def signed_bhattacharyya(p, drone_covs, means, covs, radius_sum):
    """Radius-aware Bhattacharyya distance and its gradient w.r.t. the drone mean ``p``.

    ``D = 1/8 s|s| u' S^-1 u + 1/2 ln(det S / sqrt(det S1 det S2))`` with ``S = (S1+S2)/2``,
    ``d = o - p``, ``u = d/|d|`` and ``s = |d| - R`` the separation of the body surfaces
    along the line of centres. For ``s >= 0`` this is the Bhattacharyya distance of the
    means moved ``R`` closer; the signed square keeps it increasing through contact, so
    its linearisation pushes the drone out even when the bodies overlap.
    ``grad_d D = 1/8 [2|s| q u + s|s| (2/|d|)(S^-1 u - q u)]``, ``q = u'S^-1u``; ``grad_p = -grad_d``.

    Returns
    -------
    value : (P, N) array
    grad_p : (P, N, 3) array
    """
    cov1 = np.broadcast_to(drone_covs[None], covs.shape)
    d = means - p
    dist = np.maximum(np.linalg.norm(d, axis=-1), _TINY_M)
    u = d / dist[..., None]
    s = dist - radius_sum[:, None]
    s_inv = np.linalg.inv(0.5 * (cov1 + covs))
    s_inv_u = np.einsum("pnkl,pnl->pnk", s_inv, u)
    q = np.einsum("pnk,pnk->pn", u, s_inv_u)
    c0 = overlap.bhattacharyya(means, cov1, means, covs)          # covariance term (zero separation)
    value = 0.125 * s * np.abs(s) * q + c0
    grad_d = 0.125 * (2.0 * (np.abs(s) * q)[..., None] * u
                      + (s * np.abs(s) * 2.0 / dist)[..., None] * (s_inv_u - q[..., None] * u))
    return value, -grad_d


def bhattacharyya_rows(p_bar, drone_covs, means, covs, radius_sum, r_min):
    """Rows of the ``bhattacharyya`` baseline: ``D >= D_min = r_min^2 / 2`` (D of :func:`signed_bhattacharyya`).

    ``D = 1/8 s|s| q + c0`` is quadratic in the separation, so its gradient vanishes at
    contact and a linearisation there asks for metres of motion per unit of ``D``. The same
    set is written as ``f = s sqrt(q) >= t`` with ``t = sign(D_min - c0) sqrt(8 |D_min - c0|)``
    (``f`` is monotone in ``D``), whose gradient
    ``grad_d f = sqrt(q) u + s / (|d| sqrt(q)) (S^-1 u - q u)`` stays of order ``sqrt(q)``.
    For equal covariances and ``R = 0``, ``D = eta^2 / 2``, hence the threshold.
    """
    mu1 = _nudge(p_bar, means)
    cov1 = np.broadcast_to(drone_covs[None], covs.shape)
    d = means - mu1
    dist = np.maximum(np.linalg.norm(d, axis=-1), _TINY_M)
    u = d / dist[..., None]
    sep = dist - radius_sum[:, None]
    s_inv_u = np.einsum("pnkl,pnl->pnk", np.linalg.inv(0.5 * (cov1 + covs)), u)
    q = np.einsum("pnk,pnk->pn", u, s_inv_u)
    c0 = overlap.bhattacharyya(means, cov1, means, covs)
    gap = 0.5 * (r_min + BACKOFF_SIGMA) ** 2 - c0
    target = np.sign(gap) * np.sqrt(8.0 * np.abs(gap))
    sq = np.sqrt(q)
    f = sep * sq
    grad = -(sq[..., None] * u + (sep / (dist * sq))[..., None] * (s_inv_u - q[..., None] * u))   # w.r.t. p
    lower = target - f + np.einsum("pnk,pnk->pn", grad, mu1)
    # divided by sqrt(q) the row is in metres of separation (see "Row scaling" above)
    return ObstacleRows(coef_p=grad / sq[..., None], lower=lower / sq, upper=np.full_like(lower, np.inf))


def paper_rows(p_bar, lam_bar, drone_covs, means, covs, radius_sum, r_min, r_max):
    """Rows of the ``paper`` formulation: ``h`` bounds and admissibility ``g = 0``, linearised."""
    mu1 = _nudge(p_bar, means)
    cov1 = np.broadcast_to(drone_covs[None], covs.shape)
    t = overlap.paper_terms(mu1, cov1, means, covs, lam_bar, radius_sum[:, None])
    # h + h_p.(p - p_bar) + h_lam (lam - lam_bar) >= r_min
    base = np.einsum("pnk,pnk->pn", t.h_grad_mu1, mu1) + t.h_grad_lam * lam_bar - t.h
    lower = r_min + BACKOFF_SIGMA + base
    upper = r_max + base if r_max is not None else np.full_like(lower, np.inf)
    # g + g_p.(p - p_bar) + g_lam (lam - lam_bar) = 0
    adm_rhs = np.einsum("pnk,pnk->pn", t.g_grad_mu1, mu1) + t.g_grad_lam * lam_bar - t.g
    kh, kg = _inverse_row_norm(t.h_grad_mu1, t.h_grad_lam), _inverse_row_norm(t.g_grad_mu1, t.g_grad_lam)
    return ObstacleRows(coef_p=t.h_grad_mu1 * kh[..., None], lower=lower * kh, upper=upper * kh,
                        coef_lam=t.h_grad_lam * kh, adm_p=t.g_grad_mu1 * kg[..., None], adm_lam=t.g_grad_lam * kg,
                        adm_rhs=adm_rhs * kg)


def _inverse_row_norm(coef_p: np.ndarray, coef_lam: np.ndarray) -> np.ndarray:
    """``1 / |(coef_p, coef_lam)|`` per row, (P, N): the factor that makes a row's gradient unit."""
    norm = np.sqrt(np.einsum("pnk,pnk->pn", coef_p, coef_p) + coef_lam**2)
    return 1.0 / np.maximum(norm, _TINY_M)


def relax_out_of_range(rows: ObstacleRows, in_range: np.ndarray) -> ObstacleRows:
    """Rows with obstacles outside sensing range made inactive (zero coefficients, infinite bounds)."""
    in_range = np.asarray(in_range, dtype=bool)
    if in_range.all():
        return rows
    off = ~in_range
    def zero(a):
        if a is None:
            return None
        a = a.copy()
        a[off] = 0.0
        return a
    lower, upper = rows.lower.copy(), rows.upper.copy()
    lower[off], upper[off] = -np.inf, np.inf
    adm_lam = None if rows.adm_lam is None else rows.adm_lam.copy()
    adm_rhs = None if rows.adm_rhs is None else rows.adm_rhs.copy()
    if adm_lam is not None:
        adm_lam[off], adm_rhs[off] = 1.0, 0.5   # lam = 1/2 (any value; no obstacle row uses it)
    return ObstacleRows(coef_p=zero(rows.coef_p), lower=lower, upper=upper, coef_lam=zero(rows.coef_lam),
                        adm_p=zero(rows.adm_p), adm_lam=adm_lam, adm_rhs=adm_rhs)


# --------------------------------------------------------------------------------------
# The formulations as objects behind one protocol (the SCP never asks for a name).
# --------------------------------------------------------------------------------------


class Formulation:
    """One collision formulation: its rows, its exact recheck and what its QP carries.

    Subclasses set the class attributes and implement :meth:`rows` (and :meth:`recheck`
    where the exact figures are not the minmax touch radius).

    Parameters
    ----------
    r_min : float
        Touch radius of ``c_min`` (Mahalanobis units).
    r_max : float or None
        Touch radius of ``c_max``; ``None`` without an upper bound.
    drone_radius_m : float
        Physical drone radius, metres.

    Attributes
    ----------
    name : the ``[planner] formulation`` value.
    carries_lam : whether the QP has the ``lam`` columns and admissibility rows (``paper``).
    has_upper : whether the QP has the ``c_max`` rows (formulations that bound the overlap,
        and only with ``r_max``).
    wall_radius : Mahalanobis radius of the exact wall check (``r_min``; 0 for means only).
    wall_row_radius : the same in the wall rows, with the back-off.
    wall_row_backoff_m : back-off of the wall rows in metres.
    """

    name: str = ""
    carries_lam: bool = False
    bounds_overlap: bool = False

    def __init__(self, r_min: float, r_max: float | None, drone_radius_m: float) -> None:
        self.r_min = float(r_min)
        self.r_max = None if r_max is None else float(r_max)
        self.drone_radius_m = float(drone_radius_m)
        self.has_upper = self.bounds_overlap and self.r_max is not None
        self.wall_radius = self.r_min
        self.wall_row_radius = self.r_min + BACKOFF_SIGMA
        self.wall_row_backoff_m = 0.0
        self._separator: tuple[PlanRequest, np.ndarray, bool, overlap.MinmaxResult] | None = None
        self._recheck: tuple[PlanRequest, np.ndarray, np.ndarray, tuple[SafetyFigures, bool]] | None = None

    def rows(self, request: PlanRequest, positions: np.ndarray, lam: np.ndarray | None) -> ObstacleRows:
        """Linearised obstacle rows around ``positions`` (N, 3) (and ``lam`` (P, N) if carried)."""
        raise NotImplementedError

    def initial_lam(self, request: PlanRequest, positions: np.ndarray) -> np.ndarray | None:
        """Starting ``lam`` (P, N) at ``positions`` for formulations that carry it, else ``None``."""
        return None

    def wall_upper(self, request: PlanRequest) -> np.ndarray:
        """Right-hand sides (W, N) of the wall rows ``a.p_i <= b - r sqrt(a' S_i a) - R_drone``."""
        upper = request.walls_offset[:, None] - self.wall_row_radius * request.wall_spread - self.drone_radius_m
        return upper - self.wall_row_backoff_m if self.wall_row_backoff_m else upper

    def recheck(self, request: PlanRequest, positions: np.ndarray, in_range: np.ndarray) -> tuple[SafetyFigures, bool]:
        """Exact figures of ``positions`` and whether this formulation's own constraints hold on them.

        The last answer is kept: the SCP rechecks its converged iterate, and the plan it
        returns is that iterate, so the final recheck asks the same question.
        """
        cached = self._recheck
        if (cached is not None and cached[0] is request and _same_values(cached[1], positions)
                and (cached[2] is in_range or np.array_equal(cached[2], in_range))):
            return cached[3]
        figs = self._exact(request, positions)
        answer = figs, self._holds(request, positions, figs, in_range)
        # a read-only mask (the planner's, from its request data) is kept as it is: the same object next time
        kept = in_range if isinstance(in_range, np.ndarray) and not in_range.flags.writeable else np.array(in_range)
        self._recheck = (request, np.array(positions), kept, answer)
        return answer

    def _holds(self, request: PlanRequest, positions: np.ndarray, figs: SafetyFigures, in_range: np.ndarray) -> bool:
        """Whether this formulation's own constraints hold on ``positions`` (their exact figures ``figs``)."""
        return self._walls_hold(figs) and bool((figs.eta[in_range] >= self.r_min - RECHECK_TOL_SIGMA).all())

    def separator(self, request: PlanRequest, positions: np.ndarray) -> overlap.MinmaxResult:
        """Minmax of the drone at ``positions`` (N, 3) against every obstacle (P, N), nudged off coincident means."""
        return self._separation(request, positions)[1]

    def _separation(self, request: PlanRequest, positions: np.ndarray) -> tuple[bool, overlap.MinmaxResult]:
        """Whether ``positions`` had to be nudged off an obstacle mean, and :meth:`separator`.

        The last answer is kept: the SCP's exact recheck of an iterate and the next
        linearisation around it ask for the same one.
        """
        cached = self._separator
        if cached is not None and cached[0] is request and _same_values(cached[1], positions):
            return cached[2], cached[3]
        means, pairs = request.obstacle_means, request.covariance_pairs
        if jit.available():
            pairs_n = means.shape[0] * means.shape[1]
            m1, m2 = np.empty((3, pairs_n)), np.empty((3, pairs_n))
            nudged = bool(_iterate_pairs()(np.ascontiguousarray(positions, dtype=float),
                                           np.ascontiguousarray(means, dtype=float), _NUDGE_M, m1, m2))
            res = pairs.minmax_components(m1, m2)
        else:
            close = _coincident(positions, means)
            nudged = bool(np.any(close))
            res = pairs.minmax(_nudge(positions, means, close), means)
        self._separator = (request, np.array(positions), nudged, res)
        return nudged, res

    def _exact(self, request: PlanRequest, positions: np.ndarray) -> SafetyFigures:
        separator = None
        if request.num_obstacles:
            nudged, res = self._separation(request, positions)
            separator = None if nudged else res   # at a coincident mean: the exact figures of the un-nudged pair
        return exact_safety(request, positions, self.drone_radius_m, self.wall_radius, separator)

    @staticmethod
    def _walls_hold(figs: SafetyFigures) -> bool:
        return bool((figs.wall_margin >= -RECHECK_TOL_M).all())

    def _radius_sum(self, request: PlanRequest) -> np.ndarray:
        return request.obstacle_radii + self.drone_radius_m


class Hyperplane(Formulation):
    """``hyperplane``: the minmax separating plane at the iterate, exact in ``p_i``."""

    name = "hyperplane"
    bounds_overlap = True

    def rows(self, request, positions, lam=None):
        rows, _ = hyperplane_rows(positions, request.safety_covs, request.obstacle_means, request.obstacle_covs,
                                  self._radius_sum(request), self.r_min, self.r_max, self.separator(request, positions))
        return rows


class Paper(Formulation):
    """``paper``: the paper's joint ``(p, lam)`` formulation with the admissibility rows."""

    name = "paper"
    carries_lam = True
    bounds_overlap = True

    def rows(self, request, positions, lam):
        return paper_rows(positions, lam, request.safety_covs, request.obstacle_means, request.obstacle_covs,
                          self._radius_sum(request), self.r_min, self.r_max)

    def initial_lam(self, request, positions):
        if request.num_obstacles == 0:
            return np.zeros((0, request.horizon_steps))
        return np.clip(self.separator(request, positions).lam, LAM_EPS, 1.0 - LAM_EPS)


class Deterministic(Formulation):
    """``deterministic`` baseline: means and radii only (no covariance in rows or walls)."""

    name = "deterministic"

    def __init__(self, r_min: float, r_max: float | None, drone_radius_m: float) -> None:
        super().__init__(r_min, r_max, drone_radius_m)
        self.wall_radius = 0.0
        self.wall_row_radius = 0.0
        self.wall_row_backoff_m = BACKOFF_M

    def rows(self, request, positions, lam=None):
        return deterministic_rows(positions, request.obstacle_means, self._radius_sum(request))

    def _holds(self, request, positions, figs, in_range):
        return self._walls_hold(figs) and bool(np.all(figs.distance_margin[in_range] >= -RECHECK_TOL_M))


class Bhattacharyya(Formulation):
    """``bhattacharyya`` baseline: the radius-aware Bhattacharyya distance bounded below."""

    name = "bhattacharyya"

    def rows(self, request, positions, lam=None):
        return bhattacharyya_rows(positions, request.safety_covs, request.obstacle_means, request.obstacle_covs,
                                  self._radius_sum(request), self.r_min)

    def _holds(self, request, positions, figs, in_range):
        ok = self._walls_hold(figs)
        if request.num_obstacles:
            value, _ = signed_bhattacharyya(positions, request.safety_covs, request.obstacle_means,
                                            request.obstacle_covs, self._radius_sum(request))
            margin = value - 0.5 * self.r_min**2
            ok &= bool(np.all(margin[in_range] >= -self.r_min * RECHECK_TOL_SIGMA))
        return ok


#: The formulation class of each ``[planner] formulation`` value.
BY_NAME: dict[str, type[Formulation]] = {cls.name: cls for cls in (Hyperplane, Paper, Deterministic, Bhattacharyya)}


def make_formulation(name: str, r_min: float, r_max: float | None, drone_radius_m: float) -> Formulation:
    """The formulation object for ``name`` (one of :data:`companion.core.planner.config.FORMULATIONS`)."""
    return BY_NAME[name](r_min, r_max, drone_radius_m)
