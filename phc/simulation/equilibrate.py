"""Equilibration of a dense matrix: row and column scales that bring the largest entry of
every row and column near 1, so that a rank decision, a condition estimate or a solve
compares like with like whatever the units of the equations and the unknowns.

:func:`equilibrate` is the one alternating max-norm scaling phc uses on dense matrices
(the singularity monitor, the motion check, the spectrum of a linearization). Two other
scalings are different methods and live with their callers:
:func:`phc.simulation.midpoint.equilibration` (sparse, one pass, columns fixed by the
Newton test's nominal scales, mirrored bit for bit by the numba and C step kernels) and
:func:`phc.checks.rows._equilibrated` (Ruiz's square-root scaling iterated until both
rows and columns have largest entry ≈ 1).
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps


def equilibrate(M: np.ndarray, rounds: int = 1, power_of_two: bool = False, *, overwrite: bool = False,
                col_of: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(D_r M D_c, r, c)``: `rounds` rounds of scaling the rows of M to largest entry 1 and
    then the columns to largest entry 1; ``r`` and ``c`` are the products of the rounds'
    scales. A zero row or column keeps its scale 1.

    After the last round every nonzero column has largest absolute entry 1 and every
    nonzero row at most 1 (rounds bring the rows towards 1 as well).

    ``power_of_two=False``: one round is LAPACK's ``dgeequ`` (one call instead of a dozen
    NumPy operations — a look of the singularity monitor is mostly call overhead for small
    systems); with a zero row or column, the same scaling done in NumPy.
    ``power_of_two=True``: every scale is the power of two nearest to the reciprocal of the
    largest entry (the largest entries land in [1/√2, √2]), so scaling is exact and ``D_r M
    D_c`` equals the product of M with the returned scales to the last bit.

    A sparse M (SciPy) is scaled the same way on its nonzeros and returned as a CSC matrix
    (the singularity monitor's look at a large system). With `overwrite`, a CSC matrix of
    floats in canonical form (sorted indices, no duplicates) is scaled in place and returned
    (no copy of a mesh's matrix beside it); `col_of`, its entries' columns, saves making them."""
    if sps.issparse(M):
        return _equilibrate_sparse(M, rounds, power_of_two, overwrite, col_of)
    M = np.asarray(M, dtype=float)
    m, n = M.shape
    r_all, c_all = np.ones(m), np.ones(n)
    if M.size == 0:
        return M.copy(), r_all, c_all
    for _ in range(rounds):
        if not power_of_two:
            r, c, _, _, _, info = sla.lapack.dgeequ(M)
            if info == 0:
                M = (r[:, None] * M) * c
                r_all, c_all = r_all * r, c_all * c
                continue
        rm = np.abs(M).max(axis=1)
        rs = _scale_of(rm, power_of_two)
        M = M / rs[:, None]
        cm = np.abs(M).max(axis=0)
        cs = _scale_of(cm, power_of_two)
        M = M / cs[None, :]
        r_all, c_all = r_all / rs, c_all / cs
    return M, r_all, c_all


def _scale_of(largest: np.ndarray, power_of_two: bool) -> np.ndarray:
    """What a row or column is divided by: its largest entry (its nearest power of two), 1
    for a zero one."""
    nonzero = largest > 0
    if power_of_two:
        return np.where(nonzero, 2.0 ** np.round(np.log2(np.where(nonzero, largest, 1.0))), 1.0)
    return np.where(nonzero, largest, 1.0)


def _equilibrate_sparse(M, rounds: int, power_of_two: bool, overwrite: bool = False,
                        col_of: Optional[np.ndarray] = None) -> tuple[sps.csc_matrix, np.ndarray, np.ndarray]:
    """:func:`equilibrate` of a sparse matrix: the same rounds (rows to largest entry 1, then
    columns) on the stored entries, O(nonzeros) each."""
    if not (overwrite and M.format == "csc" and M.dtype == np.float64 and M.has_canonical_format):
        M = sps.csc_matrix(M, dtype=float, copy=True)
        M.sum_duplicates()
        col_of = None
    m, n = M.shape
    r_all, c_all = np.ones(m), np.ones(n)
    if M.nnz == 0:
        return M, r_all, c_all
    if col_of is None:
        col_of = np.repeat(np.arange(n, dtype=np.int32), np.diff(M.indptr))
    for _ in range(rounds):
        rm = np.zeros(m)
        np.maximum.at(rm, M.indices, np.abs(M.data))
        rs = _scale_of(rm, power_of_two)
        M.data /= rs[M.indices]
        cm = np.zeros(n)
        np.maximum.at(cm, col_of, np.abs(M.data))
        cs = _scale_of(cm, power_of_two)
        M.data /= cs[col_of]
        r_all, c_all = r_all / rs, c_all / cs
    return M, r_all, c_all
