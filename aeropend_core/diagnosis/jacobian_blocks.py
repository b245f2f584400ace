"""The sparse Jacobian of a long record's output-error fit: the parameters' dense columns beside the block-diagonal
columns of the segments' initial states (a segment's initial state moves only its own residuals).

Built directly in compressed-row form, each row's entries in column order: the arrays the coordinate (COO) form
gave once converted, without the conversion (a sort of every entry) at each Jacobian of a fit (s26: 7.7 of 388 s
of a 600 s record's diagnosis under cProfile). The trust region's LSMR steps multiply with the same arrays, so a
fit's numbers are those of the COO form, bit for bit (tests/test_sensitivity.py compares both).
"""
from __future__ import annotations

import numpy as np
from scipy import sparse


def block_jacobian(dense: np.ndarray, initial: list[np.ndarray], segment: np.ndarray, n_columns: int):
    """Sparse (residuals, n_columns) Jacobian [rad per scaled unit] in compressed-row form.

    Parameters
    ----------
    dense : ndarray (m, p) [rad per scaled unit]
        d residual / d free parameter (scaled): the first p columns.
    initial : list of two ndarrays (m,) [rad per scaled unit]
        d residual / d (initial angle, initial rate) of the residual's own segment.
    segment : ndarray of int (m,) [-]
        Segment of each residual; its initial angle is column p + 2 segment, its rate the next.
    n_columns : int [-]
        Columns in all (p + 2 segments).
    """
    m, p = dense.shape
    width = p + 2
    columns = np.column_stack([np.broadcast_to(np.arange(p), (m, p)), p + 2 * segment, p + 2 * segment + 1])
    values = np.column_stack([dense, initial[0], initial[1]])
    return sparse.csr_array((values.ravel(), columns.ravel(), np.arange(0, m * width + 1, width)),
                            shape=(m, n_columns))


__all__ = ['block_jacobian']
