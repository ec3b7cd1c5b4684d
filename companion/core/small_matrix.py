"""Closed-form linear algebra on batches of small symmetric matrices (the overlap kernel).

One layout serves every caller: a batch of ``n`` symmetric ``d x d`` matrices is held
*batch-last*, as anything indexable ``m[i][j]`` giving a contiguous ``(n,)`` array (an
``(d, d, n)`` array or nested lists of ``(n,)`` arrays), and a batch of vectors as
``v[i]`` with ``v`` of shape ``(d, n)``. Elementwise numpy on contiguous 1-D arrays is
several times faster than on strided ``(n, d, d)`` views, and for ``d <= 3`` the
inverse, determinant and Sylvester's criterion are closed forms on the components
(larger ``d`` falls back to LAPACK).

Every function here assumes its input was validated (finite, symmetric; positive
definite where an inverse is taken): :mod:`companion.core.overlap` validates once.
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]


def matrices_to_components(a: Array) -> Array:
    """``(..., d, d)`` batch of matrices as a contiguous ``(d, d, n)`` array."""
    d = a.shape[-1]
    return np.ascontiguousarray(np.moveaxis(a.reshape(-1, d, d), 0, -1))


def vectors_to_components(v: Array) -> Array:
    """``(..., d)`` batch of vectors as a contiguous ``(d, n)`` array."""
    d = v.shape[-1]
    return np.ascontiguousarray(v.reshape(-1, d).T)


def from_components(v) -> Array:
    """A batch-last vector ``v[i]`` (``d`` arrays of shape ``(n,)``) back to ``(n, d)``."""
    return np.stack(list(v), axis=-1)


def _dense(m) -> Array:
    """Components to a dense ``(n, d, d)`` array (the LAPACK fallback for ``d > 3``)."""
    return np.stack([np.stack(list(row), axis=-1) for row in m], axis=-2)


def det(m) -> Array:
    """Determinants of a batch of symmetric matrices, ``(n,)``."""
    d = len(m)
    if d == 1:
        return m[0][0]
    if d == 2:
        return m[0][0] * m[1][1] - m[0][1] * m[0][1]
    if d == 3:
        a, b, c, dd, e, f = m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]
        return a * (dd * f - e * e) + b * (c * e - b * f) + c * (b * e - c * dd)
    return np.linalg.det(_dense(m))


def inv_sym(m) -> list[list[Array]]:
    """Inverses of a batch of symmetric positive definite matrices (adjugate for ``d <= 3``)."""
    d = len(m)
    if d == 1:
        return [[1.0 / m[0][0]]]
    if d == 2:
        det2 = m[0][0] * m[1][1] - m[0][1] * m[0][1]
        off = -m[0][1] / det2
        return [[m[1][1] / det2, off], [off, m[0][0] / det2]]
    if d == 3:
        a, b, c, dd, e, f = m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]
        c00 = dd * f - e * e
        c01 = c * e - b * f
        c02 = b * e - c * dd
        r = 1.0 / (a * c00 + b * c01 + c * c02)
        i00, i01, i02 = c00 * r, c01 * r, c02 * r
        i11 = (a * f - c * c) * r
        i12 = (b * c - a * e) * r
        i22 = (a * dd - b * b) * r
        return [[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]]
    inv = np.linalg.inv(_dense(m))
    return [[np.ascontiguousarray(inv[:, i, j]) for j in range(d)] for i in range(d)]


def is_positive_definite(m) -> NDArray[np.bool_]:
    """Sylvester's criterion (leading minors positive), ``(n,)`` booleans."""
    d = len(m)
    if d > 3:
        return np.all(np.linalg.eigvalsh(_dense(m)) > 0.0, axis=-1)
    ok = m[0][0] > 0.0
    if d >= 2:
        ok = ok & (m[0][0] * m[1][1] - m[0][1] * m[0][1] > 0.0)
    if d == 3:
        ok = ok & (det(m) > 0.0)
    return ok


def mv(m, v) -> list[Array]:
    """Matrix-vector products ``m v``."""
    return [sum(m[i][j] * v[j] for j in range(len(v))) for i in range(len(m))]


def dot(a, b) -> Array:
    """Inner products ``a . b``."""
    return sum(x * y for x, y in zip(a, b))


def quad(v, m) -> Array:
    """Quadratic forms ``v' m v``."""
    return dot(v, mv(m, v))


def axpy(t: Array | float, s1, s2) -> list[list[Array]]:
    """``t S1 + S2``."""
    return [[t * x + y for x, y in zip(r1, r2)] for r1, r2 in zip(s1, s2)]


def combine(a: Array | float, s1, b: Array | float, s2) -> list[list[Array]]:
    """``a S1 + b S2``."""
    return [[a * x + b * y for x, y in zip(r1, r2)] for r1, r2 in zip(s1, s2)]


def take(m, keep: NDArray[np.bool_] | NDArray[np.intp]):
    """The sub-batch ``keep`` of a matrix (nested) or vector batch."""
    if len(m) and isinstance(m[0], (list, tuple)) or (isinstance(m, np.ndarray) and m.ndim == 3):
        return [[c[keep] for c in row] for row in m]
    return [c[keep] for c in m]


def adjugate3(m: Array) -> Array:
    """Adjugates of a batch of symmetric 3x3 matrices given as a ``(3, 3, n)`` array (same layout)."""
    a, b, c, dd, e, f = m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2]
    c01, c02, c12 = c * e - b * f, b * e - c * dd, b * c - a * e
    return np.array([[dd * f - e * e, c01, c02], [c01, a * f - c * c, c12], [c02, c12, a * dd - b * b]])


def matvec(m: Array, v: Array) -> Array:
    """``m v`` for a ``(d, d, n)`` matrix batch and a ``(d, n)`` vector batch, as one array ``(d, n)``.

    Written as elementwise products and sums (not ``einsum``) so that every pair's result
    is the same bits whatever the batch it is computed in.
    """
    out = m[:, 0] * v[0]
    for j in range(1, v.shape[0]):
        out += m[:, j] * v[j]
    return out


def dots(a: Array, b: Array) -> Array:
    """Inner products of two ``(d, n)`` vector batches, ``(n,)`` (elementwise, batch-independent)."""
    out = a[0] * b[0]
    for j in range(1, a.shape[0]):
        out += a[j] * b[j]
    return out
