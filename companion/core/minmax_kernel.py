"""The 3x3 minmax separator as one compiled loop over pairs (numba): the planner's hot kernel.

Same procedure, same floating-point operations in the same order, as the vectorised numpy
kernel in :mod:`companion.core.overlap` (``_newton_polynomial`` and the separator that
follows it in ``_minmax``), written per pair instead of per whole array:

- the ten coefficients of the quartics ``n1(t)``, ``n2(t)`` are formed once per pair, and
  a safeguarded Newton iteration solves ``phi(u) = 2u + log(n1 / n2) = 0`` (bracket kept
  from the signs seen, bisection where Newton leaves it, steps capped at 4 until both
  ends are known);
- ``u = log t`` starts one fixed-point step from ``t = 1``: ``-0.5 log(n1(1) / n2(1))``,
  the coefficients' sums (the root where ``x`` does not turn with ``t``, as when
  ``S2 = g S1``);
- a pair stops after its first Newton step below ``u_tol`` (relative), or bisection step
  below ``u_tol**2`` (:func:`_newton_step`);
- the separator at the root from ``A(t)^-1 = adj(A) / det(A)``: ``lam``, ``eta``, the
  admissibility residual, ``alpha``, ``beta``, the unit normal, the support scales and the
  gradient of ``eta`` in ``mu1``; coincident means get ``eta = 0`` as in numpy.

So the results are the numpy kernel's bits where numpy's ``exp`` and ``log`` are the C
library's (the tests compare them bit for bit there; numpy's own AVX-512 versions differ
in the last bit, and the two kernels then agree to 1e-6 relative on the worst-conditioned
pairs), and a replay, a campaign or a figure does not depend on which kernel ran. Per
pair it is a few hundred scalar operations, with one small workspace per call: the
planner's 120 pairs per call cost microseconds instead of the ~300 whole-array numpy
calls of the vectorised kernel (docs/PERFORMANCE.md).

Why numba (a runtime dependency): it installs from a wheel with no compile step at
install; :mod:`companion.core.jit` says when the kernel is compiled or loaded. Without numba
the numpy kernel runs.

Inputs laid out batch last are validated by the caller
(:class:`companion.core.overlap.CovariancePairs`, whose 3-D checks and layout are
:func:`checked_pairs3` here); pairs given batch first, as to ``overlap.minmax``, are checked
by the kernel as it reads them (:func:`minmax3_as_given`), with the same helper.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core import jit


#: Pairs per block: the block's coefficients, inputs, Newton state and active list (about
#: 21 kB) stay in the first-level cache.
_BLOCK = 64


@jit.inline
def _checked_covariance(c00, c01, c02, c10, c11, c12, c20, c21, c22):
    """``(ok, a, b, c, d, e, f)``: whether the 3x3 covariance with these entries (square metres) is
    usable, and its upper triangle symmetrised (``0.5 (upper + lower)`` off the diagonal).

    Usable: every entry finite (``x - x`` is 0 for a finite ``x`` and NaN otherwise); each
    off-diagonal pair within ``1e-9`` of the largest entry's magnitude (plus ``1e-300``) of
    each other; positive definite by Sylvester's criterion on the symmetrised matrix with
    ``small_matrix.det``'s formula. The checks of ``overlap.CovariancePairs.from_arrays``
    with its arithmetic, so the same decisions.
    """
    finite = ((c00 - c00) + (c01 - c01) + (c02 - c02) + (c10 - c10) + (c11 - c11) + (c12 - c12)
              + (c20 - c20) + (c21 - c21) + (c22 - c22)) == 0.0
    largest = max(abs(c00), abs(c01), abs(c02), abs(c10), abs(c11), abs(c12), abs(c20), abs(c21), abs(c22))
    bound = 1e-9 * largest + 1e-300
    a, d, f = c00, c11, c22
    b, c, e = 0.5 * (c01 + c10), 0.5 * (c02 + c20), 0.5 * (c12 + c21)
    det = a * (d * f - e * e) + b * (c * e - b * f) + c * (b * e - c * d)
    ok = (finite and abs(c01 - c10) <= bound and abs(c02 - c20) <= bound and abs(c12 - c21) <= bound
          and a > 0.0 and a * d - b * b > 0.0 and det > 0.0)
    return ok, a, b, c, d, e, f


@jit.inline
def _newton_step(coef, us, los, his, k, u_tol):
    """One safeguarded Newton step on ``phi(u)`` for pair ``k`` of a block; whether it needs another.

    ``coef[k]``: the pair's quartic coefficients; ``us``, ``los``, ``his``: its ``u`` and the
    bracket ``[lo, hi]`` the signs of ``phi`` have shown, updated in place. Bisection where
    Newton leaves a two-sided bracket, steps capped at 4 until both ends are known. Another
    step is needed while a Newton step moved ``u`` by more than ``u_tol`` (relative; the
    convergence is quadratic, so the step just taken leaves an error of order ``u_tol**2``)
    or a bisection step by more than ``u_tol**2`` (it halves the error only).
    """
    u, lo, hi = us[k], los[k], his[k]
    c41, c42, c31, c32, c21, c22 = coef[k, 0], coef[k, 1], coef[k, 2], coef[k, 3], coef[k, 4], coef[k, 5]
    c11, c12, c01, c02 = coef[k, 6], coef[k, 7], coef[k, 8], coef[k, 9]
    g31, g32, g21, g22 = coef[k, 10], coef[k, 11], coef[k, 12], coef[k, 13]
    g11, g12, g01, g02 = coef[k, 14], coef[k, 15], coef[k, 16], coef[k, 17]
    t = math.exp(u)
    val1, val2 = c41 * t + c31, c42 * t + c32
    der1, der2 = g31 * t + g21, g32 * t + g22
    val1, val2 = val1 * t + c21, val2 * t + c22
    der1, der2 = der1 * t + g11, der2 * t + g12
    val1, val2 = val1 * t + c11, val2 * t + c12
    der1, der2 = der1 * t + g01, der2 * t + g02
    val1, val2 = val1 * t + c01, val2 * t + c02
    phi = 2.0 * u + math.log(val1 / val2)
    dphi = 2.0 + t * (der1 / val1 - der2 / val2)
    if phi < 0.0:
        lo = max(lo, u)
    if phi > 0.0:
        hi = min(hi, u)
    step = -phi / dphi
    new_u = u + step
    tol = u_tol
    if math.isfinite(lo) and math.isfinite(hi):
        slack = 1e-12 * (1.0 + abs(u))
        if new_u < lo - slack or new_u > hi + slack:
            new_u = 0.5 * (lo + hi)
            tol = u_tol * u_tol
    else:
        new_u = u + min(max(step, -4.0), 4.0)
    us[k], los[k], his[k] = new_u, lo, hi
    return abs(new_u - u) > tol * max(1.0, abs(u))


def _signature(t):
    """Means (3, n) or (n, 3) and covariances (3, 3, n) or (n, 3, 3) in, the layout flag, then the
    outputs (n,) and (3, n); returns an int."""
    r2, r3, w1, w2 = jit.readonly(t, 2), jit.readonly(t, 3), t.float64[::1], t.float64[:, ::1]
    return t.int64(r2, r2, r3, r3, t.float64, t.int64, t.boolean, w1, w1, w1, w2, w1, w2, w1, w1, w2)


@jit.lazy(_signature)
def _minmax3(m1, m2, s1, s2, u_tol, max_newton, batch_first,
             lam, eta, residual, alpha, beta, normal, sc1, sc2, grad):
    """Per pair ``p`` of 3-D Gaussians ``N(m1, s1)``, ``N(m2, s2)``: the minmax separator.

    Inputs: means ``m1``, ``m2`` in metres and covariances ``s1``, ``s2`` in square metres,
    either batch last and validated (``batch_first`` false: (3, n) and (3, 3, n) symmetric
    positive definite components, as :class:`companion.core.overlap.CovariancePairs` lays
    them out) or batch first as given to ``minmax`` ((n, 3) and (n, 3, 3), unchecked: each
    pair is checked as it is read, :func:`_checked_covariance` and finite means, and each
    off-diagonal pair read as ``0.5 (upper + lower)``, the layout pass's value, so both
    layouts give the same bits). Writes ``lam``, ``eta``, ``residual`` (``eta1 - eta2``),
    ``beta``, ``sc1``, ``sc2`` (the support scales ``sqrt(x'S x) / |x|``) as (n,) and
    ``alpha``, ``normal``, ``grad`` (``d eta / d mu1``) as (3, n). Returns the number of
    pairs whose Newton iteration ran ``max_newton`` steps without converging, or
    ``-1 - p`` when pair ``p`` (batch first) fails its checks.

    Pairs go in blocks of :data:`_BLOCK`: the Newton coefficients of each pair of the block,
    then sweeps of one Newton step (:func:`_newton_step`) for each pair still iterating,
    then each pair's separator. Each pair sees the same operations in the same order as
    when it was solved alone (so the same bits); a sweep steps four independent pairs in a
    row, so the processor overlaps their chains of ``exp``, ``log`` and divisions, which
    one pair's iteration leaves waiting on each other (docs/PERFORMANCE.md).
    """
    n = m1.shape[0] if batch_first else m1.shape[1]
    stalled = 0
    coef = np.empty((_BLOCK, 18))     # per pair of the block: c41 c42 c31 c32 c21 c22 c11 c12 c01 c02, g31 .. g02
    pair = np.empty((_BLOCK, 19))     # per pair of the block: S1, S2 (six entries each), m1, delta, coincident
    us, los, his = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    active = np.empty(_BLOCK, np.int64)
    for start in range(0, n, _BLOCK):
        size = min(_BLOCK, n - start)
        for k in range(size):
            p = start + k
            if batch_first:     # as given: checked here, symmetrised as the layout pass does
                ok1, a, b, c, d, e, f = _checked_covariance(s1[p, 0, 0], s1[p, 0, 1], s1[p, 0, 2], s1[p, 1, 0],
                                                            s1[p, 1, 1], s1[p, 1, 2], s1[p, 2, 0], s1[p, 2, 1],
                                                            s1[p, 2, 2])
                ok2, aa, bb, cc, dd, ee, ff = _checked_covariance(s2[p, 0, 0], s2[p, 0, 1], s2[p, 0, 2], s2[p, 1, 0],
                                                                  s2[p, 1, 1], s2[p, 1, 2], s2[p, 2, 0], s2[p, 2, 1],
                                                                  s2[p, 2, 2])
                mx, my, mz = m1[p, 0], m1[p, 1], m1[p, 2]
                nx, ny, nz = m2[p, 0], m2[p, 1], m2[p, 2]
                if not (ok1 and ok2 and ((mx - mx) + (my - my) + (mz - mz) + (nx - nx) + (ny - ny) + (nz - nz)) == 0.0):
                    return -1 - p
                dx, dy, dz = nx - mx, ny - my, nz - mz
            else:
                a, b, c = s1[0, 0, p], s1[0, 1, p], s1[0, 2, p]
                d, e, f = s1[1, 1, p], s1[1, 2, p], s1[2, 2, p]
                aa, bb, cc = s2[0, 0, p], s2[0, 1, p], s2[0, 2, p]
                dd, ee, ff = s2[1, 1, p], s2[1, 2, p], s2[2, 2, p]
                mx, my, mz = m1[0, p], m1[1, p], m1[2, p]
                dx, dy, dz = m2[0, p] - mx, m2[1, p] - my, m2[2, p] - mz
            # delta = m2 - m1; coincident means take a fixed direction scaled like the covariances
            scale = math.sqrt(max(a + d + f, aa + dd + ff))
            same = math.sqrt(dx * dx + dy * dy + dz * dz) <= 1e-15 * scale
            if same:
                dx, dy, dz = scale, 0.0, 0.0
            pair[k, 0], pair[k, 1], pair[k, 2], pair[k, 3], pair[k, 4], pair[k, 5] = a, b, c, d, e, f
            pair[k, 6], pair[k, 7], pair[k, 8], pair[k, 9], pair[k, 10], pair[k, 11] = aa, bb, cc, dd, ee, ff
            pair[k, 12], pair[k, 13], pair[k, 14], pair[k, 15], pair[k, 16], pair[k, 17] = mx, my, mz, dx, dy, dz
            pair[k, 18] = 1.0 if same else 0.0
            # adjugates of S1, S2 and S1 + S2 (symmetric: six entries each)
            p00, p01, p02 = d * f - e * e, c * e - b * f, b * e - c * d
            p11, p12, p22 = a * f - c * c, b * c - a * e, a * d - b * b
            r00, r01, r02 = dd * ff - ee * ee, cc * ee - bb * ff, bb * ee - cc * dd
            r11, r12, r22 = aa * ff - cc * cc, bb * cc - aa * ee, aa * dd - bb * bb
            ta, tb, tc, td, te, tf = a + aa, b + bb, c + cc, d + dd, e + ee, f + ff
            k01, k02, k12 = tc * te - tb * tf, tb * te - tc * td, tb * tc - ta * te
            m00 = td * tf - te * te - p00 - r00
            m01, m02 = k01 - p01 - r01, k02 - p02 - r02
            m11 = ta * tf - tc * tc - p11 - r11
            m12 = k12 - p12 - r12
            m22 = ta * td - tb * tb - p22 - r22
            # a2 = adj(S1) delta, a1 = M delta, a0 = adj(S2) delta
            a2x, a2y = p00 * dx + p01 * dy + p02 * dz, p01 * dx + p11 * dy + p12 * dz
            a2z = p02 * dx + p12 * dy + p22 * dz
            a1x, a1y = m00 * dx + m01 * dy + m02 * dz, m01 * dx + m11 * dy + m12 * dz
            a1z = m02 * dx + m12 * dy + m22 * dz
            a0x, a0y = r00 * dx + r01 * dy + r02 * dz, r01 * dx + r11 * dy + r12 * dz
            a0z = r02 * dx + r12 * dy + r22 * dz
            det1 = a * p00 + b * p01 + c * p02
            det2 = aa * r00 + bb * r01 + cc * r02
            d2 = dx * a2x + dy * a2y + dz * a2z
            d1 = dx * a1x + dy * a1y + dz * a1z
            d0 = dx * a0x + dy * a0y + dz * a0z
            # S1 a1, S2 a1, S2 a2, S1 a0
            u1x, u1y, u1z = a * a1x + b * a1y + c * a1z, b * a1x + d * a1y + e * a1z, c * a1x + e * a1y + f * a1z
            v1x, v1y = aa * a1x + bb * a1y + cc * a1z, bb * a1x + dd * a1y + ee * a1z
            v1z = cc * a1x + ee * a1y + ff * a1z
            v2x, v2y = aa * a2x + bb * a2y + cc * a2z, bb * a2x + dd * a2y + ee * a2z
            v2z = cc * a2x + ee * a2y + ff * a2z
            u0x, u0y, u0z = a * a0x + b * a0y + c * a0z, b * a0x + d * a0y + e * a0z, c * a0x + e * a0y + f * a0z
            # t^k coefficients of n1 (c*1) and n2 (c*2), and of their derivatives (g*)
            c41, c42 = det1 * d2, a2x * v2x + a2y * v2y + a2z * v2z
            c31, c32 = 2.0 * det1 * d1, 2.0 * (a2x * v1x + a2y * v1y + a2z * v1z)
            c21 = (a1x * u1x + a1y * u1y + a1z * u1z) + 2.0 * det1 * d0
            c22 = (a1x * v1x + a1y * v1y + a1z * v1z) + 2.0 * det2 * d2
            c11, c12 = 2.0 * (a0x * u1x + a0y * u1y + a0z * u1z), 2.0 * det2 * d1
            c01, c02 = a0x * u0x + a0y * u0y + a0z * u0z, det2 * d0
            g01, g02 = c11 * 1.0, c12 * 1.0
            g11, g12 = c21 * 2.0, c22 * 2.0
            g21, g22 = c31 * 3.0, c32 * 3.0
            g31, g32 = c41 * 4.0, c42 * 4.0
            coef[k, 0], coef[k, 1], coef[k, 2], coef[k, 3], coef[k, 4], coef[k, 5] = c41, c42, c31, c32, c21, c22
            coef[k, 6], coef[k, 7], coef[k, 8], coef[k, 9] = c11, c12, c01, c02
            coef[k, 10], coef[k, 11], coef[k, 12], coef[k, 13] = g31, g32, g21, g22
            coef[k, 14], coef[k, 15], coef[k, 16], coef[k, 17] = g11, g12, g01, g02
            us[k] = -0.5 * math.log((c41 + c31 + c21 + c11 + c01) / (c42 + c32 + c22 + c12 + c02))
            los[k], his[k] = -math.inf, math.inf
            active[k] = k
        # Newton, one step for each pair still iterating per sweep, four pairs at a time: their
        # steps are independent, so the processor overlaps their chains of exp, log and divisions
        left = size
        for _ in range(max_newton):
            kept = 0
            j = 0
            while j + 4 <= left:
                ka, kb, kc, kd = active[j], active[j + 1], active[j + 2], active[j + 3]
                more_a = _newton_step(coef, us, los, his, ka, u_tol)
                more_b = _newton_step(coef, us, los, his, kb, u_tol)
                more_c = _newton_step(coef, us, los, his, kc, u_tol)
                more_d = _newton_step(coef, us, los, his, kd, u_tol)
                for k, more in ((ka, more_a), (kb, more_b), (kc, more_c), (kd, more_d)):
                    if more:
                        active[kept] = k      # kept <= j: a slot already read
                        kept += 1
                j += 4
            while j < left:
                k = active[j]
                if _newton_step(coef, us, los, his, k, u_tol):
                    active[kept] = k
                    kept += 1
                j += 1
            left = kept
            if left == 0:
                break
        stalled += left
        for k in range(size):
            p = start + k
            u = us[k]
            a, b, c, d, e, f = pair[k, 0], pair[k, 1], pair[k, 2], pair[k, 3], pair[k, 4], pair[k, 5]
            aa, bb, cc, dd, ee, ff = pair[k, 6], pair[k, 7], pair[k, 8], pair[k, 9], pair[k, 10], pair[k, 11]
            mx, my, mz, dx, dy, dz = pair[k, 12], pair[k, 13], pair[k, 14], pair[k, 15], pair[k, 16], pair[k, 17]
            same = pair[k, 18] != 0.0
            # the separator at the root: x = adj(A) delta / det(A), A = t S1 + S2
            t = math.exp(u)
            lm = t / (1.0 + t)
            ga, gb, gc = t * a + aa, t * b + bb, t * c + cc
            gd, ge, gf = t * d + dd, t * e + ee, t * f + ff
            h01, h02, h12 = gc * ge - gb * gf, gb * ge - gc * gd, gb * gc - ga * ge
            h00, h11, h22 = gd * gf - ge * ge, ga * gf - gc * gc, ga * gd - gb * gb
            det = ga * h00 + gb * h01 + gc * h02
            x0 = (h00 * dx + h01 * dy + h02 * dz) / det
            x1 = (h01 * dx + h11 * dy + h12 * dz) / det
            x2 = (h02 * dx + h12 * dy + h22 * dz) / det
            q1 = x0 * (a * x0 + b * x1 + c * x2) + x1 * (b * x0 + d * x1 + e * x2) + x2 * (c * x0 + e * x1 + f * x2)
            q2 = (x0 * (aa * x0 + bb * x1 + cc * x2) + x1 * (bb * x0 + dd * x1 + ee * x2)
                  + x2 * (cc * x0 + ee * x1 + ff * x2))
            eta1 = t * math.sqrt(q1)
            eta2 = math.sqrt(q2)
            et = 0.5 * (eta1 + eta2)
            res = eta1 - eta2
            al0, al1, al2 = x0 * (1.0 + t), x1 * (1.0 + t), x2 * (1.0 + t)
            xn = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            n0, n1, n2 = x0 / xn, x1 / xn, x2 / xn
            k1 = math.sqrt(q1) / xn
            k2 = math.sqrt(q2) / xn
            if same:
                et, res, al0, al1, al2 = 0.0, 0.0, 0.0, 0.0, 0.0
            sa0, sa1, sa2 = a * al0 + b * al1 + c * al2, b * al0 + d * al1 + e * al2, c * al0 + e * al1 + f * al2
            beta[p] = (al0 * mx + al1 * my + al2 * mz) + lm * (al0 * sa0 + al1 * sa1 + al2 * sa2)
            ksum = k1 + k2
            lam[p], eta[p], residual[p], sc1[p], sc2[p] = lm, et, res, k1, k2
            alpha[0, p], alpha[1, p], alpha[2, p] = al0, al1, al2
            normal[0, p], normal[1, p], normal[2, p] = n0, n1, n2
            grad[0, p], grad[1, p], grad[2, p] = -n0 / ksum, -n1 / ksum, -n2 / ksum
    return stalled


def _checked_pairs_signature(t):
    """A batch (n, 3, 3) in, its (3, 3, n) components out; returns an int."""
    return t.int64(jit.readonly(t, 3), t.float64[:, :, ::1])


@jit.lazy(_checked_pairs_signature)
def _checked_pairs3(c, s):
    """Check and lay out ``n`` covariances ``c`` (n, 3, 3) as symmetrised components ``s`` (3, 3, n).

    Each by :func:`_checked_covariance` (the checks of ``overlap.CovariancePairs.from_arrays``,
    with its arithmetic). Returns -1 when every matrix passes, else the index of the first
    that does not.
    """
    for k in range(c.shape[0]):
        ok, a, b, cc, d, e, f = _checked_covariance(c[k, 0, 0], c[k, 0, 1], c[k, 0, 2], c[k, 1, 0], c[k, 1, 1],
                                                    c[k, 1, 2], c[k, 2, 0], c[k, 2, 1], c[k, 2, 2])
        if not ok:
            return k
        s[0, 0, k], s[1, 1, k], s[2, 2, k] = a, d, f
        s[0, 1, k], s[1, 0, k], s[0, 2, k], s[2, 0, k], s[1, 2, k], s[2, 1, k] = b, b, cc, cc, e, e
    return -1


def checked_pairs3(c: np.ndarray) -> np.ndarray | None:
    """:func:`_checked_pairs3` on a float64 batch ``c`` (n, 3, 3), square metres: its (3, 3, n)
    symmetrised components, or None when a matrix is not finite, symmetric and positive definite."""
    s = np.empty((3, 3, c.shape[0]))
    return s if _checked_pairs3()(np.ascontiguousarray(c, dtype=float), s) < 0 else None


def _shared_pairs_signature(t):
    """One batch (N, 3, 3) and P batches (P, N, 3, 3) in, (3, 3, P N) components out."""
    w3 = t.float64[:, :, ::1]
    return t.void(jit.readonly(t, 3), jit.readonly(t, 4), w3, w3)


@jit.lazy(_shared_pairs_signature)
def _shared_pairs3(c1, c2, s1, s2):
    """The planner's pairs laid out for the kernel: ``c1`` (N, 3, 3) against each row of ``c2``
    (P, N, 3, 3), symmetrised, as components (3, 3, P N), pair ``j N + i``.

    What ``overlap.CovariancePairs.shared_first`` did with numpy (component layout,
    ``0.5 (upper + lower)`` for each off-diagonal pair, the diagonal as it is, ``c1`` tiled
    ``P`` times), the same operations, so the same bits.
    """
    n_obs, n_steps = c2.shape[0], c2.shape[1]
    for j in range(n_obs):
        for i in range(n_steps):
            k = j * n_steps + i
            for r in range(3):
                s1[r, r, k] = c1[i, r, r]
                s2[r, r, k] = c2[j, i, r, r]
                for c in range(r + 1, 3):
                    m = 0.5 * (c1[i, r, c] + c1[i, c, r])
                    s1[r, c, k] = m
                    s1[c, r, k] = m
                    m = 0.5 * (c2[j, i, r, c] + c2[j, i, c, r])
                    s2[r, c, k] = m
                    s2[c, r, k] = m


def shared_pairs3(c1: np.ndarray, c2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_shared_pairs3` on validated covariances (square metres): ``(s1, s2)``, each (3, 3, P N)."""
    n = c2.shape[0] * c2.shape[1]
    s1, s2 = np.empty((3, 3, n)), np.empty((3, 3, n))
    _shared_pairs3()(np.ascontiguousarray(c1, dtype=float), np.ascontiguousarray(c2, dtype=float), s1, s2)
    return s1, s2


def minmax3(m1: np.ndarray, m2: np.ndarray, s1: np.ndarray, s2: np.ndarray,
            u_tol: float, max_newton: int) -> tuple[np.ndarray, int]:
    """The separator fields of ``n`` validated 3-D pairs, and how many pairs did not converge.

    Parameters
    ----------
    m1, m2 : (3, n) arrays
        Means, metres (any frame, the same for both).
    s1, s2 : (3, 3, n) arrays
        Validated symmetric positive definite covariances, square metres.
    u_tol, max_newton : float, int
        Newton's relative step tolerance in ``u = log t`` and its step cap.

    Returns
    -------
    fields : (15, n) array
        One buffer: rows 0 to 5 are ``lam``, ``eta``, ``residual``, ``beta``, ``s1``,
        ``s2``; rows 6-8, 9-11 and 12-14 the x, y, z components of ``alpha``, ``normal``
        and ``eta_grad_mu1`` (one allocation instead of nine; the kernel writes each field
        into a C-contiguous row view, as it wrote the separate arrays).
    stalled : int
        Pairs whose iteration hit ``max_newton`` steps.
    """
    return _run(m1, m2, s1, s2, u_tol, max_newton, False)


def minmax3_as_given(m1: np.ndarray, m2: np.ndarray, c1: np.ndarray, c2: np.ndarray,
                     u_tol: float, max_newton: int) -> tuple[np.ndarray, int] | None:
    """:func:`minmax3` of ``n`` unchecked pairs given batch first, or None when one is not usable.

    ``m1``, ``m2`` (n, 3) means in metres and ``c1``, ``c2`` (n, 3, 3) covariances in square
    metres, as a caller of ``overlap.minmax`` gives them: the kernel checks each pair as it
    reads it (finite means; :func:`_checked_covariance`) and symmetrises the covariances as
    the layout pass does, so a usable batch gives :func:`minmax3`'s bits without a
    batch-last copy of the inputs. None at the first pair that fails (the caller's numpy
    checks then word the error).
    """
    fields, stalled = _run(m1, m2, c1, c2, u_tol, max_newton, True)
    return None if stalled < 0 else (fields, stalled)


def _run(m1, m2, s1, s2, u_tol: float, max_newton: int, batch_first: bool) -> tuple[np.ndarray, int]:
    out = np.empty((15, m1.shape[0] if batch_first else m1.shape[1]))
    stalled = _minmax3()(np.ascontiguousarray(m1, dtype=float), np.ascontiguousarray(m2, dtype=float),
                          np.ascontiguousarray(s1, dtype=float), np.ascontiguousarray(s2, dtype=float),
                          float(u_tol), int(max_newton), bool(batch_first),
                          out[0], out[1], out[2], out[6:9], out[3], out[9:12], out[4], out[5], out[12:15])
    return out, int(stalled)
