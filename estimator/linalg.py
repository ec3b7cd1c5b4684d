"""The inverse of small covariances: numpy's LAPACK call without numpy's Python layer around it.

A Kalman update inverts its innovation covariance ``S`` (3x3 or 6x6) once per report, and
the planner the drone's terminal covariance (3x3) once per replan. ``np.linalg.inv`` spends
most of its time on a 3x3 in Python: argument checks, type resolution and an ``errstate``
context around the one call that does the work, ``numpy.linalg._umath_linalg.inv`` (LAPACK's
``dgesv`` against the identity). Timed with ``timeit`` on a 3x3: 5.2 us against 1.6 us for
the call alone; inside the tracker's cycle, about 10 us a track update (docs/PERFORMANCE.md).

:func:`inverse` makes that call directly, so its result is ``np.linalg.inv``'s to the bit
(the call is the same; tests/estimator/test_estimator_linalg.py compares them). What the
Python layer did for exceptional inputs is kept by falling back to ``np.linalg.inv`` itself:
for anything but a float64 array of stacked non-empty square matrices, and when a matrix of
the result starts with NaN (a singular matrix: LAPACK's failure fills it with NaN, and
``np.linalg.inv`` raises ``LinAlgError``; a NaN in the input, which it returns as it is).
Two differences remain, both in warnings only: for a singular matrix numpy also warns
("invalid value encountered in inv") before the error, and an inverse that overflows warns
where ``np.linalg.inv`` is silent; the values and exceptions are the same. A numpy without
the private module gets ``np.linalg.inv`` every time.
"""

from __future__ import annotations

import math

import numpy as np

try:  # the gufunc np.linalg.inv calls (private: numpy.linalg's own import)
    from numpy.linalg import _umath_linalg
except ImportError:  # pragma: no cover - a numpy that moved it: the public call, same results
    _umath_linalg = None

__all__ = ["inverse", "DIRECT"]

#: Whether :func:`inverse` calls numpy's LAPACK gufunc directly (False: ``np.linalg.inv`` always).
DIRECT = _umath_linalg is not None and hasattr(_umath_linalg, "inv")


def inverse(a: np.ndarray) -> np.ndarray:
    """``np.linalg.inv(a)``, the same bits, for ``a`` a float64 array of shape (..., n, n).

    Parameters
    ----------
    a : ndarray
        Square matrices (the last two axes), for example covariances in m^2 (their inverse
        then in 1/m^2). Anything else goes to ``np.linalg.inv`` unchanged.

    Raises
    ------
    numpy.linalg.LinAlgError
        As ``np.linalg.inv`` does: a singular matrix, or not square.
    """
    if (not DIRECT or type(a) is not np.ndarray or a.dtype != np.float64 or a.ndim < 2
            or a.shape[-1] != a.shape[-2] or a.shape[-1] == 0):
        return np.linalg.inv(a)
    out = _umath_linalg.inv(a, signature="d->d")
    # LAPACK's failure (a singular matrix) fills that matrix of the result with NaN: its first
    # entry says so. numpy's own call then raises; so does it here, by making that call.
    if math.isnan(out[0, 0]) if out.ndim == 2 else np.isnan(out[..., 0, 0]).any():
        return np.linalg.inv(a)
    return out
