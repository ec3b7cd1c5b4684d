"""Exact safety figures of a trajectory: what the plan reports and what its status rests on.

These use the exact minmax separator on the returned positions and covariances, never
the SCP's linearisation. With physical radii ``R = R_drone + R_obstacle`` the touch
radius is the support margin along the minmax normal,
``eta = (n.(o - p) - R) / (s1 + s2)`` (docs/METHOD.md sections 1.4-1.5); the collision probability at that
step is then at most ``Phi(-eta)``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import special

from companion.core import overlap
from companion.core.planner import pair_kernels
from companion.core.planner.request import PlanRequest

logger = logging.getLogger(__name__)

#: Tolerance of the exact recheck: Mahalanobis units for ``eta`` (about 5e-4 in the
#: contour of touch at c = 0.6, 3-D), metres for walls and the deterministic baseline.
RECHECK_TOL_SIGMA = 1e-3
RECHECK_TOL_M = 1e-3


@dataclass(frozen=True)
class SafetyFigures:
    """Exact per-obstacle, per-step and per-wall figures of a trajectory.

    Attributes
    ----------
    eta : (P, N) radius-aware touch radius (Mahalanobis units).
    contour_of_touch : (P, N) ``chi2_3.cdf(max(eta, 0)^2)`` (computed on first use: the
        SCP's rechecks decide on ``eta`` and the margins, only the plan reports it).
    overlap : (P, N) ``2 (1 - Phi(max(eta, 0)))`` (on first use, likewise).
    wall_margin : (W, N) ``b - a.p - r_wall sqrt(a' S a) - R_drone``, metres.
    distance_margin : (P, N) ``|o - p| - R``, metres (used by the deterministic baseline).
    lam : (P, N) admissible overlap parameter at the positions.
    """

    eta: np.ndarray
    wall_margin: np.ndarray
    distance_margin: np.ndarray
    lam: np.ndarray

    @cached_property
    def _touch_terms(self) -> tuple[np.ndarray, np.ndarray] | None:
        return pair_kernels.touch_terms(self.eta)

    @cached_property
    def contour_of_touch(self) -> np.ndarray:
        terms = self._touch_terms
        if terms is not None:        # confidence_from_radius's operations, the same bits
            return special.gammainc(1.5, terms[0])
        return np.asarray(overlap.confidence_from_radius(self.eta, 3)).reshape(self.eta.shape)

    @cached_property
    def overlap(self) -> np.ndarray:
        terms = self._touch_terms
        if terms is not None:        # overlap_from_radius's of max(eta, 0), the same bits
            return 2.0 * special.ndtr(terms[1])
        return np.asarray(overlap.overlap_from_radius(np.maximum(self.eta, 0.0))).reshape(self.eta.shape)


def exact_safety(request: PlanRequest, positions: np.ndarray, drone_radius_m: float, wall_radius: float,
                 separator: overlap.MinmaxResult | None = None) -> SafetyFigures:
    """Exact safety figures of ``positions`` (N, 3) against the request's obstacles and walls.

    Parameters
    ----------
    request : PlanRequest
        Covariances, obstacle predictions and walls.
    positions : (N, 3) array
        Planned drone means at steps 1..N, NED metres.
    drone_radius_m : float
        Physical drone radius, metres.
    wall_radius : float
        Mahalanobis radius used for the wall chance constraint (``r_min``; 0 for means only).
    separator : MinmaxResult, optional
        The minmax of ``positions`` against the obstacles if already computed (P, N).
    """
    P, N = request.num_obstacles, request.horizon_steps
    if P:
        if separator is None:
            separator = request.covariance_pairs.minmax(np.broadcast_to(positions[None], (P, N, 3)),
                                                        request.obstacle_means)
        res = separator
        eta, distance = pair_kernels.exact_figures(res.normal, res.s1, res.s2, request.obstacle_means, positions,
                                                   request.obstacle_radii, drone_radius_m)
        lam = res.lam
    else:
        eta = lam = distance = np.zeros((0, N))
    # a.p_i + r sqrt(a' S_i a) + R_drone <= b
    a, b = request.walls_normal, request.walls_offset
    wall_margin = b[:, None] - a @ positions.T - wall_radius * request.wall_spread - drone_radius_m
    return SafetyFigures(
        eta=eta,
        wall_margin=wall_margin,
        distance_margin=distance,
        lam=lam,
    )
