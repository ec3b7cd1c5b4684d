"""What the planner is asked (:class:`PlanRequest`) and what it answers (:class:`Plan`).

All arrays are in the local NED frame: positions in metres, velocities in m/s,
covariances in m^2. Step ``i`` (1-based in the docs, index ``i - 1`` in arrays) is the
time ``i * tau`` after the request.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from companion.core import covariance_checks, jit, small_matrix
from companion.core.overlap import CovariancePairs
from companion.errors import InputError

logger = logging.getLogger(__name__)

#: Status of a plan: converged without safety slack / slack used (constraints violated,
#: by ``Plan.slack_max``) / solver failure or the exact recheck failed.
STATUSES: tuple[str, ...] = ("optimal", "slack", "failed")


def _array(name: str, value: object, shape: tuple[int | None, ...]) -> np.ndarray:
    """Float copy of ``value`` with the given shape (``None`` = any length), finite, read-only."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} is not a numeric array: {value!r}") from None
    if arr.ndim != len(shape) or any(s is not None and a != s for a, s in zip(arr.shape, shape)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"{name} has shape {arr.shape}, expected {want}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} contains NaN or inf")
    arr.setflags(write=False)
    return arr


def _check_covariances(name: str, covs: np.ndarray) -> None:
    """Raise :class:`InputError` unless every (3, 3) matrix is symmetric positive definite."""
    if covs.size == 0:
        return
    if jit.available() and covariance_checks.all_valid3(covs):    # the same tests, compiled; numpy words a failure
        return
    asym = np.max(np.abs(covs - np.swapaxes(covs, -1, -2)), axis=(-1, -2))
    scale = np.max(np.abs(covs), axis=(-1, -2))
    bad = asym > 1e-9 * np.maximum(scale, 1e-12) + 1e-15
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{name}{list(idx)} is not symmetric: {covs[idx].tolist()}")
    # Sylvester's criterion in closed form (the 3x3 kernel); eigenvalues only to word an error
    pd = small_matrix.is_positive_definite(np.moveaxis(covs.reshape(-1, 3, 3), 0, -1)).reshape(covs.shape[:-2])
    if not np.all(pd):
        eig_min = np.linalg.eigvalsh(covs)[..., 0]
        idx = tuple(int(i) for i in np.argwhere(~pd)[0])
        raise InputError(f"{name}{list(idx)} is not positive definite (smallest eigenvalue {eig_min[idx]:.3g} m^2)")


