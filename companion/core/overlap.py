"""Overlap of two Gaussians: the minmax procedure and the confidence contour of touch.

Drone position ``D ~ N(mu1, S1)``, obstacle position ``O ~ N(mu2, S2)`` in ``d``
dimensions (any frame, typically local NED in metres). For ``lam`` in (0, 1) the
minmax separator of Anderson and Bahadur is

    alpha = (lam S1 + (1 - lam) S2)^-1 (mu2 - mu1)
    beta  = alpha.mu1 + lam alpha' S1 alpha
    eta1  = (beta - alpha.mu1) / sqrt(alpha' S1 alpha) = lam sqrt(alpha' S1 alpha)
    eta2  = (alpha.mu2 - beta) / sqrt(alpha' S2 alpha) = (1 - lam) sqrt(alpha' S2 alpha)

and the admissible ``lam`` makes ``eta1 = eta2 = eta``, i.e.
``alpha' [lam^2 S1 - (1 - lam)^2 S2] alpha = 0``. The overlap is
``Y = 2 (1 - Phi(eta))`` and the confidence contour of touch is ``c = F_chi2_d(eta^2)``:
``eta`` is the largest Mahalanobis radius at which the two confidence ellipsoids are
still disjoint, and ``alpha`` is the normal of the hyperplane that separates them there.

How ``lam`` is found. Write ``t = lam / (1 - lam)`` and ``A(t) = t S1 + S2`` so that
``x = A(t)^-1 (mu2 - mu1)`` is parallel to ``alpha``; then ``eta1 = t sqrt(x'S1x)`` and
``eta2 = sqrt(x'S2x)``. The function ``phi(u) = log(eta1 / eta2)`` of ``u = log t`` is
strictly increasing and tends to a straight line of slope 2 at both ends (it *is* that
line when ``S2`` is a multiple of ``S1``), so a Newton iteration on it with a bracket
kept from the signs seen converges in a handful of steps to machine precision. Its
derivative is closed form: ``phi'(u) = 2 - 2 t w / q1 + 2 t v / q2`` with
``q1 = x'S1x``, ``q2 = x'S2x``, ``w = (S1x)' A^-1 (S1x)`` and ``v = q1 - t w``.
The 2x2 and 3x3 solves use closed-form adjugates, vectorised over all pairs.

Everything broadcasts over leading dimensions: means ``(..., d)``, covariances
``(..., d, d)``; there is no Python loop per pair.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from companion.errors import InputError

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

#: Newton stops once every step in ``u = log(lam/(1-lam))`` is below this; convergence is
#: quadratic, so the step just taken leaves an error of order ``_U_TOL**2``.
_U_TOL = 1e-10
_MAX_NEWTON = 60


# --------------------------------------------------------------------------------------
# Confidence, radius and overlap: one-to-one maps for a d-variate Gaussian.
# --------------------------------------------------------------------------------------


def _check_dim(dim: int) -> int:
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise InputError(f"dim must be an integer >= 1, got {dim!r}")
    return int(dim)


def _check_open_unit(value: ArrayLike, name: str) -> Array:
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0) or np.any(arr >= 1.0):
        raise InputError(f"{name} must lie in the open interval (0, 1), got {value!r}")
    return arr


def touch_radius(confidence: ArrayLike, dim: int) -> Array | float:
    """Mahalanobis radius of the ellipsoid holding ``confidence`` of a ``dim``-variate Gaussian.

    ``r = sqrt(chi2.ppf(confidence, dim))``.

    Parameters
    ----------
    confidence : float or array in (0, 1)
        Probability mass inside the ellipsoid (the paper's ``c``).
    dim : int
        Dimension of the Gaussian (2 or 3 for planar or spatial positions).
    """
    d = _check_dim(dim)
    c = _check_open_unit(confidence, "confidence")
    r = np.sqrt(2.0 * special.gammaincinv(d / 2.0, c))
    return float(r) if r.ndim == 0 else r


def confidence_from_radius(radius: ArrayLike, dim: int) -> Array | float:
    """Probability mass inside the Mahalanobis ellipsoid of ``radius``: ``F_chi2_d(radius^2)``.

    Negative radii (ellipsoids that already interpenetrate at radius zero) map to 0.
    """
    d = _check_dim(dim)
    r = np.asarray(radius, dtype=float)
    if np.any(np.isnan(r)):
        raise InputError("radius must not be NaN")
    c = special.gammainc(d / 2.0, 0.5 * np.square(np.maximum(r, 0.0)))
    return float(c) if c.ndim == 0 else c


def overlap_from_radius(radius: ArrayLike) -> Array | float:
    """Overlap ``Y = 2 (1 - Phi(r))`` of two Gaussians whose contours touch at radius ``r``."""
    r = np.asarray(radius, dtype=float)
    y = 2.0 * special.ndtr(-r)
    return float(y) if y.ndim == 0 else y


def overlap_from_confidence(confidence: ArrayLike, dim: int) -> Array | float:
    """Overlap ``Y`` of two ``dim``-variate Gaussians touching at the ``confidence`` contour.

    ``Y = 2 (1 - Phi(sqrt(chi2.ppf(c, d))))``; e.g. 0.0861 for ``c = 0.6`` in 3-D.
    """
    return overlap_from_radius(touch_radius(confidence, dim))


def confidence_from_overlap(overlap: ArrayLike, dim: int) -> Array | float:
    """Inverse of :func:`overlap_from_confidence`: the contour of touch for an overlap ``Y`` in (0, 1)."""
    y = _check_open_unit(overlap, "overlap")
    r = -special.ndtri(0.5 * y)
    return confidence_from_radius(r, dim)


# --------------------------------------------------------------------------------------
# Validation and small closed-form linear algebra.
# --------------------------------------------------------------------------------------


def _validate_pair(
    mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike, check_pd: bool = True
) -> tuple[Array, Array, Array, Array]:
    """Check shapes, finiteness, symmetry and (unless the caller does it) positive definiteness.

    Returns the four arrays broadcast to common leading dimensions, covariances symmetrised.
    """
    arrays = {}
    for name, value, extra in (("mu1", mu1, 1), ("cov1", cov1, 2), ("mu2", mu2, 1), ("cov2", cov2, 2)):
        arr = np.asarray(value, dtype=float)
        if arr.ndim < extra:
            raise InputError(f"{name} must have at least {extra} dimension(s), got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name} contains NaN or infinite values")
        arrays[name] = arr
    d = arrays["mu1"].shape[-1]
    if arrays["mu2"].shape[-1] != d:
        raise InputError(f"mu1 and mu2 must have the same last dimension, got {arrays['mu1'].shape} and {arrays['mu2'].shape}")
    for name in ("cov1", "cov2"):
        if arrays[name].shape[-2:] != (d, d):
            raise InputError(f"{name} must have shape (..., {d}, {d}) to match the means, got {arrays[name].shape}")
    try:
        lead = np.broadcast_shapes(arrays["mu1"].shape[:-1], arrays["mu2"].shape[:-1], arrays["cov1"].shape[:-2], arrays["cov2"].shape[:-2])
    except ValueError as exc:
        raise InputError(f"leading dimensions do not broadcast: {exc}") from None
    out = []
    for name in ("mu1", "cov1", "mu2", "cov2"):
        arr = arrays[name]
        tail = arr.shape[-1:] if name.startswith("mu") else arr.shape[-2:]
        arr = np.broadcast_to(arr, lead + tail)
        if name.startswith("cov"):
            scale = np.max(np.abs(arr), axis=(-2, -1), keepdims=True)
            asym = np.abs(arr - np.swapaxes(arr, -1, -2))
            if np.any(asym > 1e-9 * scale + 1e-300):
                raise InputError(f"{name} is not symmetric (largest asymmetry {float(np.max(asym)):.3g})")
            arr = 0.5 * (arr + np.swapaxes(arr, -1, -2))
            if check_pd:
                _require_pd(_is_positive_definite(arr), name)
        out.append(np.ascontiguousarray(arr))
    return out[0], out[1], out[2], out[3]


def _require_pd(ok: NDArray[np.bool_], name: str) -> None:
    if not np.all(ok):
        bad = np.argwhere(~np.asarray(ok))
        where = f" at index {tuple(int(i) for i in bad[0])}" if bad.size else ""
        raise InputError(f"{name} is not positive definite{where}")


def _is_positive_definite(cov: Array) -> NDArray[np.bool_]:
    """Sylvester's criterion (closed form for d <= 3, eigenvalues otherwise), vectorised."""
    d = cov.shape[-1]
    if d == 1:
        return cov[..., 0, 0] > 0.0
    if d == 2:
        return (cov[..., 0, 0] > 0.0) & (_det(cov) > 0.0)
    if d == 3:
        m2 = cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] * cov[..., 1, 0]
        return (cov[..., 0, 0] > 0.0) & (m2 > 0.0) & (_det(cov) > 0.0)
    return np.all(np.linalg.eigvalsh(cov) > 0.0, axis=-1)


