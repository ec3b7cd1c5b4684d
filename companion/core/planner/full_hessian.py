"""The QP's full symmetric ``P`` on a fixed pattern, to evaluate ``x'Px`` for every backend.

The solvers take the upper triangle of ``P`` (CSC, :class:`companion.core.planner.qp_layout.QpLayout`);
the planner evaluates the objective ``0.5 x'Px + q'x`` itself, with the whole matrix. Its
pattern is fixed per layout, so it is built once from markers ``1..nnz`` and its data
refilled by index on every update (no sparse arithmetic per QP).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from companion.core import jit
from companion.core.planner.qp_layout import QpLayout


class FullHessian:
    """``P`` (full, CSR) of a layout, kept in step with its upper-triangle data (CSC order).

    Parameters
    ----------
    layout : QpLayout
        The fixed pattern.
    p_data : array
        ``P``'s upper-triangle data in the pattern's CSC order.
    """

    def __init__(self, layout: QpLayout, p_data: np.ndarray) -> None:
        markers = np.arange(1.0, len(p_data) + 1.0)
        self.matrix = _symmetric(layout.p_matrix(markers))
        self._source = self.matrix.data.astype(np.intp) - 1
        self.matrix.data[:] = p_data[self._source]
        self._indptr, self._indices = self.matrix.indptr.astype(np.intp), self.matrix.indices.astype(np.intp)

    def update(self, p_data: np.ndarray) -> None:
        """New upper-triangle data (CSC order of the same pattern)."""
        np.take(p_data, self._source, out=self.matrix.data)

    def times(self, x: np.ndarray) -> np.ndarray:
        """``P x``, summed as scipy's CSR product sums it (the same bits)."""
        if not jit.available():
            return self.matrix @ x
        out = np.empty(self.matrix.shape[0])
        _csr_product()(self._indptr, self._indices, self.matrix.data, np.ascontiguousarray(x, dtype=float), out)
        return out


def _symmetric(p_upper: sp.csc_matrix) -> sp.csr_matrix:
    """Full symmetric ``P`` from its upper triangle."""
    return sp.csr_matrix(p_upper + sp.triu(p_upper, k=1).T)


def _csr_product_signature(t):
    """CSR index arrays (intp), data and a vector in, the product out."""
    index = t.Array(t.intp, 1, "C", readonly=True)
    return t.void(index, index, jit.readonly(t, 1), jit.readonly(t, 1), t.float64[::1])


@jit.lazy(_csr_product_signature)
def _csr_product(indptr, indices, data, x, out):
    """``out = A x`` for a CSR ``A``: each row summed from +0 over its entries in stored order,
    as scipy's ``csr_matvec`` does (so the same bits), without scipy's Python dispatch."""
    for i in range(out.shape[0]):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * x[indices[k]]
        out[i] = acc
