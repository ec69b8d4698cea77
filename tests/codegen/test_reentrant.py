"""The generated module is re-entrant: it keeps no scratch state between calls, so threads
(a Dask worker runs sweep points on threads) may call one module at once with different
states and parameters. Before, a module-level [y; ẏ] buffer and a parameter cache that was
cleared and refilled gave 24 and 33 wrong residual vectors out of 20 000 calls from two
threads. Each call here is compared bit for bit with the same call made serially, on each
back end (the C back end's library is called with the GIL released: the threads run at once)."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import phc

MODELS = Path(__file__).resolve().parents[2] / "models"
THREADS, CALLS = 4, 2000


def _inputs(mod, k: int):
    rng = np.random.default_rng(k)
    n = mod.N
    y, yp = rng.standard_normal(n), rng.standard_normal(n)
    p = np.asarray(mod.PARAMETER_DEFAULTS, dtype=float) * (1.0 + 0.1 * (k % 3))  # three parameter vectors
    return float(k) * 1e-3, y, yp, p, 1.0 + k


def _call(mod, k: int):
    t, y, yp, p, cj = _inputs(mod, k)
    res = np.empty(len(mod.EQUATIONS))
    mod.residual(t, y, yp, p, res)
    jac = np.empty(len(mod.JAC_ROWS))
    mod.jacobian(t, y, yp, p, cj, jac)
    return np.concatenate([res, jac, [mod.hamiltonian(t, y, p)], np.asarray(mod.powers(t, y, yp, p), dtype=float)])


NUMBA = pytest.param("numba", marks=pytest.mark.skipif(not __import__("importlib").util.find_spec("numba"),
                                                      reason="numba not installed"))


def _c_compiler() -> str:
    from phc.codegen.c_backend import available

    ok, why = available()
    return "" if ok else why


C = pytest.param("c", marks=pytest.mark.skipif(bool(_c_compiler()), reason=f"C backend not tested: {_c_compiler()}"))


def _chain(tmp_path) -> Path:
    """A linear_phs chain: its rows are sparse linear blocks applied by mat-vecs (the
    parameter `k` scales them, so three parameter vectors give three sets of matrices)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "library"))
    try:
        from test_linear_phs import chain_model
    finally:
        sys.path.pop(0)
    path, _ = chain_model(tmp_path, 40)
    return path


@pytest.mark.parametrize("backend", ["numpy", NUMBA, C])
@pytest.mark.parametrize("model", ["linear_chain", "rigid_slider_crank"])  # sparse linear blocks; nonlinear rows
def test_four_threads_give_the_serial_results_bit_for_bit(model, backend, tmp_path):
    path = _chain(tmp_path) if model == "linear_chain" else MODELS / f"{model}.yaml"
    compiled = phc.compile_model(path, certify=False, backend=backend)
    if model == "linear_chain":
        assert "= _linear(p)" in compiled.source  # the path under test: matrices memoized per p
    mod = compiled.module
    serial = [_call(mod, k) for k in range(CALLS)]
    results: list = [None] * CALLS
    barrier = threading.Barrier(THREADS)

    def work(first: int):
        barrier.wait()  # all threads call at once
        for k in range(first, CALLS, THREADS):
            results[k] = _call(mod, k)

    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads as often as the interpreter allows
    try:
        threads = [threading.Thread(target=work, args=(i,)) for i in range(THREADS)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    finally:
        sys.setswitchinterval(switch)
    wrong = [k for k in range(CALLS) if not np.array_equal(results[k], serial[k], equal_nan=True)]
    assert not wrong, f"{len(wrong)} of {CALLS} calls differ from the serial ones (first: call {wrong[0]})"
