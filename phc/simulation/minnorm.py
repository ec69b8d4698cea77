"""Minimum-norm least-squares solutions of linear systems (consistent initialization, the
rates and scales of index-1 variables): phc's one least-norm solver.

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
  time on a beam's pattern) and numerically regular — SuperLU succeeds and the 1-norm
  condition κ₁ of the matrix K factored stays below ``1/cond``. A certain lower bound
  comes from the factors alone: with ``Pr K Pc = L U``, ``U⁻¹ = Pcᵀ K⁻¹ Prᵀ L``, so
  ``1/|u_ii| ≤ ‖U⁻¹‖₁ ≤ ‖K⁻¹‖₁ ‖L‖₁`` and ``κ₁ ≥ ‖K‖₁ / (‖L‖₁ min|u_ii|)``; a system it
  already rejects costs no solve. Otherwise Higham and Tisseur's block estimate
  (:func:`phc.simulation.sparse_lu.inverse_norm_estimate`) of the inverse through the
  factors estimates κ₁. Then the regular system has one solution and gelsy, which
  truncates no direction of such a matrix, computes the same one: the two agree to the
  round-off of the factorizations (one step of iterative refinement is taken). Rows left
  unmatched by a maximum matching of rows to unknowns are structurally dependent on the
  others: they are dropped, the rest solved as above, and the result is taken only if the
  dropped rows hold there to round-off (:data:`CONSISTENT`) — then it solves the whole
  consistent system with least norm, which is what gelsy gives. A sparse QR would do
  the same for rank-deficient A, but scipy has none.
* Larger A that is numerically rank-deficient (a redundant constraint, a zero row, a
  dependency the pattern does not show — a 100-element beam's Newton matrix has one):
  LSMR from v = 0 (or dense ``gelsy`` up to `dense_limit` entries for a caller that
  needs the exact solution, see :meth:`LeastNorm.solve`), whose iterates stay in the row
  space of A, so it converges to the least-norm least-squares solution; its stopping
  tolerances are the relative round-off of the data (atol = btol = 1e-15). If it stops on
  its condition estimate or iteration limit instead, dense ``gelsy`` decides while A has
  at most `dense_limit` entries (the flexible slider–crank's Newton matrix, forced onto
  this path, needs it).

A :class:`LeastNorm` serves a sequence of systems of one structure — the Newton steps of
one problem — and does not try the sparse LU again once it found one of them singular:
the later matrices differ from it by the move of the iterate, not in the dependency
that made it singular, and each rejected attempt costs a matching, a factorization and
a condition estimate (a 300-element beam's Newton matrices are all singular: trying the
LU at every step cost four times the rest of its initialization). The answer does not
depend on it: LSMR and the LU solve the same least-norm problem. A matrix equal to the
last one it factored (the polishing steps of a linear problem) reuses that factorization
and its rank decision, and a zero right-hand side (a converged step) is answered by v = 0
without any: both give what the factorization would, bit for bit (a 3000-element string's
start, whose three polishing steps have g = 0, took 0.31 s with an LU and a condition
estimate at each step, 0.12 s before the LU was introduced).

Dense solves run with one BLAS thread (:func:`one_blas_thread`). A chord iteration, which
solves with one matrix many times, keeps that matrix's pseudo-inverse instead
(:mod:`phc.simulation.chord`).
"""

from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from phc.analysis.matching import bipartite_matching
from phc.simulation.sparse_lu import inverse_norm_estimate

DENSE_SOLVE_LIMIT = 40_000
"""Systems with at most this many matrix entries (200 × 200) are solved dense (gelsy)."""

COND = 1e-13
"""Rank threshold: directions weaker than this, relative to the strongest, are not solved for."""

CONSISTENT = 1e-12
"""Dropped rows (structurally dependent) must hold to this fraction of their terms (|A| |v| + |b|):
the round-off of a sum of products, with room for the condition of the regular part."""

ONE_THREAD_ENTRIES = 10_000
"""A dense solve of a matrix with more entries than this (100 × 100, where OpenBLAS may start
threads) runs under :func:`one_blas_thread`."""

_blas = {"controller": None, "modules": -1, "depth": 0}
_blas_lock = threading.Lock()