@dataclass(frozen=True)
class PlanRequest:
    """One planning problem (validated on construction; arrays are read-only copies).

    Parameters
    ----------
    position : (3,) array
        Drone position estimate now, NED metres.
    velocity : (3,) array
        Drone velocity estimate now, NED m/s (``V_0`` of the acceleration bound).
    drone_covs : (N, 3, 3) array
        Predicted drone position covariance at steps 1..N, m^2.
    target : (3,) array
        Where the drone should be at step N, NED metres.
    obstacle_means : (P, N, 3) array
        Predicted obstacle means at steps 1..N, NED metres (static obstacles: constant).
    obstacle_covs : (P, N, 3, 3) array
        Predicted obstacle position covariances at steps 1..N, m^2.
    obstacle_radii : (P,) array
        Obstacle physical radii, metres.
    walls_normal : (W, 3) array
        Unit normals ``a`` of half-spaces ``a . p <= b`` of free space (normalised here).
    walls_offset : (W,) array
        Offsets ``b``, metres.
    upper_bound_mask : (P,) bool array, optional
        Obstacles the ``c_max`` upper bound applies to (default: all in sensing range).
        The caller decides which obstacle the drone is following, e.g. the one leading
        the way to the goal in a corridor; the bound is released for the others.
    obstacle_ranges_m : (P,) array, optional
        How far out each obstacle is planned around, metres (``inf`` allowed): an obstacle
        whose first predicted mean is farther from ``position`` than its range is left out of
        this plan. Default: the planner's ``sensing_range_m`` for every obstacle. A companion
        sets it per source: what its own sensors see from a few metres, what a transponder
        or a fleet peer announces by radio from much further.
    margin_cov : (3, 3) array, optional
        Tracking margin, m^2: added to the drone's covariance in the safety rows (obstacles
        and walls) at every step, not in the cost's Mahalanobis metric. It stands for how far
        the vehicle strays from a plan before the next replan, which the estimate's
        covariance does not carry; ``safety_covs`` is the sum.
    response_state : (3, 2) array, optional
        The vehicle response's internal state at the start, per NED axis: the velocity
        loop's error integral ``xi`` (m) and the acceleration ``a`` (m/s^2) of
        :class:`~companion.core.planner.vehicle_model.AxisResponse` (``a`` unused on an axis
        without an acceleration lag). Only with a response model; ``None`` starts from the
        steady state at ``velocity`` (the integral holding the drag of that speed).
    """

    position: np.ndarray
    velocity: np.ndarray
    drone_covs: np.ndarray
    target: np.ndarray
    obstacle_means: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    obstacle_covs: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3, 3)))
    obstacle_radii: np.ndarray = field(default_factory=lambda: np.zeros(0))
    walls_normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    walls_offset: np.ndarray = field(default_factory=lambda: np.zeros(0))
    upper_bound_mask: np.ndarray | None = None
    obstacle_ranges_m: np.ndarray | None = None
    margin_cov: np.ndarray | None = None
    response_state: np.ndarray | None = None

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("position", _array("position", self.position, (3,)))
        set_("velocity", _array("velocity", self.velocity, (3,)))
        set_("target", _array("target", self.target, (3,)))
        covs = _array("drone_covs", self.drone_covs, (None, 3, 3))
        n = covs.shape[0]
        if n < 1:
            raise InputError("drone_covs must hold at least one step")
        _check_covariances("drone_covs", covs)
        set_("drone_covs", covs)
        means = np.asarray(self.obstacle_means)
        if means.size == 0:
            means = np.zeros((0, n, 3))
        means = _array("obstacle_means", means, (None, n, 3))
        p = means.shape[0]
        ocovs = np.asarray(self.obstacle_covs)
        if ocovs.size == 0 and p == 0:
            ocovs = np.zeros((0, n, 3, 3))
        ocovs = _array("obstacle_covs", ocovs, (p, n, 3, 3))
        _check_covariances("obstacle_covs", ocovs)
        radii = _array("obstacle_radii", np.atleast_1d(self.obstacle_radii) if p else np.zeros(0), (p,))
        if np.any(radii < 0.0):
            raise InputError(f"obstacle_radii must be >= 0 m, got {radii.tolist()}")
        set_("obstacle_means", means)
        set_("obstacle_covs", ocovs)
        set_("obstacle_radii", radii)
        normals = _array("walls_normal", np.reshape(self.walls_normal, (-1, 3)), (None, 3))
        w = normals.shape[0]
        offsets = _array("walls_offset", np.atleast_1d(self.walls_offset) if w else np.zeros(0), (w,))
        norms = np.linalg.norm(normals, axis=1)
        if np.any(norms < 1e-9):
            raise InputError(f"walls_normal has a zero row: {normals.tolist()}")
        unit = normals / norms[:, None]
        set_("walls_normal", _array("walls_normal", unit, (w, 3)))
        set_("walls_offset", _array("walls_offset", offsets / norms, (w,)))
        if self.upper_bound_mask is None:
            mask = np.ones(p, dtype=bool)
        else:
            mask = np.asarray(self.upper_bound_mask)
            if mask.shape != (p,) or mask.dtype != bool:
                raise InputError(f"upper_bound_mask must be a boolean array of shape ({p},), got {self.upper_bound_mask!r}")
            mask = mask.copy()
        mask.setflags(write=False)
        set_("upper_bound_mask", mask)
        if self.obstacle_ranges_m is not None:
            try:
                ranges = np.array(np.atleast_1d(self.obstacle_ranges_m) if p else np.zeros(0), dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"obstacle_ranges_m is not a numeric array: {self.obstacle_ranges_m!r}") from None
            if ranges.shape != (p,) or np.isnan(ranges).any() or np.any(ranges <= 0.0):
                raise InputError(f"obstacle_ranges_m must be ({p},) ranges > 0 m (inf allowed), got {self.obstacle_ranges_m!r}")
            ranges.setflags(write=False)
            set_("obstacle_ranges_m", ranges)
        if self.margin_cov is None:
            set_("margin_cov", _array("margin_cov", np.zeros((3, 3)), (3, 3)))
            set_("safety_covs", covs)
        else:
            margin = _array("margin_cov", self.margin_cov, (3, 3))
            _check_covariances("margin_cov", margin[None] + np.eye(3)[None] * 1e-12)   # PSD: zero is allowed
            set_("margin_cov", margin)
            set_("safety_covs", _array("safety_covs", covs + margin, (n, 3, 3)))
        if self.response_state is not None:
            set_("response_state", _array("response_state", self.response_state, (3, 2)))

    @cached_property
    def covariance_pairs(self) -> CovariancePairs:
        """Drone (with the tracking margin) and obstacle covariances as validated pairs over (P, N), built once per request.

        Every minmax of this request (each SCP iterate's rows, the exact recheck) reuses
        them instead of validating the covariances again.
        """
        return CovariancePairs.shared_first(self.safety_covs, self.obstacle_covs)   # checked in __post_init__

    @cached_property
    def wall_spread(self) -> np.ndarray:
        """``sqrt(a' S_i a)`` (W, N), metres: the drone's standard deviation (with the margin) along each wall normal.

        Built once per request: the wall rows' right-hand sides and every exact recheck use it.
        """
        spread = np.sqrt(np.einsum("wk,nkl,wl->wn", self.walls_normal, self.safety_covs, self.walls_normal))
        spread.setflags(write=False)
        return spread

    @property
    def horizon_steps(self) -> int:
        """``N``, the number of predicted steps."""
        return int(self.drone_covs.shape[0])

    @property
    def num_obstacles(self) -> int:
        """``P``."""
        return int(self.obstacle_means.shape[0])

    @property
    def num_walls(self) -> int:
        """``W``."""
        return int(self.walls_normal.shape[0])


