"""Hypothesis properties of ``minmax``: symmetry, invariances, homogeneity, admissibility, batching."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.overlap import minmax

SETTINGS = settings(max_examples=100, deadline=None, derandomize=True)


@st.composite
def gaussian_pairs(draw, log10_spread: float = 4.0):
    """A pair of Gaussians in 2 or 3 dimensions; eigenvalues spread over ``log10_spread`` decades."""
    d = draw(st.sampled_from([2, 3]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)

    def spd() -> np.ndarray:
        q, _ = np.linalg.qr(rng.standard_normal((d, d)))
        cov = (q * 10.0 ** rng.uniform(-log10_spread / 2, log10_spread / 2, d)) @ q.T
        return 0.5 * (cov + cov.T)

    mu1 = rng.standard_normal(d) * 5
    mu2 = mu1 + rng.standard_normal(d) * draw(st.floats(0.01, 20.0))
    return mu1, spd(), mu2, spd(), rng


@SETTINGS
@given(gaussian_pairs())
def test_that_swapping_the_gaussians_maps_lam_to_one_minus_lam_and_keeps_eta(pair):
    mu1, cov1, mu2, cov2, _ = pair
    a = minmax(mu1, cov1, mu2, cov2)
    b = minmax(mu2, cov2, mu1, cov1)
    np.testing.assert_allclose(b.lam, 1.0 - a.lam, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(b.eta, a.eta, rtol=1e-9)
    np.testing.assert_allclose(b.normal, -a.normal, atol=1e-7)


@SETTINGS
@given(gaussian_pairs(), st.lists(st.floats(-100.0, 100.0), min_size=3, max_size=3))
def test_that_translating_both_means_changes_nothing(pair, shift):
    mu1, cov1, mu2, cov2, _ = pair
    shift = np.asarray(shift[: mu1.size])
    a = minmax(mu1, cov1, mu2, cov2)
    b = minmax(mu1 + shift, cov1, mu2 + shift, cov2)
    np.testing.assert_allclose(b.eta, a.eta, rtol=1e-9)
    np.testing.assert_allclose(b.lam, a.lam, rtol=1e-9)
    np.testing.assert_allclose(b.normal, a.normal, atol=1e-8)
    # the hyperplane moves with the means: beta shifts by alpha.shift
    np.testing.assert_allclose(b.beta, a.beta + a.alpha @ shift, rtol=1e-7, atol=1e-7 * np.abs(a.alpha).sum() * (1 + np.abs(shift).sum()))


@SETTINGS
@given(gaussian_pairs())
def test_that_rotating_the_frame_rotates_the_normal_and_keeps_eta_and_lam(pair):
    mu1, cov1, mu2, cov2, rng = pair
    q, _ = np.linalg.qr(rng.standard_normal((mu1.size, mu1.size)))  # orthogonal (maybe a reflection)
    a = minmax(mu1, cov1, mu2, cov2)
    b = minmax(q @ mu1, q @ cov1 @ q.T, q @ mu2, q @ cov2 @ q.T)
    np.testing.assert_allclose(b.eta, a.eta, rtol=1e-8)
    np.testing.assert_allclose(b.lam, a.lam, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(b.normal, q @ a.normal, atol=1e-6)


@SETTINGS
@given(gaussian_pairs(), st.floats(1e-3, 1e3))
def test_that_scaling_the_mean_separation_by_k_scales_eta_by_k(pair, k):
    mu1, cov1, mu2, cov2, _ = pair
    a = minmax(mu1, cov1, mu2, cov2)
    b = minmax(mu1, cov1, mu1 + k * (mu2 - mu1), cov2)
    np.testing.assert_allclose(b.eta, k * a.eta, rtol=1e-9)
    np.testing.assert_allclose(b.lam, a.lam, rtol=1e-8, atol=1e-12)


@SETTINGS
@given(gaussian_pairs())
def test_that_the_admissibility_residual_vanishes_and_eta_overlap_are_in_range(pair):
    mu1, cov1, mu2, cov2, _ = pair
    r = minmax(mu1, cov1, mu2, cov2)
    # recompute eta1, eta2 from the returned alpha, beta with the formulas of docs/METHOD.md section 1.1
    eta1 = (r.beta - r.alpha @ mu1) / np.sqrt(r.alpha @ cov1 @ r.alpha)
    eta2 = (r.alpha @ mu2 - r.beta) / np.sqrt(r.alpha @ cov2 @ r.alpha)
    assert abs(eta1 - eta2) <= 1e-10 * eta1
    assert abs(float(r.residual)) <= 1e-10 * float(r.eta)
    np.testing.assert_allclose(eta1, r.eta, rtol=1e-10)
    assert 0.0 < float(r.lam) < 1.0
    assert float(r.eta) >= 0.0
    assert 0.0 <= float(r.overlap) <= 1.0  # underflows to 0 for eta beyond ~38
    assert 0.0 <= float(r.confidence) <= 1.0  # rounds to 1 for eta beyond ~8.5
    assert abs(np.linalg.norm(r.normal) - 1.0) < 1e-14
    # alpha is docs/METHOD.md section 1.1's (lam S1 + (1-lam) S2)^-1 (mu2 - mu1)
    alpha = np.linalg.solve(r.lam * cov1 + (1 - r.lam) * cov2, mu2 - mu1)
    np.testing.assert_allclose(r.alpha, alpha, rtol=1e-6, atol=1e-9 * np.abs(alpha).max())


@settings(max_examples=30, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1), st.sampled_from([2, 3]))
def test_that_batch_results_equal_per_pair_results(seed, d):
    rng = np.random.default_rng(seed)
    n = 12
    q = np.linalg.qr(rng.standard_normal((2 * n, d, d)))[0]
    ev = 10.0 ** rng.uniform(-2, 2, (2 * n, d))
    covs = np.einsum("nij,nj,nkj->nik", q, ev, q)
    covs = 0.5 * (covs + np.swapaxes(covs, -1, -2))
    mu1 = rng.standard_normal((n, d))
    mu2 = mu1 + rng.standard_normal((n, d)) * 3
    mu2[0] = mu1[0]  # one coincident pair in the batch must not disturb the others
    batch = minmax(mu1, covs[:n], mu2, covs[n:])
    for i in range(n):
        single = minmax(mu1[i], covs[i], mu2[i], covs[n + i])
        for field in ("lam", "eta", "beta", "overlap", "confidence", "s1", "s2", "residual"):
            np.testing.assert_allclose(getattr(batch, field)[i], getattr(single, field), rtol=1e-12, atol=1e-15, err_msg=field)
        for field in ("alpha", "normal", "eta_grad_mu1"):
            np.testing.assert_allclose(getattr(batch, field)[i], getattr(single, field), rtol=1e-12, atol=1e-15, err_msg=field)