def _thread_controller():
    """threadpoolctl's controller of the loaded BLAS libraries. Importing threadpoolctl sets
    ``KMP_DUPLICATE_LIB_OK`` in ``os.environ`` (threadpoolctl 3.x, at module level); phc
    leaves the user's environment as it found it, so the variable is put back as it was
    (threadpoolctl only inspects libraries already loaded: it loads no OpenMP runtime that
    could read it)."""
    name = "KMP_DUPLICATE_LIB_OK"
    before = os.environ.get(name)
    try:
        from threadpoolctl import ThreadpoolController

        return ThreadpoolController()
    finally:
        if before is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = before


@contextmanager
def one_blas_thread():
    """While the block runs, BLAS (OpenBLAS, MKL, BLIS) uses one thread; the previous
    limits are restored after it. phc's dense systems are small (a few thousand unknowns
    at most): on a 2-core machine with other work running, OpenBLAS's threads waiting for
    each other made gelsy of 200 × 200 to 1211 × 1209 matrices 3 to 20 times slower in CPU
    and wall time than one thread (a 100-element beam's dense initialization took 281 s
    instead of 1.7 s); on an idle machine more threads can only shorten these solves, a
    small part of a run. Scoped, not set at import: phc changes
    nothing in the user's process outside its own calls (the limit is process-wide while
    the block runs). Needs ``threadpoolctl``; without it the block runs as it is. Nested
    blocks cost nothing."""
    with _blas_lock:
        outer = _blas["depth"] > 0
        # the controller lists the libraries loaded when it is made; an import since then may
        # have loaded another BLAS (scikit-sundae brings its own OpenBLAS with IDA), so it is
        # made again when the set of imported modules has grown (about 1 ms; cheaper than that
        # to notice)
        if _blas["controller"] is None or (_blas["controller"] and not outer
                                           and len(sys.modules) != _blas["modules"]):
            try:
                _blas["controller"] = _thread_controller()
                _blas["modules"] = len(sys.modules)
            except Exception:  # noqa: BLE001 — not installed or cannot inspect: no limit
                _blas["controller"] = False
        controller = _blas["controller"]
        _blas["depth"] += 1
    try:
        if outer or not controller:
            yield
        else:
            with controller.limit(limits=1, user_api="blas"):
                yield
    finally:
        with _blas_lock:
            _blas["depth"] -= 1


def dense_min_norm(A, b, cond: float = COND) -> np.ndarray:
    """gelsy's least-norm least-squares solution (dense; `A` may be sparse, `b` a vector or
    a matrix of right-hand sides)."""
    A = A.toarray() if sps.issparse(A) else np.asarray(A, dtype=float)
    if A.size <= ONE_THREAD_ENTRIES:
        return sla.lstsq(A, b, lapack_driver="gelsy", cond=cond)[0]
    with one_blas_thread():
        return sla.lstsq(A, b, lapack_driver="gelsy", cond=cond)[0]


def lsmr_min_norm(A, b, maxiter: int | None = None, btol: float = 1e-15):
    """LSMR from v = 0 at the round-off of the data: ``(v, converged)``; `maxiter` defaults
    to 20 × max(m, n). A caller content with any residual below ``btol ‖b‖`` may say so."""
    m, n = A.shape
    v, istop = spla.lsmr(sps.csr_matrix(A), b, atol=1e-15, btol=btol,
                         maxiter=20 * max(m, n) if maxiter is None else maxiter)[:2]
    return v, istop in (0, 1, 2)


def _regular_factor(A, cond):
    """A solver ``b ↦ v`` through a sparse LU of the regular part of `A` (None for a `b`
    that the dropped rows do not fit), or None when the matrix to factor is not regular."""
    A = sps.csr_matrix(A)
    keep = np.flatnonzero(bipartite_matching(A) >= 0)
    if len(keep) == A.shape[0]:
        return _factor(A, cond)
    # Structurally dependent rows: the equations matched to unknowns determine the solution
    # set if the others hold there too (a consistent system; else None). The kept rows are
    # all matched, to distinct columns: no second matching.
    solve = _factor(A[keep], cond)
    if solve is None:
        return None
    magnitude = abs(A)

    def consistent(b):
        v = solve(b[keep])
        if v is None:
            return None
        left = np.abs(A @ v - b)
        bound = CONSISTENT * (magnitude @ np.abs(v) + np.abs(b))
        return v if np.all(left <= bound) else None

    return consistent


