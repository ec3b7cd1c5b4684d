"""Per (obstacle, step) pair, from the minmax separator: the hyperplane rows and the exact figures.

Two loops over the ``P x N`` pairs of a request, each of which replaces about ten
whole-array numpy operations of a few microseconds each (the arrays hold 120 pairs in
the planner's usual shape, so call overhead, not arithmetic, is their cost):

- :func:`hyperplane_rows`: the ``hyperplane`` formulation's row at every pair,
  ``-n . p >= (r_min + backoff) (s1 + s2) + R - n . o`` and its ``c_max`` side;
- :func:`exact_figures`: the radius-aware touch radius ``eta = (n . (o - p) - R) / (s1 + s2)``
  and the centre distance ``|o - p| - R`` of the exact recheck;
- :func:`touch_terms`: from ``eta``, the arguments of the special functions that give a
  plan's contour of touch and overlap.

``n``, ``s1``, ``s2`` come from :class:`companion.core.overlap.MinmaxResult`; ``o`` are
the obstacle means (P, N, 3) and ``p`` the drone positions (N, 3), NED metres;
``R = R_obstacle + R_drone``, metres.

Both compute in the order their numpy forms below compute (:func:`dot3` sums the axes
in order from +0; the norm is numpy's, ``sqrt((x^2 + y^2) + z^2)``), so either gives the
same bits (``tests/core/test_jit.py`` compares them). Before this module the dot products
were ``np.einsum``, whose order depends on the operands' memory layout (the separator's
normal is a strided view, for which it sums as :func:`dot3` does; on a contiguous copy
it pairs the first and third axes); writing the order out makes the figures independent
of layout.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core import jit


def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``sum_k a_k b_k`` over the last axis (length 3), summed from +0 in the axes' order."""
    return ((0.0 + a[..., 0] * b[..., 0]) + a[..., 1] * b[..., 1]) + a[..., 2] * b[..., 2]


def _strided(t, ndim):
    """numba's type of a float64 input array of ``ndim`` dimensions, any strides, read-only or not."""
    return t.Array(t.float64, ndim, "A", readonly=True)


def _rows_signature(t):
    """Separator (P, N, 3), (P, N), (P, N), means (P, N, 3), radii (P,), three scalars; rows out."""
    w2, w3 = t.float64[:, ::1], t.float64[:, :, ::1]
    return t.void(_strided(t, 3), _strided(t, 2), _strided(t, 2), _strided(t, 3), _strided(t, 1),
                  t.float64, t.float64, t.boolean, w3, w2, w2)


@jit.lazy(_rows_signature)
def _hyperplane_rows(normal, s1, s2, means, radius_sum, lower_radius, upper_radius, has_upper,
                     coef_p, lower, upper):
    """:func:`hyperplane_rows` per pair: ``coef_p = -n``, ``lower``, ``upper`` (inf without ``c_max``)."""
    for j in range(normal.shape[0]):
        r = radius_sum[j]
        for i in range(normal.shape[1]):
            n0, n1, n2 = normal[j, i, 0], normal[j, i, 1], normal[j, i, 2]
            n_o = ((0.0 + n0 * means[j, i, 0]) + n1 * means[j, i, 1]) + n2 * means[j, i, 2]
            ssum = s1[j, i] + s2[j, i]
            lower[j, i] = lower_radius * ssum + r - n_o
            upper[j, i] = upper_radius * ssum + r - n_o if has_upper else math.inf
            coef_p[j, i, 0], coef_p[j, i, 1], coef_p[j, i, 2] = -n0, -n1, -n2


