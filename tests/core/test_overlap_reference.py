"""Overlap core against published values and closed forms (docs/METHOD.md section 1.6, the paper).

References here are independent of ``companion.core.overlap``: ``scipy.stats.chi2`` and
``scipy.stats.norm`` for the confidence/radius/overlap maps, a direct numpy formula for
the Bhattacharyya distance, and the closed form for equal covariances.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from companion.core.overlap import (
    bhattacharyya,
    bhattacharyya_grad_mu1,
    confidence_from_overlap,
    confidence_from_radius,
    minmax,
    overlap_from_confidence,
    overlap_from_radius,
    touch_radius,
)

# (d, c, r, Y) as printed in docs/METHOD.md section 1.6 (the paper's values).
REFERENCE_ROWS = [
    (2, 0.8051, 1.8085, 0.0705),
    (3, 0.60, 1.7164, 0.0861),
    (3, 0.30, 1.1932, 0.2328),
    (3, 0.90, 2.5003, 0.0124),
    (2, 0.90, 2.1460, 0.0319),
]

# The paper's two Bhattacharyya pairs (2-D), separation axis, expected distance.
BHATTACHARYYA_PAIRS = [
    (np.diag([0.01, 0.02]), np.diag([0.03, 0.03]), 0, 1.6079),
    (np.array([[0.04, 0.0], [0.0, 0.02]]), np.array([[0.02, 0.01], [0.01, 0.02]]), 1, 1.7108),
]


def _paper_pair(cov1: np.ndarray, cov2: np.ndarray, axis: int, confidence: float = 0.8051):
    """Means separated along ``axis`` so that the pair touches at ``confidence``.

    ``eta`` is linear in the separation, so the separation is the chi2 touch radius
    divided by ``eta`` at unit separation.
    """
    unit = np.zeros(2)
    unit[axis] = 1.0
    eta_unit = float(minmax(np.zeros(2), cov1, unit, cov2).eta)
    r = float(np.sqrt(stats.chi2.ppf(confidence, 2)))
    return np.zeros(2), unit * (r / eta_unit)


def _rounds_to(value: float, printed: float, decimals: int = 4) -> bool:
    return abs(value - printed) <= 0.5 * 10.0**-decimals + 1e-12


@pytest.mark.parametrize(("dim", "c", "r_ref", "y_ref"), REFERENCE_ROWS)
def test_that_every_reference_row_is_reproduced_to_the_printed_decimals(dim, c, r_ref, y_ref):
    r = touch_radius(c, dim)
    y = overlap_from_confidence(c, dim)
    assert _rounds_to(r, r_ref), (r, r_ref)
    assert _rounds_to(y, y_ref), (y, y_ref)


@pytest.mark.parametrize(("dim", "c", "r_ref", "y_ref"), REFERENCE_ROWS)
def test_that_the_maps_agree_with_scipy_stats_chi2_and_norm(dim, c, r_ref, y_ref):
    r_scipy = np.sqrt(stats.chi2.ppf(c, dim))
    assert touch_radius(c, dim) == pytest.approx(r_scipy, rel=1e-12)
    assert overlap_from_confidence(c, dim) == pytest.approx(2.0 * stats.norm.sf(r_scipy), rel=1e-12)
    assert confidence_from_radius(r_scipy, dim) == pytest.approx(c, rel=1e-12)
    assert overlap_from_radius(r_scipy) == pytest.approx(2.0 * stats.norm.sf(r_scipy), rel=1e-12)


@pytest.mark.parametrize("dim", [1, 2, 3, 6])
def test_that_confidence_overlap_and_radius_round_trip(dim):
    c = np.linspace(0.01, 0.999, 57)
    r = touch_radius(c, dim)
    y = overlap_from_confidence(c, dim)
    np.testing.assert_allclose(confidence_from_overlap(y, dim), c, rtol=1e-10)
    np.testing.assert_allclose(confidence_from_radius(r, dim), c, rtol=1e-10)
    np.testing.assert_allclose(overlap_from_radius(r), y, rtol=1e-12)
    # and against scipy on the whole grid
    np.testing.assert_allclose(r, np.sqrt(stats.chi2.ppf(c, dim)), rtol=1e-10)
    np.testing.assert_allclose(confidence_from_overlap(y, dim), stats.chi2.cdf(stats.norm.isf(y / 2) ** 2, dim), rtol=1e-10)


def test_that_overlap_decreases_as_the_contour_of_touch_grows():
    c = np.linspace(0.05, 0.99, 40)
    for dim in (2, 3):
        assert np.all(np.diff(overlap_from_confidence(c, dim)) < 0)
    # at equal confidence a higher-dimensional ellipsoid is larger, so the overlap is smaller
    assert np.all(overlap_from_confidence(c, 3) < overlap_from_confidence(c, 2))


def test_that_negative_radius_maps_to_zero_confidence():
    assert confidence_from_radius(-0.5, 3) == 0.0
    assert overlap_from_radius(0.0) == pytest.approx(1.0)


@pytest.mark.parametrize(("cov1", "cov2", "axis", "expected"), BHATTACHARYYA_PAIRS)
def test_that_the_paper_bhattacharyya_pairs_touch_at_80_51_percent_with_overlap_0_0705(cov1, cov2, axis, expected):
    mu1, mu2 = _paper_pair(cov1, cov2, axis)
    res = minmax(mu1, cov1, mu2, cov2)
    assert float(res.confidence) == pytest.approx(0.8051, abs=1e-12)
    assert _rounds_to(float(res.overlap), 0.0705)
    assert _rounds_to(float(bhattacharyya(mu1, cov1, mu2, cov2)), expected)


def test_that_two_pairs_with_equal_overlap_have_different_bhattacharyya_distances():
    overlaps, distances = [], []
    for cov1, cov2, axis, _ in BHATTACHARYYA_PAIRS:
        mu1, mu2 = _paper_pair(cov1, cov2, axis)
        overlaps.append(float(minmax(mu1, cov1, mu2, cov2).overlap))
        distances.append(float(bhattacharyya(mu1, cov1, mu2, cov2)))
    assert overlaps[0] == pytest.approx(overlaps[1], rel=1e-12)
    assert overlaps[0] == pytest.approx(2.0 * stats.norm.sf(np.sqrt(stats.chi2.ppf(0.8051, 2))), rel=1e-12)
    assert abs(distances[1] - distances[0]) > 0.1  # 1.7108 vs 1.6079


def _bhattacharyya_reference(mu1, cov1, mu2, cov2) -> float:
    s = 0.5 * (cov1 + cov2)
    dmu = mu2 - mu1
    _, ld = np.linalg.slogdet(s)
    _, ld1 = np.linalg.slogdet(cov1)
    _, ld2 = np.linalg.slogdet(cov2)
    return 0.125 * dmu @ np.linalg.solve(s, dmu) + 0.5 * (ld - 0.5 * (ld1 + ld2))


def _random_spd(rng: np.random.Generator, d: int, log10_spread: float = 2.0) -> np.ndarray:
    q, _ = np.linalg.qr(rng.standard_normal((d, d)))
    return (q * 10.0 ** rng.uniform(-log10_spread / 2, log10_spread / 2, d)) @ q.T


@pytest.mark.parametrize("dim", [2, 3, 4])
def test_that_bhattacharyya_matches_a_direct_numpy_formula_on_random_pairs(dim):
    rng = np.random.default_rng(11 + dim)
    pairs = [(rng.standard_normal(dim), _random_spd(rng, dim), rng.standard_normal(dim), _random_spd(rng, dim)) for _ in range(20)]
    expected = [_bhattacharyya_reference(*p) for p in pairs]
    batch = bhattacharyya(*(np.stack(x) for x in zip(*pairs)))
    np.testing.assert_allclose(batch, expected, rtol=1e-10)
    assert bhattacharyya(*pairs[0]) == pytest.approx(expected[0], rel=1e-10)


def test_that_bhattacharyya_grad_mu1_matches_finite_differences():
    rng = np.random.default_rng(5)
    for _ in range(10):
        mu1, cov1, mu2, cov2 = rng.standard_normal(3), _random_spd(rng, 3), rng.standard_normal(3), _random_spd(rng, 3)
        h = 1e-6
        fd = np.array(
            [
                (_bhattacharyya_reference(mu1 + h * e, cov1, mu2, cov2) - _bhattacharyya_reference(mu1 - h * e, cov1, mu2, cov2)) / (2 * h)
                for e in np.eye(3)
            ]
        )
        np.testing.assert_allclose(bhattacharyya_grad_mu1(mu1, cov1, mu2, cov2), fd, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_that_equal_covariances_give_lam_one_half_and_half_the_mahalanobis_distance(dim):
    rng = np.random.default_rng(21 + dim)
    for _ in range(25):
        cov = _random_spd(rng, dim, log10_spread=4.0)
        mu1, mu2 = rng.standard_normal(dim), 3.0 * rng.standard_normal(dim)
        dmu = mu2 - mu1
        mahalanobis = np.sqrt(dmu @ np.linalg.solve(cov, dmu))
        res = minmax(mu1, cov, mu2, cov)
        assert float(res.lam) == pytest.approx(0.5, abs=1e-12)
        assert float(res.eta) == pytest.approx(0.5 * mahalanobis, rel=1e-12)
        # Fisher's discriminant direction S^-1 (mu2 - mu1), and the hyperplane through the midpoint
        fisher = np.linalg.solve(cov, dmu)
        np.testing.assert_allclose(res.normal, fisher / np.linalg.norm(fisher), rtol=1e-10, atol=1e-12)
        assert float(res.beta) == pytest.approx(float(res.alpha @ (0.5 * (mu1 + mu2))), rel=1e-10, abs=1e-12)
