"""The 3x3 minmax separator as one compiled loop over pairs (numba), the planner's hot kernel.

Same procedure as :func:`companion.core.overlap._minmax` for ``d = 3`` (docs/METHOD.md
section 1.1): with ``t = lam / (1 - lam)``, ``A(t) = t S1 + S2`` and ``x = A^-1 delta``, a
safeguarded Newton iteration on ``phi(u) = 2u + log(x'S1x) - log(x'S2x)`` in ``u = log t``
(strictly increasing, slope 2 at both ends), started at the geometric mean of the
generalised eigenvalues, then the separator at the root. Each pair is a few hundred
scalar floating-point operations on 3x3 adjugates, with no temporary arrays, so the
planner's 120 pairs per call cost microseconds instead of the ~300 whole-array numpy
calls of the vectorised kernel.

Why numba (a runtime dependency): measured on the planner's batch (120 pairs) it is about
18x faster than the vectorised numpy kernel and on 10,000 pairs about 4.5x
(docs/PERFORMANCE.md); it installs from a wheel with no compile step at install. The
module imports numba only on the first call, which compiles the function or loads it from
its disk cache (``cache=True``): only the first process after an install (or a change of
this file) pays the compilation; every planning process pays the import and the load. Without numba the numpy kernel runs
(:data:`COMPILED` is then False); the tests compare the two.

Inputs are validated by the caller (:class:`companion.core.overlap.CovariancePairs`).
"""

from __future__ import annotations

import functools
import importlib.util
import logging
import math

import numpy as np

logger = logging.getLogger(__name__)

#: Whether numba is installed (then 3x3 pairs use the compiled kernel). numba itself is
#: imported, and the kernel compiled or loaded from its cache, on first use only.
COMPILED = importlib.util.find_spec("numba") is not None

#: Newton stops once a step in ``u`` is below this (relative to max(1, |u|)); as in overlap.
U_TOL = 1e-10
MAX_NEWTON = 60


