"""Planner-facing terms: paper_terms gradients, eta gradient, support margin, contour of touch.

Gradients are checked against central finite differences of the values, and the values
against the formulas of docs/METHOD.md (sections 1.4 and 2.6) computed here in plain numpy.
"""

from __future__ import annotations

import numpy as np
import pytest

from companion.core.overlap import contour_of_touch, minmax, paper_terms, support_margin


def _spd(rng: np.random.Generator, d: int, spread: float = 2.0) -> np.ndarray:
    q, _ = np.linalg.qr(rng.standard_normal((d, d)))
    cov = (q * 10.0 ** rng.uniform(-spread / 2, spread / 2, d)) @ q.T
    return 0.5 * (cov + cov.T)


def _pairs(seed: int, count: int = 8):
    rng = np.random.default_rng(seed)
    for k in range(count):
        d = 2 + k % 2
        mu1 = rng.standard_normal(d)
        yield mu1, _spd(rng, d), mu1 + 3 * rng.standard_normal(d), _spd(rng, d), rng


def _central(f, x: np.ndarray, h: float) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    out = np.empty(x.shape)
    for i in np.ndindex(x.shape):
        e = np.zeros_like(x)
        e[i] = h
        out[i] = (f(x + e) - f(x - e)) / (2 * h)
    return out


@pytest.mark.parametrize("radius_sum", [0.0, 0.4])
def test_that_paper_terms_gradients_match_central_finite_differences(radius_sum):
    for mu1, cov1, mu2, cov2, rng in _pairs(31):
        lam = rng.uniform(0.2, 0.8)
        terms = paper_terms(mu1, cov1, mu2, cov2, lam, radius_sum)
        h_mu = _central(lambda m: float(paper_terms(m, cov1, mu2, cov2, lam, radius_sum).h), mu1, 1e-6)
        g_mu = _central(lambda m: float(paper_terms(m, cov1, mu2, cov2, lam, radius_sum).g), mu1, 1e-6)
        h_lam = _central(lambda x: float(paper_terms(mu1, cov1, mu2, cov2, x, radius_sum).h), np.array(lam), 1e-6)
        g_lam = _central(lambda x: float(paper_terms(mu1, cov1, mu2, cov2, x, radius_sum).g), np.array(lam), 1e-6)
        np.testing.assert_allclose(terms.h_grad_mu1, h_mu, rtol=1e-5, atol=1e-7 * np.abs(h_mu).max())
        np.testing.assert_allclose(terms.g_grad_mu1, g_mu, rtol=1e-5, atol=1e-7 * np.abs(g_mu).max())
        np.testing.assert_allclose(terms.h_grad_lam, h_lam, rtol=1e-5, atol=1e-7 * abs(float(terms.h)))
        np.testing.assert_allclose(terms.g_grad_lam, g_lam, rtol=1e-5, atol=1e-9)


def test_that_paper_terms_values_follow_the_formulas_of_the_method():
    for mu1, cov1, mu2, cov2, rng in _pairs(32):
        lam, radius = rng.uniform(0.1, 0.9), rng.uniform(0.0, 0.5)
        alpha = np.linalg.solve(lam * cov1 + (1 - lam) * cov2, mu2 - mu1)
        q1, q2 = alpha @ cov1 @ alpha, alpha @ cov2 @ alpha
        terms = paper_terms(mu1, cov1, mu2, cov2, lam, radius)
        h = (alpha @ (mu2 - mu1) - radius * np.linalg.norm(alpha)) / (np.sqrt(q1) + np.sqrt(q2))
        assert float(terms.h) == pytest.approx(h, rel=1e-10)
        assert float(terms.g) == pytest.approx(lam**2 * q1 - (1 - lam) ** 2 * q2, rel=1e-9, abs=1e-12 * (q1 + q2))


def test_that_at_the_admissible_lam_g_vanishes_and_h_is_the_support_margin_at_the_minmax_normal():
    for mu1, cov1, mu2, cov2, rng in _pairs(33):
        res = minmax(mu1, cov1, mu2, cov2)
        at_zero = paper_terms(mu1, cov1, mu2, cov2, res.lam, 0.0)
        assert abs(float(at_zero.g)) <= 1e-10 * float(res.lam**2 * res.alpha @ cov1 @ res.alpha)
        assert float(at_zero.h) == pytest.approx(float(res.eta), rel=1e-10)
        radius = rng.uniform(0.1, 1.0)
        with_r = paper_terms(mu1, cov1, mu2, cov2, res.lam, radius)
        assert float(with_r.h) == pytest.approx(float(support_margin(mu1, cov1, mu2, cov2, res.normal, radius)), rel=1e-10)


def test_that_the_eta_gradient_matches_finite_differences_of_eta():
    for mu1, cov1, mu2, cov2, _ in _pairs(34):
        res = minmax(mu1, cov1, mu2, cov2)
        fd = _central(lambda m: float(minmax(m, cov1, mu2, cov2).eta), mu1, 1e-6)
        np.testing.assert_allclose(res.eta_grad_mu1, fd, rtol=1e-6, atol=1e-8 * np.abs(fd).max())


def test_that_support_margin_follows_the_method_and_ignores_the_length_of_the_normal():
    for mu1, cov1, mu2, cov2, rng in _pairs(35):
        n = rng.standard_normal(mu1.size)
        u = n / np.linalg.norm(n)
        radius = rng.uniform(0, 1)
        expected = (u @ (mu2 - mu1) - radius) / (np.sqrt(u @ cov1 @ u) + np.sqrt(u @ cov2 @ u))
        assert float(support_margin(mu1, cov1, mu2, cov2, 7.5 * n, radius)) == pytest.approx(expected, rel=1e-12)


def test_that_no_unit_normal_has_a_larger_margin_than_the_minmax_normal():
    for mu1, cov1, mu2, cov2, rng in _pairs(36):
        res = minmax(mu1, cov1, mu2, cov2)
        best = float(support_margin(mu1, cov1, mu2, cov2, res.normal, 0.0))
        assert best == pytest.approx(float(res.eta), rel=1e-12)
        normals = rng.standard_normal((500, mu1.size))
        margins = support_margin(mu1, cov1, mu2, cov2, normals, 0.0)  # normals broadcast as a batch
        assert margins.shape == (500,)
        assert np.all(margins <= best * (1 + 1e-12))


def test_that_contour_of_touch_equals_minmax_confidence_without_radii_and_drops_with_radii():
    for mu1, cov1, mu2, cov2, _ in _pairs(37):
        res = minmax(mu1, cov1, mu2, cov2)
        c0 = float(contour_of_touch(mu1, cov1, mu2, cov2, 0.0))
        assert c0 == pytest.approx(float(res.confidence), rel=1e-12, abs=1e-15)
        radii = np.array([0.05, 0.2, 0.5])
        c = np.array([float(contour_of_touch(mu1, cov1, mu2, cov2, r)) for r in radii])
        np.testing.assert_allclose(contour_of_touch(mu1, cov1, mu2, cov2, radii), c, rtol=1e-12)  # radii broadcast
        assert np.all(np.diff(np.concatenate([[c0], c])) <= 0)
        if 0 < c0 < 1:
            assert c[0] < c0
    # bodies that already overlap at radius zero: contour of touch 0
    assert float(contour_of_touch([0.0, 0.0], np.eye(2), [1.0, 0.0], np.eye(2), 2.0)) == 0.0