def _det(a: Array) -> Array:
    d = a.shape[-1]
    if d == 1:
        return a[..., 0, 0]
    if d == 2:
        return a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    if d == 3:
        return (
            a[..., 0, 0] * (a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1])
            - a[..., 0, 1] * (a[..., 1, 0] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 0])
            + a[..., 0, 2] * (a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0])
        )
    return np.linalg.det(a)


def _inv(a: Array) -> Array:
    """Inverse of a batch of small symmetric positive definite matrices (adjugate for d <= 3)."""
    d = a.shape[-1]
    if d > 3:
        return np.linalg.inv(a)
    det = _det(a)[..., None, None]
    if d == 1:
        return 1.0 / a
    if d == 2:
        adj = np.empty_like(a)
        adj[..., 0, 0] = a[..., 1, 1]
        adj[..., 1, 1] = a[..., 0, 0]
        adj[..., 0, 1] = -a[..., 0, 1]
        adj[..., 1, 0] = -a[..., 1, 0]
        return adj / det
    adj = np.empty_like(a)
    adj[..., 0, 0] = a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1]
    adj[..., 0, 1] = a[..., 0, 2] * a[..., 2, 1] - a[..., 0, 1] * a[..., 2, 2]
    adj[..., 0, 2] = a[..., 0, 1] * a[..., 1, 2] - a[..., 0, 2] * a[..., 1, 1]
    adj[..., 1, 0] = a[..., 1, 2] * a[..., 2, 0] - a[..., 1, 0] * a[..., 2, 2]
    adj[..., 1, 1] = a[..., 0, 0] * a[..., 2, 2] - a[..., 0, 2] * a[..., 2, 0]
    adj[..., 1, 2] = a[..., 0, 2] * a[..., 1, 0] - a[..., 0, 0] * a[..., 1, 2]
    adj[..., 2, 0] = a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0]
    adj[..., 2, 1] = a[..., 0, 1] * a[..., 2, 0] - a[..., 0, 0] * a[..., 2, 1]
    adj[..., 2, 2] = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    return adj / det


