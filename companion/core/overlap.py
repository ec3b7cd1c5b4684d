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
The 2x2 and 3x3 solves use closed-form adjugates, vectorised over all pairs
(:mod:`companion.core.small_matrix`, the one small-matrix kernel); 3-D pairs, the
planner's, run the same operations per pair in one compiled loop
(:mod:`companion.core.minmax_kernel`, numba) when numba is installed, with the same bits.

Everything broadcasts over leading dimensions: means ``(..., d)``, covariances
``(..., d, d)``; there is no Python loop per pair. Inputs are validated once per call
(or once per request with :class:`CovariancePairs`).

Why this module is over 400 lines: it is the one place that defines the overlap of two
Gaussians and every quantity the planner derives from it (the confidence/radius/overlap
maps, the minmax separator, the support margin, the Bhattacharyya baseline and the
paper's joint terms), all sharing one validation; split, each half would re-export the
other. The small-matrix algebra lives in :mod:`companion.core.small_matrix`.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from companion.core import jit, minmax_kernel
from companion.core import small_matrix as K
from companion.errors import InputError

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

#: A pair's Newton iteration in ``u = log(lam/(1-lam))`` stops after a Newton step below
#: this (relative): convergence is quadratic, so the step just taken leaves an error of
#: order ``_U_TOL**2``. A bisection step (the safeguard) halves the error only, so it must
#: be below ``_U_TOL**2`` (:func:`_still_moving`).
_U_TOL = 1e-6
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
    if np.isnan(r).any():
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
# Validation (once per call, or once per request with CovariancePairs).
# --------------------------------------------------------------------------------------


def _checked(name: str, value: ArrayLike, extra: int, finite: bool = True) -> Array:
    """``value`` as a float array of at least ``extra`` dimensions, checked finite unless ``finite`` is false."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim < extra:
        raise InputError(f"{name} must have at least {extra} dimension(s), got shape {arr.shape}")
    if finite:
        _require_finite(name, arr)
    return arr


def _require_finite(name: str, arr: Array) -> None:
    if not np.isfinite(arr).all():
        raise InputError(f"{name} contains NaN or infinite values")


def _require_pd(ok: NDArray[np.bool_], name: str) -> None:
    if not np.all(ok):
        bad = np.argwhere(~np.asarray(ok))
        where = f" at index {tuple(int(i) for i in bad[0])}" if bad.size else ""
        raise InputError(f"{name} is not positive definite{where}")


@functools.cache
def _upper_indices(d: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Row and column indices of the strict upper triangle of a ``d x d`` matrix."""
    return np.triu_indices(d, 1)


def _symmetrised_components(name: str, comp: Array, check: bool = True) -> Array:
    """Check a ``(d, d, n)`` component batch for symmetry (unless ``check`` is false) and symmetrise it.

    ``0.5 (a + a')`` per off-diagonal pair; the diagonal is left as it is (``0.5 (a + a)``
    is ``a`` exactly).
    """
    d = comp.shape[0]
    if d < 2:
        return comp
    if comp.base is not None or not comp.flags.writeable:    # a view of the caller's array: copy first
        comp = comp.copy()
    iu, ju = _upper_indices(d)
    upper, lower = comp[iu, ju], comp[ju, iu]
    asym = np.abs(upper - lower) if check else None
    if check and np.any(asym > 1e-9 * np.max(np.abs(comp), axis=(0, 1)) + 1e-300):
        raise InputError(f"{name} is not symmetric (largest asymmetry {float(np.max(asym)):.3g})")
    mean = 0.5 * (upper + lower)
    comp[iu, ju] = mean
    comp[ju, iu] = mean
    return comp


@dataclass(frozen=True)
class CovariancePairs:
    """Validated covariance pairs in the batch-last layout of :mod:`companion.core.small_matrix`.

    Built once (shapes, finiteness, symmetry, positive definiteness checked here) and
    reused for any number of mean pairs: the planner builds one per request and calls
    :meth:`minmax` at every SCP iterate without validating again.

    Attributes
    ----------
    lead : leading (batch) shape of the pairs.
    s1, s2 : (d, d, n) covariances of the first and second Gaussian, square metres.
    """

    lead: tuple[int, ...]
    s1: Array
    s2: Array

    @classmethod
    def from_arrays(cls, cov1: ArrayLike, cov2: ArrayLike, lead: tuple[int, ...] | None = None,
                    *, validated: bool = False) -> CovariancePairs:
        """Validate ``cov1``, ``cov2`` (..., d, d), broadcast to ``lead`` (default: their common leading shape).

        ``validated=True``: the caller has already checked finiteness, symmetry (to 1e-9
        relative) and positive definiteness (as :class:`~companion.core.planner.PlanRequest`
        does on construction); the pairs are then only laid out and symmetrised.
        """
        if validated:
            c1, c2 = np.asarray(cov1, dtype=float), np.asarray(cov2, dtype=float)
            d = c1.shape[-1]
            lead = np.broadcast_shapes(c1.shape[:-2], c2.shape[:-2]) if lead is None else lead
            s1, s2 = (_symmetrised_components(name, K.matrices_to_components(np.broadcast_to(arr, lead + (d, d))),
                                              check=False) for name, arr in (("cov1", c1), ("cov2", c2)))
            return cls(lead=tuple(lead), s1=s1, s2=s2)
        c1, c2 = _checked("cov1", cov1, 2, finite=False), _checked("cov2", cov2, 2, finite=False)
        d = c1.shape[-1]
        for name, arr in (("cov1", c1), ("cov2", c2)):
            if arr.shape[-2:] != (d, d):
                raise InputError(f"{name} must have shape (..., {d}, {d}), got {arr.shape}")
        if lead is None:
            try:
                lead = np.broadcast_shapes(c1.shape[:-2], c2.shape[:-2])
            except ValueError as exc:
                raise InputError(f"leading dimensions do not broadcast: {exc}") from None
        out = []
        for name, arr in (("cov1", c1), ("cov2", c2)):
            full = np.broadcast_to(arr, lead + (d, d))
            # 3-D: one compiled pass checks (finite, symmetric, positive definite), symmetrises and
            # lays out (the same tests, the same bits); a matrix it rejects sends the batch
            # through numpy, which words the error
            comp = minmax_kernel.checked_pairs3(full.reshape(-1, 3, 3)) if d == 3 and jit.available() else None
            if comp is None:
                _require_finite(name, arr)
                comp = _symmetrised_components(name, K.matrices_to_components(full))
                _require_pd(K.is_positive_definite(comp).reshape(lead), name)
            out.append(comp)
        return cls(lead=tuple(lead), s1=out[0], s2=out[1])

    @classmethod
    def shared_first(cls, cov1: Array, cov2: Array) -> CovariancePairs:
        """Validated pairs of one ``cov1`` (N, d, d) against each row of ``cov2`` (P, N, d, d): lead (P, N).

        What :meth:`from_arrays` gives for ``cov1`` broadcast to ``cov2``'s shape with
        ``validated=True`` (the same values), with ``cov1`` laid out and symmetrised once
        and tiled ``P`` times: the planner's drone against each obstacle, once per request.
        """
        c1, c2 = np.asarray(cov1, dtype=float), np.asarray(cov2, dtype=float)
        P, d = c2.shape[0], c1.shape[-1]
        if d == 3 and jit.available():    # one compiled pass, the same bits (minmax_kernel.shared_pairs3)
            s1, s2 = minmax_kernel.shared_pairs3(c1, c2)
            return cls(lead=c2.shape[:-2], s1=s1, s2=s2)
        s1 = _symmetrised_components("cov1", K.matrices_to_components(c1), check=False)
        s2 = _symmetrised_components("cov2", K.matrices_to_components(c2), check=False)
        return cls(lead=c2.shape[:-2], s1=np.tile(s1, (1, 1, P)), s2=s2)

    @property
    def dim(self) -> int:
        """Spatial dimension ``d``."""
        return int(self.s1.shape[0])

    def minmax(self, mu1: ArrayLike, mu2: ArrayLike) -> MinmaxResult:
        """:func:`minmax` of ``N(mu1, s1)`` and ``N(mu2, s2)``; means (lead + (d,)) are trusted (finite)."""
        d = self.dim
        m1 = np.broadcast_to(np.asarray(mu1, dtype=float), self.lead + (d,))
        m2 = np.broadcast_to(np.asarray(mu2, dtype=float), self.lead + (d,))
        return self.minmax_components(K.vectors_to_components(m1), K.vectors_to_components(m2))

    def minmax_components(self, m1: Array, m2: Array) -> MinmaxResult:
        """:meth:`minmax` with the means already laid out as (d, n) components, pair ``k`` of the flattened lead."""
        return _minmax(m1, m2, self.s1, self.s2, self.lead)


def _validate_pair(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike) -> tuple[Array, Array, CovariancePairs]:
    """Check shapes, finiteness, symmetry and positive definiteness, once.

    Returns the means as ``(d, n)`` components and the validated :class:`CovariancePairs`,
    broadcast to common leading dimensions.
    """
    m1, m2 = _checked("mu1", mu1, 1), _checked("mu2", mu2, 1)
    c1, c2 = _checked("cov1", cov1, 2, finite=False), _checked("cov2", cov2, 2, finite=False)   # by from_arrays
    d = m1.shape[-1]
    if m2.shape[-1] != d:
        raise InputError(f"mu1 and mu2 must have the same last dimension, got {m1.shape} and {m2.shape}")
    for name, arr in (("cov1", c1), ("cov2", c2)):
        if arr.shape[-2:] != (d, d):
            raise InputError(f"{name} must have shape (..., {d}, {d}) to match the means, got {arr.shape}")
    try:
        lead = np.broadcast_shapes(m1.shape[:-1], m2.shape[:-1], c1.shape[:-2], c2.shape[:-2])
    except ValueError as exc:
        raise InputError(f"leading dimensions do not broadcast: {exc}") from None
    pairs = CovariancePairs.from_arrays(c1, c2, lead)
    return (K.vectors_to_components(np.broadcast_to(m1, lead + (d,))),
            K.vectors_to_components(np.broadcast_to(m2, lead + (d,))), pairs)


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
        coincident means (``eta = 0``) no direction separates: ``alpha`` and ``eta`` are
        set to 0, and ``normal``, ``lam``, ``s1``, ``s2`` are those of means displaced
        along the first axis (an arbitrary but deterministic choice).
    s1, s2 : ``sqrt(normal' S_k normal)``, the standard deviation of each Gaussian along the normal.
    eta_grad_mu1 : ``(..., d)`` gradient of ``eta`` with respect to ``mu1`` (envelope
        theorem on ``eta = max_n n.(mu2-mu1) / (s1(n) + s2(n))``): ``-normal / (s1 + s2)``.
    residual : admissibility residual ``eta1 - eta2`` (zero to rounding).
    """

    lam: Array
    eta: Array
    alpha: Array
    beta: Array
    normal: Array
    s1: Array
    s2: Array
    eta_grad_mu1: Array
    residual: Array

    # computed on first use: the planner's rows and rechecks need only eta, normal, s1, s2
    @cached_property
    def overlap(self) -> Array:
        """``Y = 2 (1 - Phi(eta))``."""
        return 2.0 * special.ndtr(-self.eta)

    @cached_property
    def confidence(self) -> Array:
        """Contour of touch ``F_chi2_d(eta^2)``."""
        return special.gammainc(self.alpha.shape[-1] / 2.0, 0.5 * self.eta * self.eta)


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
    direct = _minmax_batch_first3(mu1, cov1, mu2, cov2)
    if direct is not None:
        return direct
    m1, m2, pairs = _validate_pair(mu1, cov1, mu2, cov2)
    return _minmax(m1, m2, pairs.s1, pairs.s2, pairs.lead)


def _minmax_batch_first3(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike) -> MinmaxResult | None:
    """:func:`minmax` of 3-D pairs given with one leading shape, by the compiled kernel on the arrays as given.

    No broadcasting and no copies into the batch-last layout: the kernel reads the means
    and covariances batch first, checking each pair as it reads it (the checks of
    :func:`_validate_pair`) and symmetrising as the layout pass does (the same bits as the
    general path). On 10,000 pairs this halves the memory the call touches, and with it
    the page faults a fresh allocation of the layout costs. ``None`` when this does not
    apply (no numba, another dimension, leading shapes that differ) or a check fails: then
    the general path runs, and words the error.
    """
    if not jit.available():
        return None
    m1, c1, m2, c2 = (np.asarray(x, dtype=float) for x in (mu1, cov1, mu2, cov2))
    if not (m1.ndim >= 1 and m1.shape[-1] == 3 and m2.shape == m1.shape
            and c1.shape == m1.shape + (3,) and c2.shape == c1.shape):
        return None
    lead = m1.shape[:-1]
    done = minmax_kernel.minmax3_as_given(m1.reshape(-1, 3), m2.reshape(-1, 3), c1.reshape(-1, 3, 3),
                                          c2.reshape(-1, 3, 3), _U_TOL, _MAX_NEWTON)
    return None if done is None else _compiled_result(*done, lead)


def _compiled_result(fields: Array, stalled: int, lead: tuple[int, ...]) -> MinmaxResult:
    """The :class:`MinmaxResult` of the compiled kernel's ``fields`` (15, n) over ``lead``, as views."""
    if stalled:
        logger.warning("minmax: Newton iteration hit %d steps on %d pair(s)", _MAX_NEWTON, stalled)
    # views in the numpy kernel's layout: scalars lead-shaped, vectors (lead, 3) with the
    # components a row apart (what `v.T.reshape(lead + (3,))` of a (3, n) field gives)
    lam, eta, residual, beta, s1, s2 = fields[:6].reshape((6,) + lead)
    alpha, normal, grad = fields[6:].reshape(3, 3, fields.shape[1]).transpose(0, 2, 1).reshape((3,) + lead + (3,))
    return MinmaxResult(lam=lam, eta=eta, alpha=alpha, beta=beta, normal=normal, s1=s1, s2=s2,
                        eta_grad_mu1=grad, residual=residual)


def _minmax(m1: Array, m2: Array, S1: Array, S2: Array, lead: tuple[int, ...],
            compiled: bool | None = None) -> MinmaxResult:
    """:func:`minmax` on validated batch-last inputs: means (d, n), covariances (d, d, n).

    ``compiled``: 3x3 pairs go through the compiled kernel (:mod:`companion.core.minmax_kernel`,
    the same operations per pair, so the same bits); ``None`` (default) does so when numba
    is available, ``False`` runs the vectorised numpy kernel below (the tests compare the two
    bit for bit).
    """
    d, n = m1.shape
    if compiled is None:
        compiled = jit.available()
    if d == 3 and compiled and isinstance(S1, np.ndarray):
        return _compiled_result(*minmax_kernel.minmax3(m1, m2, S1, S2, _U_TOL, _MAX_NEWTON), lead)
    delta = m2 - m1
    scale = np.sqrt(np.maximum(sum(S1[i][i] for i in range(d)), sum(S2[i][i] for i in range(d))))
    coincident = np.sqrt(K.dot(delta, delta)) <= 1e-15 * scale
    # Keep the iteration well-defined for coincident means; they are patched at the end.
    dv = np.where(coincident[None, :], np.eye(d)[:, :1] * scale[None, :], delta) if np.any(coincident) else delta

    three = d == 3 and isinstance(S1, np.ndarray)
    u = _newton_polynomial(S1, S2, np.asarray(dv)) if three else _newton_direct(S1, S2, dv)
    t = np.exp(u)
    lam = t / (1.0 + t)
    if three:    # whole-array adjugate: x = adj(A) delta / det(A)
        a = t * S1 + S2
        adj = K.adjugate3(a)
        x = K.matvec(adj, np.asarray(dv)) / K.dots(a[0], adj[:, 0])
        q1 = K.dots(x, K.matvec(S1, x))
        q2 = K.dots(x, K.matvec(S2, x))
    else:
        x = np.array(K.mv(K.inv_sym(K.axpy(t, S1, S2)), dv))
        q1 = K.dot(x, K.mv(S1, x))
        q2 = K.dot(x, K.mv(S2, x))
    eta1 = t * np.sqrt(q1)
    eta2 = np.sqrt(q2)
    eta = 0.5 * (eta1 + eta2)
    residual = eta1 - eta2
    alpha = x * (1.0 + t)  # (lam S1 + (1-lam) S2)^-1 delta = (1 + t) x
    xn = np.sqrt(K.dots(x, x))
    normal = x / xn
    s1 = np.sqrt(q1) / xn
    s2 = np.sqrt(q2) / xn
    if np.any(coincident):
        eta = np.where(coincident, 0.0, eta)
        residual = np.where(coincident, 0.0, residual)
        alpha = np.where(coincident, 0.0, alpha)
    beta = K.dots(alpha, m1) + lam * K.quad(alpha, S1)
    ssum = s1 + s2

    def shaped(a: Array) -> Array:
        return a.reshape(lead)

    def shaped_vec(v: Array) -> Array:
        return v.T.reshape(lead + (d,))

    return MinmaxResult(
        lam=shaped(lam),
        eta=shaped(eta),
        alpha=shaped_vec(alpha),
        beta=shaped(beta),
        normal=shaped_vec(normal),
        s1=shaped(s1),
        s2=shaped(s2),
        eta_grad_mu1=shaped_vec(-normal / ssum),
        residual=shaped(residual),
    )


def _safeguarded_step(u: Array, phi: Array, dphi: Array, lo: Array,
                      hi: Array) -> tuple[Array, Array, Array, Array]:
    """One safeguarded Newton step on ``phi(u) = 0``: the new ``u``, the updated bracket, and
    where the step was a bisection rather than Newton's."""
    lo = np.where(phi < 0.0, np.maximum(lo, u), lo)
    hi = np.where(phi > 0.0, np.minimum(hi, u), hi)
    step = -phi / dphi
    new_u = u + step
    # Safeguard: stay inside the bracket the signs have shown; bisect where Newton leaves it.
    both = np.isfinite(lo) & np.isfinite(hi)
    # A bracket end can sit within rounding of the root (phi ~ 1e-16 there); a Newton step
    # that lands just beyond it is still good, so only a clear exit counts as leaving.
    slack = 1e-12 * (1.0 + np.abs(u))
    outside = (new_u < lo - slack) | (new_u > hi + slack)
    midpoint = 0.5 * (np.where(both, lo, 0.0) + np.where(both, hi, 0.0))
    bisected = outside & both
    new_u = np.where(bisected, midpoint, new_u)
    new_u = np.where(~both, u + np.clip(step, -4.0, 4.0), new_u)  # no two-sided bracket yet: cap every step
    return new_u, lo, hi, bisected


def _still_moving(new_u: Array, u: Array, bisected: Array) -> Array:
    """Pairs that need another step: a Newton step above ``_U_TOL`` or a bisection step above
    ``_U_TOL**2`` (relative to ``max(1, |u|)``)."""
    tol = np.where(bisected, _U_TOL * _U_TOL, _U_TOL)
    return np.abs(new_u - u) > tol * np.maximum(1.0, np.abs(u))


def _newton_polynomial(S1: Array, S2: Array, delta: Array) -> Array:
    """``u = log t`` solving ``phi(u) = 0`` for 3x3 pairs, with ``phi`` a ratio of two quartics in ``t``.

    ``adj(t S1 + S2) = t^2 adj(S1) + t M + adj(S2)`` with ``M = adj(S1 + S2) - adj(S1) - adj(S2)``,
    so ``x`` is parallel to ``v(t) = t^2 a2 + t a1 + a0`` (``a2 = adj(S1) delta``, ...) and
    ``phi(u) = 2u + log(n1(t)) - log(n2(t))`` with the quartics ``n_k(t) = v(t)'S_k v(t)``
    (the determinant cancels); ``phi'(u) = 2 + t (n1'(t) / n1 - n2'(t) / n2)``. Because
    ``adj(S) S = det(S) I``, most coefficients are ``det(S_k)`` times a quadratic form of
    ``delta`` with a positive definite adjugate:

        n1 = det1 (d'a2) t^4 + 2 det1 (d'a1) t^3 + (a1'S1a1 + 2 det1 d'a0) t^2 + 2 a1'S1a0 t + a0'S1a0
        n2 = a2'S2a2 t^4 + 2 a1'S2a2 t^3 + (a1'S2a1 + 2 det2 d'a2) t^2 + 2 det2 (d'a1) t + det2 d'a0

    so only the ``t`` (resp. ``t^3``) coefficient can be negative and the expansion loses
    little to cancellation. The ten coefficients are computed once per pair; a Newton
    step is then about twenty whole-array operations on ``(2, n)`` arrays, whatever ``d``
    costs elsewhere. The final separator is evaluated from ``A(t)^-1`` directly (in
    :func:`_minmax`), so the coefficients only locate the root.

    The iteration starts one fixed-point step from ``t = 1``, ``u = -0.5 log(n1(1) / n2(1))``
    (the sums of the coefficients): the root when ``x`` does not turn with ``t``, as when
    ``S2 = g S1``. On the benchmark's 10,000 random pairs its median distance to the root is
    0.03, against 0.44 for the geometric mean of the generalised eigenvalues.
    """
    adj1, adj2 = K.adjugate3(S1), K.adjugate3(S2)
    mixed = K.adjugate3(S1 + S2) - adj1 - adj2
    a2, a1, a0 = K.matvec(adj1, delta), K.matvec(mixed, delta), K.matvec(adj2, delta)
    det1 = K.dots(S1[0], adj1[:, 0])        # det(S) = S[0] . adj(S)[:, 0]
    det2 = K.dots(S2[0], adj2[:, 0])
    d2, d1, d0 = K.dots(delta, a2), K.dots(delta, a1), K.dots(delta, a0)
    s1a1, s2a1 = K.matvec(S1, a1), K.matvec(S2, a1)
    coef = np.empty((5, 2, det1.shape[0]))     # coef[k, j]: t^k coefficient of n_{j+1}
    coef[4, 0], coef[4, 1] = det1 * d2, K.dots(a2, K.matvec(S2, a2))
    coef[3, 0], coef[3, 1] = 2.0 * det1 * d1, 2.0 * K.dots(a2, s2a1)
    coef[2, 0], coef[2, 1] = K.dots(a1, s1a1) + 2.0 * det1 * d0, K.dots(a1, s2a1) + 2.0 * det2 * d2
    coef[1, 0], coef[1, 1] = 2.0 * K.dots(a0, s1a1), 2.0 * det2 * d1
    coef[0, 0], coef[0, 1] = K.dots(a0, K.matvec(S1, a0)), det2 * d0
    slope = coef[1:] * np.arange(1.0, 5.0)[:, None, None]      # t^(k-1) coefficients of n'
    u = -0.5 * np.log((coef[4, 0] + coef[3, 0] + coef[2, 0] + coef[1, 0] + coef[0, 0])
                      / (coef[4, 1] + coef[3, 1] + coef[2, 1] + coef[1, 1] + coef[0, 1]))
    n = u.shape[0]
    lo = np.full(n, -np.inf)
    hi = np.full(n, np.inf)
    idx = None  # all pairs iterate until most converge, then only the rest
    active = None  # pairs of the current batch still iterating (a converged pair is frozen)
    for _ in range(_MAX_NEWTON):
        ua = u if idx is None else u[idx]
        t = np.exp(ua)
        val = coef[4] * t + coef[3]
        der = slope[3] * t + slope[2]
        for k in (2, 1):
            val *= t
            val += coef[k]
            der *= t
            der += slope[k - 1]
        val *= t
        val += coef[0]
        phi = 2.0 * ua + np.log(val[0] / val[1])
        dphi = 2.0 + t * (der[0] / val[0] - der[1] / val[1])
        la, ha = (lo, hi) if idx is None else (lo[idx], hi[idx])
        new_u, la, ha, bisected = _safeguarded_step(ua, phi, dphi, la, ha)
        keep = _still_moving(new_u, ua, bisected)
        if active is not None:     # frozen pairs keep their value: each pair's result is batch-independent
            new_u = np.where(active, new_u, ua)
            keep &= active
        if idx is None:
            u, lo, hi = new_u, la, ha
        else:
            u[idx], lo[idx], hi[idx] = new_u, la, ha
        left = int(np.count_nonzero(keep))
        if left == 0:
            return u
        if 2 * left < keep.size:      # compacting costs a gather per array: only when it halves the work
            idx = np.flatnonzero(keep) if idx is None else idx[keep]
            coef, slope = coef[:, :, keep], slope[:, :, keep]
            active = None
        elif left < keep.size:
            active = keep
    logger.warning("minmax: Newton iteration hit %d steps on %d pair(s)", _MAX_NEWTON, n if idx is None else idx.size)
    return u


def _newton_direct(S1, S2, dv) -> Array:
    """``u = log t`` solving ``phi(u) = 0`` for any dimension, solving ``A(t) x = delta`` at each step.

    Starts as :func:`_newton_polynomial` does, one fixed-point step from ``t = 1``:
    ``u = -0.5 log(q1 / q2)``, ``q_k = x' S_k x``, ``x = (S1 + S2)^-1 delta``.
    """
    x = K.mv(K.inv_sym(K.axpy(1.0, S1, S2)), dv)
    u = -0.5 * (np.log(K.dot(x, K.mv(S1, x))) - np.log(K.dot(x, K.mv(S2, x))))
    n = u.shape[0]
    lo = np.full(n, -np.inf)
    hi = np.full(n, np.inf)
    idx = np.arange(n)  # pairs still iterating
    S1a, S2a, da = S1, S2, dv
    for _ in range(_MAX_NEWTON):
        ua = u[idx]
        t = np.exp(ua)
        a_inv = K.inv_sym(K.axpy(t, S1a, S2a))
        x = K.mv(a_inv, da)
        y = K.mv(S1a, x)
        q1 = K.dot(x, y)
        q2 = K.dot(x, K.mv(S2a, x))
        w = K.dot(y, K.mv(a_inv, y))
        v = q1 - t * w
        phi = 2.0 * ua + np.log(q1) - np.log(q2)  # log(eta1^2 / eta2^2), increasing in u
        dphi = 2.0 - 2.0 * t * w / q1 + 2.0 * t * v / q2
        new_u, lo[idx], hi[idx], bisected = _safeguarded_step(ua, phi, dphi, lo[idx], hi[idx])
        u[idx] = new_u
        keep = _still_moving(new_u, ua, bisected)
        if not np.any(keep):
            return u
        if not np.all(keep):
            idx = idx[keep]
            S1a, S2a, da = K.take(S1a, keep), K.take(S2a, keep), K.take(da, keep)
    logger.warning("minmax: Newton iteration hit %d steps on %d pair(s)", _MAX_NEWTON, idx.size)
    return u


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
    n = _checked("normal", normal, 1)
    m1, m2, pairs = _validate_pair(*_broadcast_means(mu1, cov1, mu2, cov2, n.shape[:-1], np.shape(radius_sum)))
    lead, d = pairs.lead, pairs.dim
    radius = np.asarray(radius_sum, dtype=float)
    return _support_margin(m1, m2, pairs, K.vectors_to_components(np.broadcast_to(n, lead + (d,))),
                           np.broadcast_to(radius, lead).ravel()).reshape(lead)


def _broadcast_means(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike,
                     *extra: tuple[int, ...]) -> tuple[Array, ArrayLike, ArrayLike, ArrayLike]:
    """``mu1`` broadcast so that the pair also covers the leading shapes ``extra`` (normals, radii)."""
    m1 = _checked("mu1", mu1, 1)
    try:
        lead = np.broadcast_shapes(m1.shape[:-1], *extra)
    except ValueError as exc:
        raise InputError(f"leading dimensions do not broadcast: {exc}") from None
    return np.broadcast_to(m1, lead + m1.shape[-1:]), cov1, mu2, cov2


def _support_margin(m1: Array, m2: Array, pairs: CovariancePairs, normal: Array, radius: Array,
                    spread: Array | None = None) -> Array:
    """:func:`support_margin` on validated components (means and normals (d, n), radii (n,)).

    ``spread``: ``s1 + s2`` along ``normal`` when the caller has it (then ``normal`` must
    be unit already, as minmax's is); computed here otherwise.
    """
    n = normal
    if spread is None:
        n = normal / np.sqrt(K.dot(normal, normal))
        spread = np.sqrt(K.quad(n, pairs.s1)) + np.sqrt(K.quad(n, pairs.s2))
    return (K.dot(n, m2 - m1) - radius) / spread


def contour_of_touch(
    mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike, radius_sum: ArrayLike = 0.0
) -> Array:
    """Confidence contour at which the two (body-inflated) ellipsoids touch.

    ``F_chi2_d(m^2)`` with ``m`` the :func:`support_margin` at the minmax normal (0 when the
    inflated bodies already overlap at radius 0). Exact for ``radius_sum = 0``; with radii
    it is the contour the planner's constraint guarantees, a lower bound of the exact one.
    """
    radius = np.asarray(radius_sum, dtype=float)
    m1, m2, pairs = _validate_pair(*_broadcast_means(mu1, cov1, mu2, cov2, radius.shape))
    lead, d = pairs.lead, pairs.dim
    res = _minmax(m1, m2, pairs.s1, pairs.s2, pairs.lead)
    normal = K.vectors_to_components(res.normal)
    margin = _support_margin(m1, m2, pairs, normal, np.broadcast_to(radius, lead).ravel(),
                             (res.s1 + res.s2).ravel()).reshape(lead)
    return special.gammainc(d / 2.0, 0.5 * np.square(np.maximum(margin, 0.0)))


# --------------------------------------------------------------------------------------
# Bhattacharyya distance (the paper's entropic baseline).
# --------------------------------------------------------------------------------------


def bhattacharyya(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike) -> Array | float:
    """Bhattacharyya distance ``1/8 dmu' S^-1 dmu + 1/2 ln(det S / sqrt(det S1 det S2))``, ``S = (S1 + S2)/2``."""
    m1, m2, pairs = _validate_pair(mu1, cov1, mu2, cov2)
    s = K.combine(0.5, pairs.s1, 0.5, pairs.s2)
    db = 0.125 * K.quad(m2 - m1, K.inv_sym(s)) + 0.5 * (
        np.log(K.det(s)) - 0.5 * (np.log(K.det(pairs.s1)) + np.log(K.det(pairs.s2))))
    db = db.reshape(pairs.lead)
    return float(db) if db.ndim == 0 else db


def bhattacharyya_grad_mu1(mu1: ArrayLike, cov1: ArrayLike, mu2: ArrayLike, cov2: ArrayLike) -> Array:
    """Gradient of :func:`bhattacharyya` with respect to ``mu1``: ``-1/4 S^-1 (mu2 - mu1)``."""
    m1, m2, pairs = _validate_pair(mu1, cov1, mu2, cov2)
    g = K.mv(K.inv_sym(K.combine(0.5, pairs.s1, 0.5, pairs.s2)), m2 - m1)
    return -0.25 * K.from_components(g).reshape(pairs.lead + (len(g),))


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
    m1, m2, pairs = _validate_pair(mu1, cov1, mu2, cov2)
    lam_a = np.asarray(lam, dtype=float)
    if not np.all(np.isfinite(lam_a)) or np.any(lam_a <= 0.0) or np.any(lam_a >= 1.0):
        raise InputError("lam must lie in the open interval (0, 1)")
    lead = pairs.lead
    lam_a = np.broadcast_to(lam_a, lead).ravel()
    radius = np.broadcast_to(np.asarray(radius_sum, dtype=float), lead).ravel()
    delta = m2 - m1
    a_inv = K.inv_sym(K.combine(lam_a, pairs.s1, 1.0 - lam_a, pairs.s2))
    alpha = np.array(K.mv(a_inv, delta))
    s1a = np.array(K.mv(pairs.s1, alpha))
    s2a = np.array(K.mv(pairs.s2, alpha))
    q1 = K.dot(alpha, s1a)
    q2 = K.dot(alpha, s2a)
    r1, r2 = np.sqrt(q1), np.sqrt(q2)
    na = np.sqrt(K.dot(alpha, alpha))
    den = r1 + r2
    num = K.dot(alpha, delta) - radius * na
    h = num / den
    # dh/dalpha = (delta - R alpha/|alpha|)/den - num/den^2 (S1 alpha/sqrt(q1) + S2 alpha/sqrt(q2))
    dh_dalpha = (delta - (radius / na) * alpha) / den - (num / den**2) * (s1a / r1 + s2a / r2)
    dalpha_dlam = -np.array(K.mv(a_inv, s1a - s2a))
    h_grad_mu1 = -alpha / den - np.array(K.mv(a_inv, dh_dalpha))  # d delta/d mu1 = -I, d alpha/d mu1 = -A^-1
    h_grad_lam = K.dot(dh_dalpha, dalpha_dlam)
    # g = lam^2 q1 - (1-lam)^2 q2
    g = lam_a**2 * q1 - (1.0 - lam_a) ** 2 * q2
    dg_dalpha = 2.0 * lam_a**2 * s1a - 2.0 * (1.0 - lam_a) ** 2 * s2a
    g_grad_mu1 = -np.array(K.mv(a_inv, dg_dalpha))
    g_grad_lam = 2.0 * lam_a * q1 + 2.0 * (1.0 - lam_a) * q2 + K.dot(dg_dalpha, dalpha_dlam)
    d = delta.shape[0]

    def vec(v: Array) -> Array:
        return v.T.reshape(lead + (d,))

    return PaperTerms(h=h.reshape(lead), h_grad_mu1=vec(h_grad_mu1), h_grad_lam=h_grad_lam.reshape(lead),
                      g=g.reshape(lead), g_grad_mu1=vec(g_grad_mu1), g_grad_lam=g_grad_lam.reshape(lead))
