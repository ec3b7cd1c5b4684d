"""Input validation of the overlap core: each error says what was wrong and where."""

from __future__ import annotations

import numpy as np
import pytest

from companion.errors import InputError
from companion.core.overlap import (
    bhattacharyya,
    confidence_from_overlap,
    minmax,
    overlap_from_confidence,
    paper_terms,
    support_margin,
    touch_radius,
)

I2 = np.eye(2)
I3 = np.eye(3)


def test_that_input_error_is_a_value_error():
    assert issubclass(InputError, ValueError)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (([0.0, 0.0], I2, [1.0, 0.0, 0.0], I3), "mu1 and mu2 must have the same last dimension"),
        (([0.0, 0.0], I3, [1.0, 0.0], I2), r"cov1 must have shape \(\.\.\., 2, 2\)"),
        (([0.0, 0.0], I2, [1.0, 0.0], np.ones((2, 3))), r"cov2 must have shape"),
        ((0.0, I2, [1.0, 0.0], I2), "mu1 must have at least 1 dimension"),
        (([0.0, 0.0], [1.0, 1.0], [1.0, 0.0], I2), "cov1 must have at least 2 dimension"),
        ((np.zeros((3, 2)), I2, np.zeros((4, 2)), I2), "leading dimensions do not broadcast"),
    ],
)
def test_that_wrong_shapes_are_rejected_with_the_argument_named(args, match):
    with pytest.raises(InputError, match=match):
        minmax(*args)


@pytest.mark.parametrize("which", ["mu1", "cov1", "mu2", "cov2"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_that_nan_and_inf_are_rejected_naming_the_argument(which, bad):
    args = {"mu1": np.zeros(2), "cov1": I2.copy(), "mu2": np.ones(2), "cov2": I2.copy()}
    args[which] = args[which].astype(float)
    args[which].flat[0] = bad
    with pytest.raises(InputError, match=f"{which} contains NaN or infinite values"):
        minmax(**args)


@pytest.mark.parametrize("which", ["cov1", "cov2"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("entry", range(9))
def test_that_a_non_finite_3d_covariance_entry_anywhere_in_a_batch_is_rejected_by_name(which, bad, entry):
    """3-D batches are checked by one compiled pass (finite, symmetric, positive definite): a
    NaN or infinite entry in any place, diagonal or not, is refused with the numpy path's words."""
    covs = {"cov1": np.stack([I3, 2.0 * I3, I3]), "cov2": np.stack([I3, I3, 3.0 * I3])}
    covs[which][1].flat[entry] = bad
    with pytest.raises(InputError, match=f"{which} contains NaN or infinite values"):
        minmax(np.zeros((3, 3)), covs["cov1"], np.ones((3, 3)), covs["cov2"])


def test_that_non_symmetric_covariances_are_rejected():
    with pytest.raises(InputError, match="cov2 is not symmetric"):
        minmax([0, 0], I2, [1, 0], [[1.0, 0.3], [0.0, 1.0]])


@pytest.mark.parametrize("func", [minmax, bhattacharyya])
def test_that_not_positive_definite_names_the_covariance_and_the_index(func):
    covs = np.stack([I3, I3, np.diag([1.0, -1.0, 1.0]), I3])
    with pytest.raises(InputError, match=r"cov2 is not positive definite at index \(2,\)"):
        func(np.zeros((4, 3)), I3, np.ones((4, 3)), covs)
    grid = np.broadcast_to(I2, (2, 3, 2, 2)).copy()
    grid[1, 2] = np.zeros((2, 2))
    with pytest.raises(InputError, match=r"cov1 is not positive definite at index \(1, 2\)"):
        func(np.zeros(2), grid, np.ones(2), I2)


def test_that_semidefinite_and_indefinite_covariances_are_rejected():
    with pytest.raises(InputError, match="cov1 is not positive definite"):
        minmax([0, 0, 0], np.diag([1.0, 1.0, 0.0]), [1, 0, 0], I3)
    with pytest.raises(InputError, match="cov1 is not positive definite"):
        minmax([0, 0], [[1.0, 2.0], [2.0, 1.0]], [1, 0], I2)


@pytest.mark.parametrize("func", [touch_radius, overlap_from_confidence])
@pytest.mark.parametrize("confidence", [0.0, 1.0, -0.1, 1.5, np.nan, [0.5, 1.0]])
def test_that_confidence_outside_the_open_unit_interval_is_rejected(func, confidence):
    with pytest.raises(InputError, match=r"confidence must lie in the open interval \(0, 1\)"):
        func(confidence, 3)


@pytest.mark.parametrize("overlap", [0.0, 1.0, 2.0])
def test_that_overlap_outside_the_open_unit_interval_is_rejected(overlap):
    with pytest.raises(InputError, match=r"overlap must lie in the open interval \(0, 1\)"):
        confidence_from_overlap(overlap, 2)


@pytest.mark.parametrize("dim", [0, -1, 2.0, True, "3"])
def test_that_a_dimension_that_is_not_a_positive_integer_is_rejected(dim):
    with pytest.raises(InputError, match="dim must be an integer >= 1"):
        touch_radius(0.5, dim)


@pytest.mark.parametrize("lam", [0.0, 1.0, np.nan])
def test_that_paper_terms_rejects_lam_outside_the_open_unit_interval(lam):
    with pytest.raises(InputError, match="lam must lie in the open interval"):
        paper_terms([0, 0], I2, [1, 0], I2, lam)


def test_that_support_margin_validates_like_minmax():
    with pytest.raises(InputError, match="cov1 is not positive definite"):
        support_margin([0, 0], -I2, [1, 0], I2, [1, 0])
