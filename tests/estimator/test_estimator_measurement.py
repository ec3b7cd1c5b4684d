"""Assembling a report into ``(z, H, R)``: the noise a 3x3 covariance gives."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from estimator.measurement import assemble


def _report_noise(cov: np.ndarray) -> np.ndarray:
    return assemble(np.zeros(3), None, cov, None, position_std_m=0.1, velocity_std_mps=0.1).R


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, (3, 3), elements=st.floats(-10.0, 10.0)), st.floats(1e-3, 10.0),
       st.sampled_from([0.0, 1e-12, -3e-13]), st.sampled_from([1.0, 1e-200, 1e300]))
def test_that_a_full_covariance_becomes_its_symmetric_part_bit_for_bit(a, shift, skew, scale):
    """Exactly symmetric (the copy) or within the tolerance (the elementwise mean), R is ``(C + C') / 2``."""
    cov = (a @ a.T + shift * np.eye(3)) * scale
    cov[0, 1] += skew * abs(cov[0, 1])        # asymmetry within the check's 1e-9 relative tolerance
    R = _report_noise(cov)
    np.testing.assert_array_equal(R, 0.5 * (cov + cov.T))
    assert not np.shares_memory(R, cov)        # the report's array is not kept


def test_that_a_transposed_view_is_read_as_the_matrix_it_shows():
    base = np.array([[2.0, 0.5, 0.1], [0.5, 1.0, 0.2], [0.1, 0.2, 3.0]])
    view = np.asfortranarray(base).T            # not C-contiguous
    R = _report_noise(view)
    np.testing.assert_array_equal(R, base)
    assert R.flags.c_contiguous