def _mv(m: Array, v: Array) -> Array:
    """Batched matrix-vector product ``m @ v``."""
    return (m * v[..., None, :]).sum(axis=-1)


def _dot(a: Array, b: Array) -> Array:
    return (a * b).sum(axis=-1)


def _quad(v: Array, m: Array) -> Array:
    """Batched quadratic form ``v' m v``."""
    return (v * _mv(m, v)).sum(axis=-1)


# Structure of arrays for the hot loop: a d x d matrix over n pairs is a nested list of d*d
# contiguous arrays of shape (n,), a vector a list of d arrays. Elementwise numpy on
# contiguous 1-D arrays is several times faster than on strided (n, d, d) views.
Comp = list


def _to_comp_mat(a: Array) -> list[list[Array]]:
    d = a.shape[-1]
    return [[np.ascontiguousarray(a[:, i, j]) for j in range(d)] for i in range(d)]


def _to_comp_vec(v: Array) -> list[Array]:
    return [np.ascontiguousarray(v[:, i]) for i in range(v.shape[-1])]


def _comp_inv_sym(m: list[list[Array]]) -> list[list[Array]]:
    """Inverse of symmetric matrices in component form (adjugate for d <= 3)."""
    d = len(m)
    if d == 1:
        return [[1.0 / m[0][0]]]
    if d == 2:
        det = m[0][0] * m[1][1] - m[0][1] * m[0][1]
        off = -m[0][1] / det
        return [[m[1][1] / det, off], [off, m[0][0] / det]]
    if d == 3:
        a, b, c, dd, e, f = m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]
        c00 = dd * f - e * e
        c01 = c * e - b * f
        c02 = b * e - c * dd
        det = a * c00 + b * c01 + c * c02
        r = 1.0 / det
        i00, i01, i02 = c00 * r, c01 * r, c02 * r
        i11 = (a * f - c * c) * r
        i12 = (b * c - a * e) * r
        i22 = (a * dd - b * b) * r
        return [[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]]
    dense = np.stack([np.stack(row, axis=-1) for row in m], axis=-2)
    return _to_comp_mat(np.linalg.inv(dense))


