"""Assemble a validated linear measurement ``z = H x + r``, ``r ~ N(0, R)``.

Position is always measured, velocity optionally::

    z = p           H = [I 0]        R = Rp
    z = [p, v]      H = I (6x6)      R = blockdiag(Rp, Rv)

Noise comes from the report where it gives one, else from configured standard
deviations. A bad input raises :class:`MeasurementRejected`, which the filters turn
into a rejected :class:`~estimator.results.UpdateResult` (they never raise).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from estimator.covariance import problem_3x3
from estimator.errors import EstimatorInputError
from estimator.results import Reason

logger = logging.getLogger(__name__)

#: Largest magnitude ``x`` for which ``x + x`` does not overflow (then ``0.5 * (x + x) == x``).
_HALF_MAX = np.finfo(float).max / 2.0

H_POSITION = np.hstack([np.eye(3), np.zeros((3, 3))])
"""Measurement matrix of a position-only report, (3, 6)."""
H_POSITION_VELOCITY = np.eye(6)
"""Measurement matrix of a position-and-velocity report, (6, 6)."""
for _H in (H_POSITION, H_POSITION_VELOCITY):
    _H.setflags(write=False)


class MeasurementRejected(EstimatorInputError):
    """Internal: a measurement failed validation; carries the :class:`Reason`."""

    def __init__(self, reason: Reason, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class Measurement:
    """A validated measurement.

    Attributes
    ----------
    z : numpy.ndarray, shape (m,)
        ``p`` or ``[p, v]`` (m, m/s, NED), m = 3 or 6.
    H : numpy.ndarray, shape (m, 6)
    R : numpy.ndarray, shape (m, m)
        Symmetric positive definite.
    """

    z: np.ndarray
    H: np.ndarray
    R: np.ndarray

    @property
    def has_velocity(self) -> bool:
        return self.z.size == 6


def assemble(
    pos: np.ndarray,
    vel: np.ndarray | None,
    pos_cov: np.ndarray | None,
    vel_cov: np.ndarray | None,
    *,
    position_std_m: float,
    velocity_std_mps: float,
) -> Measurement:
    """Validate a report and build ``(z, H, R)``.

    Parameters
    ----------
    pos : array_like, shape (3,)
        Position, m, NED.
    vel : array_like, shape (3,), or None
        Velocity, m/s, NED, if reported.
    pos_cov, vel_cov : array_like, shape (3,) or (3, 3), or None
        Either per-axis variances (``ODOMETRY`` diagonal; NaN entries mean unknown and
        fall back to the configured noise on that axis) or a full covariance (all-NaN
        means unknown). ``None``: configured noise.
    position_std_m, velocity_std_mps : float
        Configured 1-sigma noise per axis.

    Returns
    -------
    Measurement

    Raises
    ------
    MeasurementRejected
        With reason ``non_finite``, ``invalid_shape`` or ``invalid_covariance``.
    """
    p = _vector(pos, "position")
    Rp = _noise(pos_cov, position_std_m, "position")
    if vel is None:
        return Measurement(p, H_POSITION, Rp)
    v = _vector(vel, "velocity")
    Rv = _noise(vel_cov, velocity_std_mps, "velocity")
    R = np.zeros((6, 6))
    R[:3, :3] = Rp
    R[3:, 3:] = Rv
    return Measurement(np.concatenate([p, v]), H_POSITION_VELOCITY, R)


def _vector(value: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.shape != (3,):
        raise MeasurementRejected(Reason.INVALID_SHAPE, f"{name} has shape {a.shape}, expected (3,)")
    if not all(math.isfinite(x) for x in a.tolist()):   # three Python floats: cheaper than np.all(np.isfinite())
        raise MeasurementRejected(Reason.NON_FINITE, f"{name} is not finite: {a.tolist()}")
    return a


def _noise(cov: np.ndarray | None, std: float, name: str) -> np.ndarray:
    default_var = std * std
    if cov is None:
        return default_var * np.eye(3)
    c = np.asarray(cov, dtype=float)
    if c.shape == (3,):
        # per-axis variances: NaN = unknown on that axis (PX4 convention)
        # on three Python floats: cheaper than np.where / np.isfinite / np.any on three numbers
        var = [default_var if math.isnan(x) else x for x in c.tolist()]
        if not all(math.isfinite(x) and x > 0.0 for x in var):
            raise MeasurementRejected(
                Reason.INVALID_COVARIANCE, f"{name} variances must be finite and > 0, got {c.tolist()}"
            )
        return np.diag(var)
    if c.shape == (3, 3):
        rows = c.tolist()
        if math.isnan(rows[0][0]) and all(math.isnan(x) for row in rows for x in row):    # all NaN: unknown
            return default_var * np.eye(3)
        problem = problem_3x3(rows)
        if problem is not None:
            raise MeasurementRejected(Reason.INVALID_COVARIANCE, f"{name} {problem}: {rows}")
        (a, b, c_), (d, e, f), (g, h, i) = rows
        if b == d and c_ == g and f == h and max(abs(a), abs(b), abs(c_), abs(e), abs(f), abs(i)) <= _HALF_MAX:
            return c.copy()     # already symmetric: (C + C') / 2 is C, bit for bit (x + x does not overflow)
        # (C + C') / 2 on the Python floats already read: symmetrise's bits, a third of its time
        return np.array([[0.5 * (rows[i][j] + rows[j][i]) for j in range(3)] for i in range(3)])
    raise MeasurementRejected(
        Reason.INVALID_SHAPE, f"{name} covariance has shape {c.shape}, expected (3,) or (3, 3)"
    )