@dataclass(frozen=True)
class Plan:
    """Result of one trajectory optimisation (all SCP iterations).

    The safety figures (``eta``, ``contour_of_touch``, ``overlap``, ``wall_margin``) are
    recomputed with the exact overlap on the returned positions and covariances, not
    taken from the linearisation.

    Attributes
    ----------
    velocities : (N, 3) array
        Planned vehicle velocities ``V_1..V_N`` at the step ends, NED m/s.
    commands : (N, 3) array
        Velocity setpoints ``u_1..u_N`` to stream, each held ``tau``, NED m/s: equal to
        ``velocities`` without a velocity lag, leading them with one
        (:mod:`companion.core.planner.vehicle_model`).
    initial_velocity : (3,) array
        ``V_0``: the vehicle velocity the plan starts from (the request's, clipped to
        what the bounds can hold), NED m/s.
    initial_response_state : (3, 2) array or None
        The response model's internal state the plan starts from (the request's
        ``response_state``; ``None``: the steady state at ``initial_velocity``).
    positions : (N, 3) array
        Planned positions ``p_1..p_N``, NED metres.
    eta : (P, N) array
        Radius-aware Mahalanobis touch radius (support margin along the minmax normal:
        the radius at which the two ellipsoids, each inflated by its body radius, touch).
    contour_of_touch : (P, N) array
        ``chi2_3.cdf(eta^2)`` (0 where ``eta <= 0``).
    overlap : (P, N) array
        Overlap of Gaussians corresponding to ``contour_of_touch``.
    wall_margin : (W, N) array
        ``b - a.p_i - r_min sqrt(a' S_i a) - R_drone``, metres (>= 0: chance constraint holds).
    in_range : (P,) bool array
        Obstacles within sensing range (constrained); the others were ignored.
    status : str
        ``'optimal'``, ``'slack'`` or ``'failed'`` (see :data:`STATUSES`).
    iterations : int
        SCP iterations (QP solves).
    solve_time_s : float
        Wall time of the solve from ``time.perf_counter()``; a diagnostic only, it never
        influences the plan.
    slack_max : float
        Largest safety slack in the last QP (units of the violated row: metres for walls
        and the deterministic, hyperplane and bhattacharyya rows; ``paper`` rows are
        divided by the norm of their gradient, see :mod:`companion.core.planner.formulations`).
    cost : float
        Objective of the last QP at its solution (terminal + jerk + effort + penalties).
    formulation : str
        Which formulation produced the plan.
    notes : tuple of str
        Diagnostics, e.g. ``'max_iterations'``, ``'c_max_violated'``, ``'work_budget: ...'``,
        solver messages.
    work : int
        Work units this replan spent (ADMM iterations of all its QPs plus a fixed charge
        per QP, :mod:`companion.core.planner.budget`); at most ``replan_work_budget``.
    admm_iterations : int
        ADMM iterations summed over all QPs of this replan.
    """

    velocities: np.ndarray
    positions: np.ndarray
    eta: np.ndarray
    contour_of_touch: np.ndarray
    overlap: np.ndarray
    wall_margin: np.ndarray
    in_range: np.ndarray
    status: str
    iterations: int
    solve_time_s: float
    slack_max: float
    cost: float
    formulation: str
    commands: np.ndarray
    initial_velocity: np.ndarray
    notes: tuple[str, ...] = ()
    work: int = 0
    admm_iterations: int = 0
    initial_response_state: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """True when the plan is safe to fly as planned (status ``'optimal'``)."""
        return self.status == "optimal"

    @property
    def min_contour_of_touch(self) -> float:
        """Smallest contour of touch over in-range obstacles and steps (1.0 if none)."""
        c = self.contour_of_touch[self.in_range]
        return float(c.min()) if c.size else 1.0