def _comp_det(m: list[list[Array]]) -> Array:
    d = len(m)
    if d == 1:
        return m[0][0]
    if d == 2:
        return m[0][0] * m[1][1] - m[0][1] * m[0][1]
    if d == 3:
        a, b, c, dd, e, f = m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]
        return a * (dd * f - e * e) + b * (c * e - b * f) + c * (b * e - c * dd)
    return np.linalg.det(np.stack([np.stack(row, axis=-1) for row in m], axis=-2))


def _comp_pd(m: list[list[Array]]) -> NDArray[np.bool_]:
    """Sylvester's criterion in component form (leading minors positive)."""
    d = len(m)
    if d > 3:
        return _is_positive_definite(np.stack([np.stack(row, axis=-1) for row in m], axis=-2))
    ok = m[0][0] > 0.0
    if d >= 2:
        ok &= m[0][0] * m[1][1] - m[0][1] * m[0][1] > 0.0
    if d == 3:
        ok &= _comp_det(m) > 0.0
    return ok


def _comp_mv(m: list[list[Array]], v: list[Array]) -> list[Array]:
    return [sum(m[i][j] * v[j] for j in range(len(v))) for i in range(len(m))]


def _comp_dot(a: list[Array], b: list[Array]) -> Array:
    return sum(x * y for x, y in zip(a, b))


def _comp_axpy(t: Array, s1: list[list[Array]], s2: list[list[Array]]) -> list[list[Array]]:
    """``t S1 + S2`` in component form."""
    return [[t * x + y for x, y in zip(r1, r2)] for r1, r2 in zip(s1, s2)]


# --------------------------------------------------------------------------------------
# The minmax procedure.
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MinmaxResult:
    """The admissible minmax separator of two Gaussians (arrays over the leading dims).

    Attributes
    ----------
    lam : overlap parameter ``lam`` in (0, 1) solving the admissibility condition.
    eta : Mahalanobis radius at which the two confidence ellipsoids touch (``eta1 = eta2``).
    alpha : ``(..., d)`` separating normal ``(lam S1 + (1-lam) S2)^-1 (mu2 - mu1)``.
    beta : offset of the separating hyperplane ``alpha.x = beta``.
    overlap : ``Y = 2 (1 - Phi(eta))``.
    confidence : contour of touch ``F_chi2_d(eta^2)``.
    normal : ``(..., d)`` unit normal ``alpha / |alpha|`` pointing from 1 towards 2. For
        coincident means (``eta = 0``) every direction separates equally badly; the first
        axis is returned.
    s1, s2 : ``sqrt(normal' S_k normal)``, the standard deviation of each Gaussian along the normal.
    eta_grad_mu1 : ``(..., d)`` gradient of ``eta`` with respect to ``mu1`` (envelope
        theorem on ``eta = max_n n.(mu2-mu1) / (s1(n) + s2(n))``): ``-normal / (s1 + s2)``.
    residual : admissibility residual ``eta1 - eta2`` (zero to rounding).
    """

    lam: Array
    eta: Array
    alpha: Array
    beta: Array
    overlap: Array
    confidence: Array
    normal: Array
    s1: Array
    s2: Array
    eta_grad_mu1: Array
    residual: Array