def hyperplane_rows(normal: np.ndarray, s1: np.ndarray, s2: np.ndarray, means: np.ndarray,
                    radius_sum: np.ndarray, lower_radius: float,
                    upper_radius: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(coef_p, lower, upper)`` of the ``hyperplane`` rows, (P, N, 3), (P, N), (P, N).

    ``lower_radius``: ``r_min`` plus the back-off, ``upper_radius``: ``r_max`` or None (then
    ``upper`` is inf), Mahalanobis units; ``radius_sum`` (P,) metres.
    """
    means, radius_sum = np.asarray(means, dtype=float), np.asarray(radius_sum, dtype=float)
    if jit.available():
        coef_p, lower, upper = np.empty(normal.shape), np.empty(s1.shape), np.empty(s1.shape)
        _hyperplane_rows()(normal, s1, s2, means, radius_sum, float(lower_radius),
                           0.0 if upper_radius is None else float(upper_radius), upper_radius is not None,
                           coef_p, lower, upper)
        return coef_p, lower, upper
    ssum = s1 + s2
    n_o = dot3(normal, means)
    lower = lower_radius * ssum + radius_sum[:, None] - n_o
    upper = (upper_radius * ssum + radius_sum[:, None] - n_o if upper_radius is not None
             else np.full_like(lower, np.inf))
    return -normal, lower, upper


def _figures_signature(t):
    """Separator (P, N, 3), (P, N), (P, N), means (P, N, 3), positions (N, 3), radii (P,), a scalar; figures out."""
    w2 = t.float64[:, ::1]
    return t.void(_strided(t, 3), _strided(t, 2), _strided(t, 2), _strided(t, 3), _strided(t, 2), _strided(t, 1),
                  t.float64, w2, w2)


@jit.lazy(_figures_signature)
def _exact_figures(normal, s1, s2, means, positions, radii, drone_radius, eta, distance):
    """:func:`exact_figures` per pair."""
    for j in range(normal.shape[0]):
        r = radii[j] + drone_radius
        for i in range(normal.shape[1]):
            dx = means[j, i, 0] - positions[i, 0]
            dy = means[j, i, 1] - positions[i, 1]
            dz = means[j, i, 2] - positions[i, 2]
            n_d = ((0.0 + normal[j, i, 0] * dx) + normal[j, i, 1] * dy) + normal[j, i, 2] * dz
            eta[j, i] = (n_d - r) / (s1[j, i] + s2[j, i])
            distance[j, i] = math.sqrt((dx * dx + dy * dy) + dz * dz) - r


def exact_figures(normal: np.ndarray, s1: np.ndarray, s2: np.ndarray, means: np.ndarray, positions: np.ndarray,
                  radii: np.ndarray, drone_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """``(eta, distance)`` (P, N): the radius-aware touch radius (Mahalanobis units) and ``|o - p| - R`` (metres)."""
    means, positions = np.asarray(means, dtype=float), np.asarray(positions, dtype=float)
    radii = np.asarray(radii, dtype=float)
    if jit.available():
        eta, distance = np.empty(s1.shape), np.empty(s1.shape)
        _exact_figures()(normal, s1, s2, means, positions, radii, float(drone_radius), eta, distance)
        return eta, distance
    radius_sum = radii[:, None] + drone_radius
    delta = means - positions[None]
    eta = (dot3(normal, delta) - radius_sum) / (s1 + s2)
    return eta, np.linalg.norm(delta, axis=-1) - radius_sum


def _touch_signature(t):
    """``eta`` (P, N) in; the two arguments (P, N) out; whether ``eta`` holds a NaN."""
    w2 = t.float64[:, ::1]
    return t.boolean(_strided(t, 2), w2, w2)


@jit.lazy(_touch_signature)
def _touch_terms(eta, half_square, negative):
    """:func:`touch_terms` per pair; returns whether a NaN was seen (then the outputs are not used)."""
    nan = False
    for j in range(eta.shape[0]):
        for i in range(eta.shape[1]):
            e = eta[j, i]
            if e != e:
                nan = True
            m = e if e > 0.0 else 0.0          # np.maximum(eta, 0): +0 on a tie with -0
            half_square[j, i] = 0.5 * (m * m)
            negative[j, i] = -m
    return nan


def touch_terms(eta: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(0.5 max(eta, 0)^2, -max(eta, 0))`` (P, N), or None when ``eta`` holds a NaN or numba is absent.

    The arguments of ``gammainc(3/2, .)`` (the contour of touch, ``chi2_3.cdf(max(eta, 0)^2)``)
    and of ``ndtr`` (the overlap, ``2 ndtr(-max(eta, 0))``), as
    :func:`companion.core.overlap.confidence_from_radius` and
    :func:`companion.core.overlap.overlap_from_radius` form them (``np.maximum``, ``np.square``,
    the product by 0.5, the negation), in one pass instead of eight numpy calls. None sends the
    caller to those functions (which reject a NaN radius with their own error).
    """
    if not jit.available() or eta.ndim != 2:
        return None
    half_square, negative = np.empty(eta.shape), np.empty(eta.shape)
    if _touch_terms()(eta, half_square, negative):
        return None
    return half_square, negative
