"""Minimum-norm least-squares solutions of sparse linear systems (consistent initialization).

``min_norm_solve(A, b)`` returns the v of least norm among those minimizing ‖A v − b‖₂ —
what LAPACK's QR with column pivoting (``gelsy``) gives when no direction of A is below
its rank threshold. Three ways, by size and rank:

* Small A (at most :data:`DENSE_SOLVE_LIMIT` entries): dense ``gelsy`` with the rank
  threshold `cond` (relative to the largest diagonal entry of R). For a few hundred
  unknowns it is as fast as anything sparse, and it decides a numerical rank.
* Larger A whose regular part is all of it: one sparse LU (SuperLU, ``splu``) of A itself
  when it is square, else of the augmented system of the minimum-norm problem,
  ``[γI Aᵀ; A 0] [v; λ] = [0; b]`` (A of full row rank; v = −Aᵀλ/γ lies in the row space
  of A, so it is the least-norm solution). γ = max|A| balances the blocks and does not
  change v. The rank decision is made before the solution is trusted: the matrix
  factored must be structurally regular (a maximum matching of A's rows to its columns
  covers the rows: phc's matching, as scipy's ``structural_rank`` takes exponential
  time on a beam's pattern) and numerically regular — SuperLU succeeds and the 1-norm condition estimate
  (``onenormest`` of the inverse through the factors, times ‖K‖₁) stays below
  ``1/cond``. Then the regular system has one solution and gelsy, which truncates no
  direction of such a matrix, computes the same one: the two agree to the round-off of
  the factorizations (one step of iterative refinement is taken). Rows left unmatched
  by a maximum matching of rows to unknowns are structurally dependent on the others:
  they are dropped, the rest solved as above, and the result is taken only if the
  dropped rows hold there to round-off (:data:`CONSISTENT`) — then it solves the whole
  consistent system with least norm, which is what gelsy gives. A sparse QR would do
  the same for rank-deficient A, but scipy has none.
* Larger A that is numerically rank-deficient (a redundant constraint, a zero row, a
  dependency the pattern does not show — the 100-element beam's Newton matrix has one):
  LSMR from v = 0 (or dense ``gelsy`` up to `dense_limit` entries for a caller that
  needs the exact solution, see :func:`min_norm_solve`), whose
  iterates stay in the row space of A, so it converges to the least-norm least-squares
  solution; its stopping tolerances are the relative round-off of the data
  (atol = btol = 1e-15). If it stops on its condition estimate or iteration limit
  instead, dense ``gelsy`` decides while A has at most `dense_limit` entries (the
  flexible slider–crank's Newton matrix, forced onto this path, needs it).

The same routine serves the Newton steps and the affine pre-check of
:mod:`phc.simulation.initial`, so dense and sparse paths differ only where the rank
decision does.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from phc.analysis.matching import bipartite_matching

DENSE_SOLVE_LIMIT = 40_000
"""Systems with at most this many matrix entries (200 × 200) are solved dense (gelsy)."""

COND = 1e-13
"""Rank threshold: directions weaker than this, relative to the strongest, are not solved for."""


CONSISTENT = 1e-12
"""Dropped rows (structurally dependent) must hold to this fraction of their terms (|A| |v| + |b|):
the round-off of a sum of products, with room for the condition of the regular part."""


def dense_min_norm(A, b, cond: float = COND) -> np.ndarray:
    """gelsy's least-norm least-squares solution (dense; `A` may be sparse)."""
    A = A.toarray() if sps.issparse(A) else np.asarray(A)
    return sla.lstsq(A, b, lapack_driver="gelsy", cond=cond)[0]


def _regular_lu(A, b, cond):
    """The solution through a sparse LU, or None when the matrix to factor is not regular."""
    A = sps.csr_matrix(A)
    unmatched = bipartite_matching(A) < 0
    if unmatched.any():
        # Structurally dependent rows: the equations matched to unknowns determine the
        # solution set if the others hold there too (a consistent system; else None).
        keep = np.flatnonzero(~unmatched)
        v = _regular_lu(A[keep], b[keep], cond)
        if v is None:
            return None
        left = np.abs(A @ v - b)
        bound = CONSISTENT * (abs(A) @ np.abs(v) + np.abs(b))
        return v if np.all(left <= bound) else None
    m, n = A.shape
    A = sps.csc_matrix(A)
    gamma = float(abs(A).max()) if A.nnz else 0.0
    if gamma == 0.0:
        return None
    if m == n:
        K, rhs = A, b
    else:  # m < n: every row is matched, so m > n cannot reach here
        K = sps.bmat([[gamma * sps.identity(n), A.T], [A, None]], format="csc")
        rhs = np.concatenate([np.zeros(n), b])
    # (structurally regular: A's rows are matched to distinct columns, and so is K)
    try:
        lu = spla.splu(K)
    except RuntimeError:  # "Factor is exactly singular"
        return None
    k = K.shape[0]
    inverse = spla.LinearOperator((k, k), matvec=lu.solve, rmatvec=lambda x: lu.solve(x, trans="T"), dtype=float)
    with np.errstate(all="ignore"):
        norm_inv = spla.onenormest(inverse)
        if not np.isfinite(norm_inv) or norm_inv * spla.norm(K, 1) * cond >= 1.0:
            return None
        x = lu.solve(rhs)
        x = x + lu.solve(rhs - K @ x)  # one step of iterative refinement
    if not np.all(np.isfinite(x)):
        return None
    return x[:n]


def min_norm_solve(A, b, *, cond: float = COND, dense_limit: int = 4_000_000, iterative: bool = True):
    """The least-norm least-squares solution of ``A v = b`` (`A` sparse or dense); see the
    module docstring for the method chosen. A large rank-deficient system is solved by
    LSMR when `iterative` (a Newton step: what it leaves is the next step's work), else
    — a caller that needs the exact solution to decide something — dense up to
    `dense_limit` entries, beyond that None."""
    m, n = A.shape
    b = np.asarray(b, dtype=float)
    if m * n <= DENSE_SOLVE_LIMIT or not m or not n:
        return dense_min_norm(A, b, cond) if m and n else np.zeros(n)
    v = _regular_lu(A, b, cond)
    if v is not None:
        return v
    if iterative:
        v, istop = spla.lsmr(sps.csr_matrix(A), b, atol=1e-15, btol=1e-15, maxiter=20 * max(m, n))[:2]
        if istop in (0, 1, 2) or m * n > dense_limit:
            return v  # converged (or nothing better affordable)
        # stopped on its condition estimate or iteration limit: the dense solve decides
    if m * n <= dense_limit:
        return dense_min_norm(A, b, cond)
    return None
