"""The sparse LU every solver of phc factorizes its large matrices with: scipy's SuperLU
(:func:`scipy.sparse.linalg.splu`), above :data:`NARROW_PANEL_FROM` unknowns with a panel of
one column.

SuperLU's column-panel factorization keeps dense work arrays of ``n × panel_size`` entries
(values and indices) while it factorizes; with scipy's default panel of several columns they
are the largest part of the factorization's peak memory on a mesh, whose supernodes are
narrow anyway. The round-off floor's matrix (:func:`phc.simulation.scaling.roundoff_sizes`) of
``benchmarks/bench_beam_scale.py``'s cantilever with 2·10⁴ elements (1.6·10⁵ unknowns, 1.1·10⁶
nonzeros), factorized alone in a fresh process, peaked 86 MiB above the matrix with the default
panel and 40 MiB with a panel of one column (``VmHWM`` of ``/proc/self/status``), in less CPU time
(0.15 s against 0.21 s; the factors are the same size). With this and the description's rows
(:class:`phc.codegen.description.LabelledRows`) the 10⁵-element cantilever's run peaked 2 212 MiB
instead of 2 434 MiB (``PHC_MAX_MEMORY=4G python benchmarks/bench_beam_scale.py --measure eb
100000 --phases``). Below
:data:`NARROW_PANEL_FROM` the arrays are small and the default is kept, so the small models'
results stay bit for bit what they were.
"""

from __future__ import annotations

import numpy as np

NARROW_PANEL_FROM = 50_000
"""Unknowns from which the panel is one column (the work arrays are then tens of MiB)."""


def sparse_lu(J):
    """The SuperLU factorization of the square CSC matrix `J` (``scipy.sparse.linalg.splu``,
    its ``solve`` and ``RuntimeError`` on an exactly singular matrix), with a panel of one
    column from :data:`NARROW_PANEL_FROM` unknowns on."""
    import scipy.sparse.linalg as spla

    if J.shape[1] >= NARROW_PANEL_FROM:
        return spla.splu(J, panel_size=1)
    return spla.splu(J)


def csc_structure(rows, cols, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(indices, indptr, col_of)`` (int32) of an n × n sparse matrix whose entries are given
    in CSC order by their `rows` and `cols` (a generated module's ``JAC_ROWS``/``JAC_COLS``:
    sorted by column, then row, no duplicates): a matrix of data ``d`` in that order is
    ``csc_matrix((d, indices, indptr))``, without the copies and the sort of a conversion from
    coordinates, and ``col_of`` is each entry's column (for scaling the columns in place). The
    solvers' iteration matrices and the singularity monitor's looks share it."""
    rows, cols = np.asarray(rows), np.asarray(cols)
    indices = rows.astype(np.int32)
    indptr = np.searchsorted(cols, np.arange(n + 1)).astype(np.int32)
    return indices, indptr, cols.astype(np.int32)


ESTIMATE_SEED = 0
"""The seed of the random ±1 columns of :func:`inverse_norm_estimate` (the same estimate in every
process)."""
ESTIMATE_COLUMNS = 2
"""Columns of the block estimate (Higham and Tisseur's ``t``; scipy's ``onenormest`` default)."""
ESTIMATE_ITERATIONS = 5
"""Most iterations of the block estimate (their ``itmax``; scipy's default)."""


def inverse_norm_estimate(operator) -> float:
    """A lower bound of the 1-norm of `operator` (a ``LinearOperator``: an inverse applied
    through a factorization, with ``matmat`` and ``rmatmat``): Algorithm 2.4 of N. J. Higham and
    F. Tisseur, "A block algorithm for matrix 1-norm estimation, with an application to 1-norm
    pseudospectra", SIAM J. Matrix Anal. Appl. 21 (2000), with :data:`ESTIMATE_COLUMNS` columns,
    its random ±1 columns drawn from phc's own generator seeded with :data:`ESTIMATE_SEED`.

    Why not ``scipy.sparse.linalg.onenormest``, the same algorithm: it draws those columns from
    NumPy's global random state, which a fresh process seeds from the operating system. The
    estimate then differed from process to process in its last bits or more, and what phc decides
    on it (the singularity monitor's sparse looks above :data:`phc.simulation.monitor.DENSE_SIZE`
    unknowns, the least-norm solver's rank decision) differed with it: IDA on the N = 10 four-bar
    took other bridges, other passages and 10⁴ to 10⁵ more steps from run to run (issue 34).
    Seeding the global state instead would change the user's random numbers, or another
    thread's, while phc runs. The generator is NumPy's ``RandomState`` so the columns are the
    ones the global state would draw after ``numpy.random.seed(ESTIMATE_SEED)``: the estimate is
    scipy's under that seed to the bit (``tests/simulation/test_sparse_lu.py`` checks it)."""
    n = operator.shape[1]
    t = ESTIMATE_COLUMNS
    if n <= t:  # as small as the block: the norm itself
        return float(np.abs(np.asarray(operator.matmat(np.eye(n)))).sum(axis=0).max(initial=0.0))
    rng = np.random.RandomState(ESTIMATE_SEED)

    def random_signs():
        return rng.randint(0, 2, size=n) * 2 - 1

    def parallel(v, others):  # ±1 columns: parallel exactly when their product is n
        return any(np.dot(v, w) == n for w in others)

    def distinct(X, earlier=()):
        """Redraws a column of ±1 parallel to one before it or to one of `earlier`."""
        for i in range(X.shape[1]):
            while parallel(X[:, i], [X[:, j] for j in range(i)] + list(earlier)):
                X[:, i] = random_signs()

    X = np.ones((n, t))
    for i in range(1, t):
        X[:, i] = random_signs()
    distinct(X)
    X /= n
    S = np.zeros((n, t))
    seen = np.zeros(0, dtype=np.intp)  # the unit columns already tried
    ind = ind_best = None
    estimate_old = 0.0
    k = 1
    while True:
        Y = np.asarray(operator.matmat(X))
        sums = np.abs(Y).sum(axis=0)
        best = int(np.argmax(sums))
        estimate = sums[best]
        if k >= 2 and (estimate > estimate_old or k == 2):
            ind_best = ind[best]
        if k >= 2 and estimate <= estimate_old:
            return float(estimate_old)
        estimate_old = estimate
        if k > ESTIMATE_ITERATIONS:
            return float(estimate)
        S_old = S
        S = np.where(Y >= 0, 1.0, -1.0)  # sign, with sign(0) = 1
        if all(parallel(v, S_old.T) for v in S.T):
            return float(estimate)
        if t > 1:
            distinct(S, S_old.T)
        h = np.abs(np.asarray(operator.rmatmat(S))).max(axis=1)
        if k >= 2 and h.max() == h[ind_best]:
            return float(estimate)
        ind = np.argsort(h)[::-1][: t + len(seen)].copy()
        if t > 1:
            if np.isin(ind[:t], seen).all():
                return float(estimate)
            tried = np.isin(ind, seen)
            ind = np.concatenate((ind[~tried], ind[tried]))
        X = np.zeros((n, t))
        X[ind[:t], np.arange(t)] = 1.0
        seen = np.concatenate((seen, ind[:t][~np.isin(ind[:t], seen)]))
        k += 1