def minmax(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike) -> MinmaxResult:
    """Admissible minmax separator of ``N(mu1, cov1)`` and ``N(mu2, cov2)``.

    Parameters
    ----------
    mu1, mu2 : array (..., d)
        Means (e.g. drone and obstacle positions, NED metres).
    cov1, cov2 : array (..., d, d)
        Symmetric positive definite covariances (square metres).

    Returns
    -------
    MinmaxResult
        Broadcast over the leading dimensions of the inputs.

    Raises
    ------
    InputError
        Shapes that do not match, NaN or infinite entries, covariances that are not
        symmetric or not positive definite.
    """
    m1, s1m, m2, s2m = _validate_pair(mu1, cov1, mu2, cov2, check_pd=False)
    lead = m1.shape[:-1]
    d = m1.shape[-1]
    n = int(np.prod(lead, dtype=int))
    m1f, m2f = m1.reshape(n, d), m2.reshape(n, d)
    s1f, s2f = s1m.reshape(n, d, d), s2m.reshape(n, d, d)
    S1, S2 = _to_comp_mat(s1f), _to_comp_mat(s2f)
    _require_pd(_comp_pd(S1).reshape(lead), "cov1")
    _require_pd(_comp_pd(S2).reshape(lead), "cov2")
    delta = m2f - m1f
    scale = np.sqrt(np.maximum(sum(S1[i][i] for i in range(d)), sum(S2[i][i] for i in range(d))))
    coincident = np.sqrt(_dot(delta, delta)) <= 1e-15 * scale
    # Keep the iteration well-defined for coincident means; they are patched at the end.
    delta_it = np.where(coincident[:, None], np.eye(d)[0] * scale[:, None], delta)
    dv = _to_comp_vec(delta_it)

    # Start at the geometric mean of the generalised eigenvalues of (S2, S1): exact when S2 = g S1.
    u = 0.5 * (np.log(_comp_det(S2)) - np.log(_comp_det(S1))) / d
    lo = np.full(n, -np.inf)
    hi = np.full(n, np.inf)
    idx = np.arange(n)  # pairs still iterating
    S1a, S2a, da = S1, S2, dv
    for _ in range(_MAX_NEWTON):
        ua = u[idx]
        t = np.exp(ua)
        a_inv = _comp_inv_sym(_comp_axpy(t, S1a, S2a))
        x = _comp_mv(a_inv, da)
        y = _comp_mv(S1a, x)
        q1 = _comp_dot(x, y)
        q2 = _comp_dot(x, _comp_mv(S2a, x))
        w = _comp_dot(y, _comp_mv(a_inv, y))
        v = q1 - t * w
        phi = 2.0 * ua + np.log(q1) - np.log(q2)  # log(eta1^2 / eta2^2), increasing in u
        dphi = 2.0 - 2.0 * t * w / q1 + 2.0 * t * v / q2
        la = np.where(phi < 0.0, np.maximum(lo[idx], ua), lo[idx])
        ha = np.where(phi > 0.0, np.minimum(hi[idx], ua), hi[idx])
        lo[idx], hi[idx] = la, ha
        step = -phi / dphi
        new_u = ua + step
        # Safeguard: stay inside the bracket the signs have shown; bisect where Newton leaves it.
        both = np.isfinite(la) & np.isfinite(ha)
        # A bracket end can sit within rounding of the root (phi ~ 1e-16 there); a Newton step
        # that lands just beyond it is still good, so only a clear exit counts as leaving.
        slack = 1e-12 * (1.0 + np.abs(ua))
        outside = (new_u < la - slack) | (new_u > ha + slack)
        midpoint = 0.5 * (np.where(both, la, 0.0) + np.where(both, ha, 0.0))
        new_u = np.where(outside & both, midpoint, new_u)
        new_u = np.where(~both, ua + np.clip(step, -4.0, 4.0), new_u)  # no two-sided bracket yet: cap every step
        u[idx] = new_u
        keep = np.abs(new_u - ua) > _U_TOL * np.maximum(1.0, np.abs(ua))
        if not np.any(keep):
            break
        if not np.all(keep):
            idx = idx[keep]
            S1a = [[c[keep] for c in row] for row in S1a]
            S2a = [[c[keep] for c in row] for row in S2a]
            da = [c[keep] for c in da]
    else:  # pragma: no cover - the iteration is proven to converge; keep a trace if it ever does not
        logger.warning("minmax: Newton iteration hit %d steps on %d pair(s)", _MAX_NEWTON, idx.size)

    t = np.exp(u)
    lam = t / (1.0 + t)
    a_inv = _comp_inv_sym(_comp_axpy(t, S1, S2))
    xc = _comp_mv(a_inv, dv)
    q1 = _comp_dot(xc, _comp_mv(S1, xc))
    q2 = _comp_dot(xc, _comp_mv(S2, xc))
    x = np.stack(xc, axis=-1)
    eta1 = t * np.sqrt(q1)
    eta2 = np.sqrt(q2)
    eta = 0.5 * (eta1 + eta2)
    residual = eta1 - eta2
    alpha = x * (1.0 + t)[:, None]  # (lam S1 + (1-lam) S2)^-1 delta = (1 + t) x
    xn = np.sqrt(_dot(x, x))
    normal = x / xn[:, None]
    s1 = np.sqrt(q1) / xn
    s2 = np.sqrt(q2) / xn
    if np.any(coincident):
        eta = np.where(coincident, 0.0, eta)
        residual = np.where(coincident, 0.0, residual)
        alpha = np.where(coincident[:, None], 0.0, alpha)
    beta = _dot(alpha, m1f) + lam * _quad(alpha, s1f)

    def shaped(a: Array) -> Array:
        return a.reshape(lead + a.shape[1:])

    return MinmaxResult(
        lam=shaped(lam),
        eta=shaped(eta),
        alpha=shaped(alpha),
        beta=shaped(beta),
        overlap=shaped(2.0 * special.ndtr(-eta)),
        confidence=shaped(special.gammainc(d / 2.0, 0.5 * eta * eta)),
        normal=shaped(normal),
        s1=shaped(s1),
        s2=shaped(s2),
        eta_grad_mu1=shaped(-normal / (s1 + s2)[:, None]),
        residual=shaped(residual),
    )


