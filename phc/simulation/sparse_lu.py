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

import threading

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


ESTIMATE_SEED = 0
"""The seed of the random columns of :func:`inverse_norm_estimate` (the same estimate in every process)."""
_RANDOM_LOCK = threading.Lock()


def inverse_norm_estimate(operator) -> float:
    """Higham's block 1-norm estimate of `operator` (a ``LinearOperator``: an inverse applied
    through a factorization), ``scipy.sparse.linalg.onenormest``, with its random columns drawn
    from :data:`ESTIMATE_SEED`.

    Why seeded: scipy draws the estimator's starting ±1 columns (and the resampled ones) from
    NumPy's global random state, which a fresh process seeds from the operating system. The
    estimate, a lower bound of the norm, then differed from process to process in its last bits
    or more, and what phc decides on it (the singularity monitor's sparse looks above
    :data:`phc.simulation.monitor.DENSE_SIZE` unknowns, the least-norm solver's rank decision)
    differed with it: IDA on the N = 10 four-bar took other bridges, other passages and 10⁴ to
    10⁵ more steps from run to run (issue 34). The global state is put back afterwards (phc
    leaves the user's random numbers as it found them; another thread drawing from it meanwhile
    is not excluded)."""
    import scipy.sparse.linalg as spla

    with _RANDOM_LOCK:
        saved = np.random.get_state()
        np.random.seed(ESTIMATE_SEED)
        try:
            return float(spla.onenormest(operator))
        finally:
            np.random.set_state(saved)