def _factor(A, cond):
    """A solver ``b ↦ v`` of the least-norm solutions of a system whose rows are matched to
    distinct columns, through a sparse LU (None for a `b` whose solution is not finite), or
    None when the matrix factored is numerically singular."""
    m, n = A.shape
    A = sps.csc_matrix(A)
    gamma = float(abs(A).max()) if A.nnz else 0.0
    if gamma == 0.0:
        return None
    if m == n:
        K = A
    else:  # m < n (matched rows), and so K is structurally regular too
        K = sps.bmat([[gamma * sps.identity(n), A.T], [A, None]], format="csc")
    try:
        lu = spla.splu(K)
    except RuntimeError:  # "Factor is exactly singular"
        return None
    norm_k = spla.norm(K, 1)
    pivot = float(np.abs(lu.U.diagonal()).min())
    norm_l = float(abs(lu.L).sum(axis=0).max())
    if not np.isfinite(pivot) or norm_k * cond >= norm_l * pivot:
        return None  # κ₁ ≥ ‖K‖₁ / (‖L‖₁ min|u_ii|) ≥ 1/cond: singular for sure
    k = K.shape[0]
    inverse = spla.LinearOperator((k, k), matvec=lu.solve, rmatvec=lambda x: lu.solve(x, trans="T"), dtype=float)
    with np.errstate(all="ignore"):
        norm_inv = inverse_norm_estimate(inverse)  # the same rank decision in every process
    if not np.isfinite(norm_inv) or norm_inv * norm_k * cond >= 1.0:
        return None

    def solve(b):
        rhs = b if m == n else np.concatenate([np.zeros((n,) + np.shape(b)[1:]), b])
        with np.errstate(all="ignore"):
            x = lu.solve(rhs)
            x = x + lu.solve(rhs - K @ x)  # one step of iterative refinement
        if not np.all(np.isfinite(x)):
            return None
        return x[:n]

    return solve


class LeastNorm:
    """Least-norm solves of a sequence of systems of one structure (the Newton steps of one
    problem): after the sparse LU has found one of them singular, the later ones go to
    LSMR (or the dense solve) directly; a matrix equal to the last one factored reuses its
    factorization; a zero right-hand side costs nothing (module docstring)."""

    def __init__(self):
        self.singular = False
        """The sparse LU found a system of the sequence singular (or its dropped rows
        inconsistent): not tried again."""
        self._factored = None
        """The last matrix factored (shape, rank threshold, CSR arrays) and its solver."""

    def _regular(self, A, cond):
        """The solver of :func:`_regular_factor` for `A`, that of the last call when `A` is
        the same matrix (the same CSR arrays: the polishing steps of a linear problem)."""
        A = sps.csr_matrix(A)
        last = self._factored
        if (last is not None and last[0] == (A.shape, cond) and np.array_equal(last[1], A.indptr)
                and np.array_equal(last[2], A.indices) and np.array_equal(last[3], A.data)):
            return last[4]
        solve = _regular_factor(A, cond)
        self._factored = ((A.shape, cond), A.indptr.copy(), A.indices.copy(), A.data.copy(), solve)
        return solve

    def solve(self, A, b, *, cond: float = COND, dense_limit: int = 4_000_000, iterative: bool = True):
        """The least-norm least-squares solution of ``A v = b`` (`A` sparse or dense, `b` a
        vector); see the module docstring for the method chosen. A large rank-deficient
        system is solved by LSMR when `iterative` (a Newton step: what it leaves is the next
        step's work), else — a caller that needs the exact solution to decide something —
        dense up to `dense_limit` entries, beyond that None."""
        m, n = A.shape
        b = np.asarray(b, dtype=float)
        if not m or not n:
            return np.zeros(n)
        if not b.any():  # v = 0 is the least-norm solution, by every method (a converged Newton step)
            return np.zeros((n,) + b.shape[1:])
        if m * n <= DENSE_SOLVE_LIMIT:
            return dense_min_norm(A, b, cond)
        if not self.singular:
            solve = self._regular(A, cond)
            v = None if solve is None else solve(b)
            if v is not None:
                return v
            self.singular = True
            self._factored = None
        if iterative:
            v, converged = lsmr_min_norm(A, b)
            if converged or m * n > dense_limit:
                return v  # converged (or nothing better affordable)
            # stopped on its condition estimate or iteration limit: the dense solve decides
        if m * n <= dense_limit:
            return dense_min_norm(A, b, cond)
        return None


def min_norm_solve(A, b, *, cond: float = COND, dense_limit: int = 4_000_000, iterative: bool = True):
    """One least-norm least-squares solution of ``A v = b`` (:meth:`LeastNorm.solve`)."""
    return LeastNorm().solve(A, b, cond=cond, dense_limit=dense_limit, iterative=iterative)
