"""Covariance helpers: PX4 ``ODOMETRY`` covariance arrays and validity checks.

``ODOMETRY.pose_covariance`` and ``ODOMETRY.velocity_covariance`` hold the upper
triangle of a symmetric 6x6 matrix, row-major, 21 floats. For the pose the rows are
``x, y, z, roll, pitch, yaw`` (so indices 0, 6, 11 are the x, y, z variances and 15,
18, 20 roll, pitch, yaw); for the velocity ``vx, vy, vz, rollspeed, pitchspeed,
yawspeed``. NaN in element 0 means the covariance is unknown. PX4 fills only the
diagonal. Frames follow the message (``LOCAL_NED`` for PX4: m^2 and m^2/s^2).

These functions are pure parsers; the filters decide what to do with what they return.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from estimator.errors import EstimatorInputError

logger = logging.getLogger(__name__)

UPPER_TRIANGLE_LEN = 21
"""Number of elements in the upper triangle of a 6x6 matrix."""

XYZ_VARIANCE_INDICES = (0, 6, 11)
"""Indices of the x, y, z variances in the 21-element upper triangle."""

_ROWS, _COLS = np.triu_indices(6)  # row-major order of the upper triangle
_TINY = float(np.finfo(float).tiny)


def upper_triangle_to_matrix(arr21: np.ndarray | list[float]) -> np.ndarray:
    """Expand a row-major 21-element upper triangle into the symmetric 6x6 matrix.

    Parameters
    ----------
    arr21 : array_like, shape (21,)
        ``[c00, c01, ..., c05, c11, c12, ..., c55]``. NaNs are passed through.

    Returns
    -------
    numpy.ndarray, shape (6, 6)
        Symmetric matrix with ``M[i, j] = M[j, i]`` taken from the triangle.

    Raises
    ------
    EstimatorInputError
        If ``arr21`` does not hold exactly 21 numbers.
    """
    a = _as_triangle(arr21)
    M = np.empty((6, 6))
    M[_ROWS, _COLS] = a
    M[_COLS, _ROWS] = a
    return M


def position_variances(arr21: np.ndarray | list[float]) -> np.ndarray | None:
    """x, y, z variances from an ``ODOMETRY.pose_covariance`` array.

    Parameters
    ----------
    arr21 : array_like, shape (21,)
        Row-major upper triangle of the pose covariance (m^2, NED for ``LOCAL_NED``).

    Returns
    -------
    numpy.ndarray, shape (3,), or None
        Elements 0, 6, 11 (m^2); ``None`` when element 0 is NaN (covariance unknown).
        Other NaN entries are passed through: :class:`~estimator.DroneFilter` then uses
        its configured noise on those axes.
    """
    a = _as_triangle(arr21)
    if np.isnan(a[0]):
        return None
    return a[list(XYZ_VARIANCE_INDICES)].copy()


def velocity_variances(arr21: np.ndarray | list[float]) -> np.ndarray | None:
    """vx, vy, vz variances from an ``ODOMETRY.velocity_covariance`` array (m^2/s^2).

    Same layout and NaN convention as :func:`position_variances`.
    """
    return position_variances(arr21)


def position_covariance(arr21: np.ndarray | list[float]) -> np.ndarray | None:
    """Full 3x3 x, y, z block of a pose (or velocity) covariance array.

    Parameters
    ----------
    arr21 : array_like, shape (21,)
        Row-major upper triangle.

    Returns
    -------
    numpy.ndarray, shape (3, 3), or None
        Upper-left block of :func:`upper_triangle_to_matrix` (m^2), ``None`` when
        element 0 is NaN (unknown).
    """
    a = _as_triangle(arr21)
    if np.isnan(a[0]):
        return None
    return upper_triangle_to_matrix(a)[:3, :3].copy()


def covariance_problem(cov: np.ndarray, *, rtol: float = 1e-9) -> str | None:
    """Say why ``cov`` is not a usable covariance, or return ``None`` if it is.

    Usable means finite, symmetric (to ``rtol`` of its largest entry) and positive
    definite (a Cholesky factorisation exists).

    Parameters
    ----------
    cov : numpy.ndarray, shape (n, n)
        Candidate covariance.
    rtol : float
        Relative tolerance on ``|C - C'|``.

    Returns
    -------
    str or None
        A short human-readable reason, or ``None``.
    """
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        return f"covariance has shape {cov.shape}, expected square"
    if cov.shape == (3, 3):
        return problem_3x3(cov.tolist(), rtol)
    if not np.all(np.isfinite(cov)):
        return "covariance has non-finite entries"
    scale = max(float(np.max(np.abs(cov))), _TINY)
    if np.max(np.abs(cov - cov.T)) > rtol * scale:
        return "covariance is not symmetric"
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return "covariance is not positive definite"
    return None


def problem_3x3(c: list[list[float]], rtol: float = 1e-9) -> str | None:
    """:func:`covariance_problem` for a 3x3 given as three rows of Python floats (3 to 6 us a
    report against 23 to 31 us with numpy).

    The same checks in the same order; positive definiteness by the Cholesky pivots in
    closed form (each must be positive, as LAPACK's factorisation requires).
    """
    (a, b, c_), (d, e, f), (g, h, i) = c
    # a sum of finite entries is finite unless it overflows; only then (or with an infinite or
    # NaN entry) are they looked at one by one
    if (not math.isfinite(a + b + c_ + d + e + f + g + h + i)
            and not all(math.isfinite(x) for x in (a, b, c_, d, e, f, g, h, i))):
        return "covariance has non-finite entries"
    scale = max(abs(a), abs(b), abs(c_), abs(d), abs(e), abs(f), abs(g), abs(h), abs(i), _TINY)
    if max(abs(b - d), abs(c_ - g), abs(f - h)) > rtol * scale:
        return "covariance is not symmetric"
    # Cholesky of the lower triangle (LAPACK reads one triangle): pivots l11^2, l22^2, l33^2
    if not a > 0.0:
        return "covariance is not positive definite"
    l11 = math.sqrt(a)
    l21, l31 = d / l11, g / l11
    p2 = e - l21 * l21
    if not p2 > 0.0:
        return "covariance is not positive definite"
    l22 = math.sqrt(p2)
    l32 = (h - l31 * l21) / l22
    if not i - l31 * l31 - l32 * l32 > 0.0:
        return "covariance is not positive definite"
    return None


def symmetrise(cov: np.ndarray) -> np.ndarray:
    """``(C + C') / 2``: removes the rounding asymmetry left by matrix products."""
    return 0.5 * (cov + cov.T)


def _as_triangle(arr21: np.ndarray | list[float]) -> np.ndarray:
    a = np.asarray(arr21, dtype=float).reshape(-1)
    if a.size != UPPER_TRIANGLE_LEN:
        raise EstimatorInputError(
            f"covariance upper triangle must have {UPPER_TRIANGLE_LEN} elements, got {a.size}"
        )
    return a