def support_margin(
    mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike, normal: ArrayLike, radius_sum: ArrayLike = 0.0
) -> Array:
    """Mahalanobis radius at which the body-inflated ellipsoids touch along ``normal``.

    ``(n.(mu2 - mu1) - R) / (s1 + s2)`` with ``n`` the normal made unit, ``s_k = |S_k^1/2 n|``
    and ``R = R_drone + R_obstacle`` (metres). Any unit normal gives a valid lower bound
    of the exact touch radius of the inflated ellipsoids ``{x: (x-mu_k)'S_k^-1(x-mu_k) <= r^2}
    + ball(R_k)``; the minmax normal is the tightest for ``R = 0``, where this equals ``eta``.
    Under ``margin >= r`` the collision probability at that instant is at most ``Phi(-r)``.
    """
    m1, s1m, m2, s2m = _validate_pair(mu1, cov1, mu2, cov2)
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    s1 = np.sqrt(_quad(n, s1m))
    s2 = np.sqrt(_quad(n, s2m))
    return (_dot(n, m2 - m1) - np.asarray(radius_sum, dtype=float)) / (s1 + s2)


def contour_of_touch(
    mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike, radius_sum: ArrayLike = 0.0
) -> Array:
    """Confidence contour at which the two (body-inflated) ellipsoids touch.

    ``F_chi2_d(m^2)`` with ``m`` the :func:`support_margin` at the minmax normal (0 when the
    inflated bodies already overlap at radius 0). Exact for ``radius_sum = 0``; with radii
    it is the contour the planner's constraint guarantees, a lower bound of the exact one.
    """
    res = minmax(mu1, cov1, mu2, cov2)
    m1, s1m, m2, s2m = _validate_pair(mu1, cov1, mu2, cov2)
    margin = (_dot(res.normal, m2 - m1) - np.asarray(radius_sum, dtype=float)) / (res.s1 + res.s2)
    d = m1.shape[-1]
    return special.gammainc(d / 2.0, 0.5 * np.square(np.maximum(margin, 0.0)))


# --------------------------------------------------------------------------------------
# Bhattacharyya distance (the paper's entropic baseline).
# --------------------------------------------------------------------------------------


def bhattacharyya(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike) -> Array | float:
    """Bhattacharyya distance ``1/8 dmu' S^-1 dmu + 1/2 ln(det S / sqrt(det S1 det S2))``, ``S = (S1 + S2)/2``."""
    m1, s1m, m2, s2m = _validate_pair(mu1, cov1, mu2, cov2)
    s = 0.5 * (s1m + s2m)
    delta = m2 - m1
    db = 0.125 * _quad(delta, _inv(s)) + 0.5 * (np.log(_det(s)) - 0.5 * (np.log(_det(s1m)) + np.log(_det(s2m))))
    return float(db) if db.ndim == 0 else db


def bhattacharyya_grad_mu1(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike) -> Array:
    """Gradient of :func:`bhattacharyya` with respect to ``mu1``: ``-1/4 S^-1 (mu2 - mu1)``."""
    m1, s1m, m2, s2m = _validate_pair(mu1, cov1, mu2, cov2)
    return -0.25 * _mv(_inv(0.5 * (s1m + s2m)), m2 - m1)


