"""Result types of the estimator: states, update outcomes and counters."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

logger = logging.getLogger(__name__)


class Reason(StrEnum):
    """Why an update was accepted or rejected (``UpdateResult.reason``; compares equal to its string)."""

    UPDATED = "updated"
    """Accepted: predicted to the measurement time and corrected."""
    INITIALISED = "initialised"
    """Accepted: first measurement, the filter was created from it."""
    REINITIALISED = "reinitialised"
    """Accepted: the gap since the last accepted measurement exceeded ``reinit_gap_s``, or the
    gate had refused ``reinit_after_gated`` measurements in a row; the filter starts again from it."""
    OUT_OF_ORDER = "out_of_order"
    """Rejected: timestamp older than the last accepted measurement."""
    DUPLICATE = "duplicate"
    """Rejected: timestamp equal to the last accepted measurement."""
    NON_FINITE = "non_finite"
    """Rejected: NaN or infinite time, position or velocity."""
    INVALID_SHAPE = "invalid_shape"
    """Rejected: an array had the wrong shape."""
    INVALID_COVARIANCE = "invalid_covariance"
    """Rejected: a reported covariance (or variance) was not finite, symmetric, positive definite."""
    GATED = "gated"
    """Rejected: normalised innovation squared above the chi-square gate."""
    ADOPTED = "adopted"
    """Accepted: the report is an estimate already filtered upstream (the autopilot's), taken as the state."""


ACCEPTED_REASONS = frozenset({Reason.UPDATED, Reason.INITIALISED, Reason.REINITIALISED, Reason.ADOPTED})


@dataclass(frozen=True, eq=False)  # arrays: no element-wise == (compare .mean/.cov explicitly)
class GaussianState:
    """A Gaussian estimate of ``[p, v]`` at one time.

    Attributes
    ----------
    t_s : float
        Time of validity, seconds (message time base).
    mean : numpy.ndarray, shape (6,)
        ``[p_n, p_e, p_d, v_n, v_e, v_d]``, m and m/s, local NED. Read-only.
    cov : numpy.ndarray, shape (6, 6)
        Covariance (m^2, m^2/s, m^2/s^2 blocks), symmetric positive definite. Read-only.
    """

    t_s: float
    mean: np.ndarray
    cov: np.ndarray

    def __post_init__(self) -> None:
        for name in ("mean", "cov"):
            a = np.array(getattr(self, name), dtype=float)  # own copy
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def position(self) -> np.ndarray:
        """Position mean, m, NED, shape (3,)."""
        return self.mean[:3]

    @property
    def velocity(self) -> np.ndarray:
        """Velocity mean, m/s, NED, shape (3,)."""
        return self.mean[3:]

    @property
    def position_cov(self) -> np.ndarray:
        """Position covariance, m^2, shape (3, 3)."""
        return self.cov[:3, :3]

    @property
    def velocity_cov(self) -> np.ndarray:
        """Velocity covariance, m^2/s^2, shape (3, 3)."""
        return self.cov[3:, 3:]


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update.

    Attributes
    ----------
    accepted : bool
        Whether the measurement changed the estimate.
    reason : str
        A :class:`Reason` value (``"updated"``, ``"gated"``, ...).
    t_s : float
        Timestamp of the measurement, seconds.
    nis : float
        Normalised innovation squared ``y' S^-1 y`` against the prediction; NaN
        when no innovation was formed (initialisation, rejection before the
        prediction).
    dof : int
        Measurement dimension (degrees of freedom of ``nis``): 3 or 6; 0 with NaN nis.
    detail : str
        Human-readable explanation (empty when accepted).
    """

    accepted: bool
    reason: str
    t_s: float
    nis: float = float("nan")
    dof: int = 0
    detail: str = ""


@dataclass(frozen=True)
class FilterStats:
    """Counters of update outcomes since construction, one per :class:`Reason`."""

    updated: int = 0
    initialised: int = 0
    reinitialised: int = 0
    out_of_order: int = 0
    duplicate: int = 0
    non_finite: int = 0
    invalid_shape: int = 0
    invalid_covariance: int = 0
    gated: int = 0
    adopted: int = 0

    @property
    def accepted(self) -> int:
        """Measurements that changed an estimate."""
        return self.updated + self.initialised + self.reinitialised + self.adopted

    @property
    def rejected(self) -> int:
        """Measurements ignored, for any reason."""
        return (
            self.out_of_order + self.duplicate + self.non_finite + self.invalid_shape
            + self.invalid_covariance + self.gated
        )


@dataclass(frozen=True)
class TrackerStats(FilterStats):
    """:class:`FilterStats` summed over all tracks, plus track bookkeeping."""

    tracks_created: int = 0
    tracks_dropped: int = 0
    active_tracks: int = 0