def _minmax3(s1, s2, delta, u_tol, max_newton, t_out, lam, x_out, q1_out, q2_out, stalled):
    """Per pair ``p``: root ``t`` of the admissibility condition and ``x = A(t)^-1 delta``.

    ``s1``, ``s2``: (3, 3, n) symmetric positive definite; ``delta``: (3, n), nonzero.
    Writes ``t_out`` and ``lam`` (n,), ``x_out`` (3, n),
    ``q1_out = x'S1x``, ``q2_out = x'S2x``, ``stalled`` (n,) 1 where Newton hit its cap.
    """
    n = delta.shape[1]
    for p in range(n):
        a, b, c, d, e, f = s1[0, 0, p], s1[0, 1, p], s1[0, 2, p], s1[1, 1, p], s1[1, 2, p], s1[2, 2, p]
        aa, bb, cc, dd, ee, ff = s2[0, 0, p], s2[0, 1, p], s2[0, 2, p], s2[1, 1, p], s2[1, 2, p], s2[2, 2, p]
        dx, dy, dz = delta[0, p], delta[1, p], delta[2, p]
        det1 = a * (d * f - e * e) + b * (c * e - b * f) + c * (b * e - c * d)
        det2 = aa * (dd * ff - ee * ee) + bb * (cc * ee - bb * ff) + cc * (bb * ee - cc * dd)
        u = 0.5 * (math.log(det2) - math.log(det1)) / 3.0
        lo, hi = -math.inf, math.inf
        converged = False
        for k in range(max_newton + 1):     # the last pass only evaluates x at the final u
            t = math.exp(u)
            g00, g01, g02 = t * a + aa, t * b + bb, t * c + cc
            g11, g12, g22 = t * d + dd, t * e + ee, t * f + ff
            c00, c01, c02 = g11 * g22 - g12 * g12, g02 * g12 - g01 * g22, g01 * g12 - g02 * g11
            c11, c12, c22 = g00 * g22 - g02 * g02, g01 * g02 - g00 * g12, g00 * g11 - g01 * g01
            det = g00 * c00 + g01 * c01 + g02 * c02
            x0 = (c00 * dx + c01 * dy + c02 * dz) / det
            x1 = (c01 * dx + c11 * dy + c12 * dz) / det
            x2 = (c02 * dx + c12 * dy + c22 * dz) / det
            y0, y1, y2 = a * x0 + b * x1 + c * x2, b * x0 + d * x1 + e * x2, c * x0 + e * x1 + f * x2
            q1 = x0 * y0 + x1 * y1 + x2 * y2
            q2 = x0 * (aa * x0 + bb * x1 + cc * x2) + x1 * (bb * x0 + dd * x1 + ee * x2) + x2 * (cc * x0 + ee * x1 + ff * x2)
            if converged or k == max_newton:
                break
            w = (y0 * (c00 * y0 + c01 * y1 + c02 * y2) + y1 * (c01 * y0 + c11 * y1 + c12 * y2)
                 + y2 * (c02 * y0 + c12 * y1 + c22 * y2)) / det     # (S1x)' A^-1 (S1x)
            v = q1 - t * w
            phi = 2.0 * u + math.log(q1) - math.log(q2)
            dphi = 2.0 - 2.0 * t * w / q1 + 2.0 * t * v / q2
            # safeguard: keep the bracket the signs have shown; bisect where Newton leaves it
            if phi < 0.0 and u > lo:
                lo = u
            if phi > 0.0 and u < hi:
                hi = u
            step = -phi / dphi
            new_u = u + step
            if math.isinf(lo) or math.isinf(hi):
                new_u = u + min(max(step, -4.0), 4.0)
            else:
                slack = 1e-12 * (1.0 + abs(u))
                if new_u < lo - slack or new_u > hi + slack:
                    new_u = 0.5 * (lo + hi)
            converged = abs(new_u - u) <= u_tol * max(1.0, abs(u))
            u = new_u
        stalled[p] = 0 if converged else 1
        t_out[p] = t
        lam[p] = t / (1.0 + t)
        x_out[0, p], x_out[1, p], x_out[2, p] = x0, x1, x2
        q1_out[p], q2_out[p] = q1, q2


@functools.cache
def _compiled():
    """The numba-compiled :func:`_minmax3` (compiled, or loaded from the disk cache, on first call)."""
    import numba

    return numba.njit(cache=True, nogil=True)(_minmax3)


def root_and_solution(s1: np.ndarray, s2: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, ...]:
    """``t``, ``lam``, ``x = A(t)^-1 delta`` (3, n), ``q1 = x'S1x``, ``q2 = x'S2x`` at the admissible root.

    Parameters
    ----------
    s1, s2 : (3, 3, n) arrays
        Validated symmetric positive definite covariances, square metres.
    delta : (3, n) array
        ``mu2 - mu1``, nonzero (coincident means replaced by the caller), metres.
    """
    n = delta.shape[1]
    t, lam = np.empty(n), np.empty(n)
    x, q1, q2 = np.empty((3, n)), np.empty(n), np.empty(n)
    stalled = np.zeros(n, dtype=np.int8)
    _compiled()(np.ascontiguousarray(s1), np.ascontiguousarray(s2), np.ascontiguousarray(delta),
                      U_TOL, MAX_NEWTON, t, lam, x, q1, q2, stalled)
    if stalled.any():
        logger.warning("minmax: Newton iteration hit %d steps on %d pair(s)", MAX_NEWTON, int(stalled.sum()))
    return t, lam, x, q1, q2


def warm_up() -> None:
    """Compile (or load from the disk cache) the kernel now, on one pair.

    The planning process calls this before it says it is ready, so that the first replan
    of a flight does not pay the compilation (seconds on a fresh install).
    """
    if COMPILED:
        eye = np.eye(3)[:, :, None].copy()
        root_and_solution(eye, 2.0 * eye, np.array([[1.0], [0.0], [0.0]]))
