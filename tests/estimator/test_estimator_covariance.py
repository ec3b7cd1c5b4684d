"""Parsing PX4 ODOMETRY covariance arrays and checking covariances."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from estimator.covariance import (
    covariance_problem,
    position_covariance,
    position_variances,
    upper_triangle_to_matrix,
    velocity_variances,
)
from estimator.errors import EstimatorInputError


def test_that_the_upper_triangle_is_read_row_major_into_a_symmetric_matrix():
    M = np.arange(36, dtype=float).reshape(6, 6)
    M = M + M.T
    arr21 = [M[i, j] for i in range(6) for j in range(i, 6)]  # row-major upper triangle
    np.testing.assert_array_equal(upper_triangle_to_matrix(arr21), M)


def test_that_indices_0_6_11_are_the_xyz_variances():
    arr = np.zeros(21)
    arr[[0, 6, 11]] = [0.1, 0.2, 0.3]
    arr[[15, 18, 20]] = 9.0  # roll, pitch, yaw
    np.testing.assert_array_equal(position_variances(arr), [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(velocity_variances(arr), [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(np.diag(upper_triangle_to_matrix(arr)), [0.1, 0.2, 0.3, 9, 9, 9])
    np.testing.assert_array_equal(position_covariance(arr), np.diag([0.1, 0.2, 0.3]))


def test_that_nan_in_element_0_means_unknown():
    arr = np.full(21, np.nan)
    assert position_variances(arr) is None
    assert position_covariance(arr) is None


def test_that_a_triangle_of_the_wrong_length_is_an_input_error():
    with pytest.raises(EstimatorInputError, match="21 elements, got 20"):
        upper_triangle_to_matrix(np.zeros(20))


@pytest.mark.parametrize(
    ("cov", "message"),
    [
        (np.diag([1.0, np.inf, 1.0]), "non-finite"),
        (np.diag([1.0, np.nan, 1.0]), "non-finite"),
        (np.array([[1.0, 0.0, np.inf], [0.0, 1.0, 0.0], [-np.inf, 0.0, 1.0]]), "non-finite"),   # inf - inf in a sum
        (np.array([[1.0, 0.5, 0], [0.4, 1.0, 0], [0, 0, 1.0]]), "not symmetric"),
        (np.diag([1.0, -1.0, 1.0]), "not positive definite"),
        (np.zeros((3, 3)), "not positive definite"),
        (np.ones((3, 2)), "square"),
    ],
)
def test_that_covariance_problem_names_what_is_wrong(cov, message):
    assert message in covariance_problem(cov)


def test_that_a_valid_covariance_has_no_problem():
    assert covariance_problem(np.array([[2.0, 0.3, 0], [0.3, 1.0, 0.1], [0, 0.1, 0.5]])) is None


def test_that_finite_entries_whose_sum_overflows_are_finite():
    # the 3x3 check takes the entries' sum as its finiteness test and looks one by one when it overflows
    assert covariance_problem(np.diag([1e308, 1e308, 1e308])) is None
    assert "not positive definite" in covariance_problem(np.diag([1e308, 1e308, -1e308]))


@settings(max_examples=300, deadline=None)
@given(
    arrays(np.float64, (3, 3), elements=st.floats(-10.0, 10.0)),
    st.floats(-5.0, 5.0),
    st.booleans(),
)
def test_that_the_3x3_check_agrees_with_numpys_cholesky(a, shift, symmetric):
    """The closed-form 3x3 path decides as numpy's Cholesky does, away from singular matrices."""
    cov = a @ a.T + shift * np.eye(3) if symmetric else a
    sym = np.max(np.abs(cov - cov.T)) <= 1e-9 * max(np.max(np.abs(cov)), np.finfo(float).tiny)
    if sym:
        eig = np.linalg.eigvalsh(0.5 * (cov + cov.T))
        assume(abs(eig.min()) > 1e-9 * max(1.0, np.abs(eig).max()))  # not on the boundary
        try:
            np.linalg.cholesky(cov)
            expected = None
        except np.linalg.LinAlgError:
            expected = "covariance is not positive definite"
    else:
        expected = "covariance is not symmetric"
    assert covariance_problem(cov) == expected