# --------------------------------------------------------------------------------------
# The paper's joint formulation: values and gradients in (mu1, lam).
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PaperTerms:
    """Overlap terms of the paper's joint formulation at a given (possibly non-admissible) ``lam``.

    ``alpha = (lam S1 + (1-lam) S2)^-1 (mu2 - mu1)``, ``q_k = alpha' S_k alpha``.

    Attributes
    ----------
    h : radius-aware touch radius ``(alpha.(mu2-mu1) - R |alpha|) / (sqrt(q1) + sqrt(q2))``;
        at the admissible ``lam`` and ``R = 0`` it equals ``eta``. The constraint
        ``h >= r_min`` is the paper's ``overlap <= Y_max`` (``Y`` is monotone in it).
    h_grad_mu1 : (..., d) gradient of ``h`` w.r.t. ``mu1``.
    h_grad_lam : derivative of ``h`` w.r.t. ``lam``.
    g : admissibility residual ``eta1^2 - eta2^2 = lam^2 q1 - (1-lam)^2 q2``.
    g_grad_mu1 : (..., d) gradient of ``g`` w.r.t. ``mu1``.
    g_grad_lam : derivative of ``g`` w.r.t. ``lam``.
    """

    h: Array
    h_grad_mu1: Array
    h_grad_lam: Array
    g: Array
    g_grad_mu1: Array
    g_grad_lam: Array


def paper_terms(
    mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike, lam: ArrayLike, radius_sum: ArrayLike = 0.0
) -> PaperTerms:
    """Values and analytic gradients of the paper's overlap and admissibility terms.

    With ``A = lam S1 + (1-lam) S2``: ``d alpha / d mu1 = -A^-1`` and
    ``d alpha / d lam = -A^-1 (S1 - S2) alpha``; the rest is the chain rule.
    """
    m1, s1m, m2, s2m = _validate_pair(mu1, cov1, mu2, cov2)
    lam_a = np.asarray(lam, dtype=float)
    if not np.all(np.isfinite(lam_a)) or np.any(lam_a <= 0.0) or np.any(lam_a >= 1.0):
        raise InputError("lam must lie in the open interval (0, 1)")
    lam_a = np.broadcast_to(lam_a, m1.shape[:-1])
    radius = np.broadcast_to(np.asarray(radius_sum, dtype=float), m1.shape[:-1])
    delta = m2 - m1
    a_inv = _inv(lam_a[..., None, None] * s1m + (1.0 - lam_a)[..., None, None] * s2m)
    alpha = _mv(a_inv, delta)
    s1a = _mv(s1m, alpha)
    s2a = _mv(s2m, alpha)
    q1 = _dot(alpha, s1a)
    q2 = _dot(alpha, s2a)
    r1, r2 = np.sqrt(q1), np.sqrt(q2)
    na = np.sqrt(_dot(alpha, alpha))
    den = r1 + r2
    num = _dot(alpha, delta) - radius * na
    h = num / den
    # dh/dalpha = (delta - R alpha/|alpha|)/den - num/den^2 (S1 alpha/sqrt(q1) + S2 alpha/sqrt(q2))
    dh_dalpha = (delta - (radius / na)[..., None] * alpha) / den[..., None] - (num / den**2)[..., None] * (
        s1a / r1[..., None] + s2a / r2[..., None]
    )
    dalpha_dlam = -_mv(a_inv, s1a - s2a)
    h_grad_mu1 = -alpha / den[..., None] - _mv(a_inv, dh_dalpha)  # d delta/d mu1 = -I, d alpha/d mu1 = -A^-1
    h_grad_lam = _dot(dh_dalpha, dalpha_dlam)
    # g = lam^2 q1 - (1-lam)^2 q2
    g = lam_a**2 * q1 - (1.0 - lam_a) ** 2 * q2
    dg_dalpha = 2.0 * lam_a[..., None] ** 2 * s1a - 2.0 * (1.0 - lam_a)[..., None] ** 2 * s2a
    g_grad_mu1 = -_mv(a_inv, dg_dalpha)
    g_grad_lam = 2.0 * lam_a * q1 + 2.0 * (1.0 - lam_a) * q2 + _dot(dg_dalpha, dalpha_dlam)
    return PaperTerms(h=h, h_grad_mu1=h_grad_mu1, h_grad_lam=h_grad_lam, g=g, g_grad_mu1=g_grad_mu1, g_grad_lam=g_grad_lam)
