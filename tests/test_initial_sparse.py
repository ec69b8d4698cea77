"""Consistent initialization through sparse least-norm solves (phc/simulation/minnorm.py):
the dense and sparse paths give the same start, and a large beam never calls dense
least squares."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

import phc
import phc.simulation.initial as initial
import phc.simulation.minnorm as minnorm
from phc.simulation import initial_values, parameter_vector
from time_limits import SUBPROCESS_TIMEOUT

MODELS = Path(__file__).resolve().parent.parent / "models"


def _start(compiled):
    mod = compiled.module
    p = parameter_vector(mod, None)
    values, fixed = initial_values(compiled, p)
    return initial.consistent_initial_conditions(mod, p, float(compiled.options.get("t_start", 0.0)), values, fixed)


def _start_and_stage(compiled, monkeypatch):
    """The start, and the problem of the stage that found it with its unknowns there and
    the tolerance it was solved to (``_solve``'s `tol`: the initialization's 1e-11 times
    its scale)."""
    solves = []
    solve = initial._solve

    def recording(prob, tol, max_iter, *rest):
        u, it = solve(prob, tol, max_iter, *rest)
        solves.append((prob, u, tol))
        return u, it

    monkeypatch.setattr(initial, "_solve", recording)
    start = _start(compiled)
    monkeypatch.setattr(initial, "_solve", solve)
    for prob, u, tol in reversed(solves):
        y, yp, _, _ = prob.unpack(u)
        if np.array_equal(y, start.y0) and np.array_equal(yp, start.yp0):
            return start, prob, u, tol
    raise AssertionError("no stage solved to the start returned")


@pytest.mark.parametrize("name", ["pendulum", "double_pendulum", "rigid_slider_crank", "vibrating_string",
                                  "flexible_slider_crank"])
def test_dense_and_sparse_paths_agree(name, monkeypatch):
    compiled = phc.compile_model(str(MODELS / f"{name}.yaml"), certify=False, backend="numpy")
    dense, prob, u, tol = _start_and_stage(compiled, monkeypatch)
    # every solve through the sparse paths: LU of the regular part, else LSMR
    with monkeypatch.context() as m:
        m.setattr(minnorm, "DENSE_SOLVE_LIMIT", 0)
        m.setattr(initial, "DENSE_LIMIT", 0)
        sparse, prob_s, u_s, tol_s = _start_and_stage(compiled, monkeypatch)
    # The bound the Newton tolerance puts on the difference. Both starts pass the same
    # acceptance test: every row of the equilibrated system G within e = 10 tol of 0. At
    # these starts the Newton matrix J of the stage has full column rank (checked), so the
    # solution is locally unique whatever least-norm rule the steps followed, and to first
    # order u_s - u_d = J⁺ (G(u_s) - G(u_d)): |u_s - u_d| <= |J⁺| (2e), entry by entry. A
    # factor 2 covers the second-order remainder and J being taken at one end. (The
    # condition of J makes this loose where J⁺ has large entries: up to 2e-3 of the scale
    # on the flexible slider-crank, where the two starts differ by 3e-15 of it.) Held
    # values are not unknowns: they must agree exactly.
    assert prob_s.free.tolist() == prob.free.tolist() and tol_s == tol, "the starts come from different stages"
    e = 10 * tol
    assert max(np.abs(prob.G(u)).max(), np.abs(prob_s.G(u_s)).max()) <= e
    J = prob.jacobian(u).toarray()
    assert np.linalg.matrix_rank(J) == J.shape[1]
    bound_u = 2 * np.abs(np.linalg.pinv(J)) @ np.full(J.shape[0], 2 * e)
    nf, nd = len(prob.free), len(prob.dif)
    bound_y, bound_yp = np.zeros(len(dense.y0)), np.zeros(len(dense.yp0))
    bound_y[prob.free] = bound_u[:nf]
    bound_yp[prob.dif] = bound_u[nf:nf + nd]
    assert np.all(np.abs(sparse.y0 - dense.y0) <= bound_y)
    assert np.all(np.abs(sparse.yp0 - dense.yp0) <= bound_yp)


def test_large_beam_initialization_calls_no_dense_lstsq(monkeypatch, tmp_path):
    src = (MODELS / "euler_bernoulli_beam.yaml").read_text()
    assert "elements: 6" in src
    path = tmp_path / "beam.yaml"
    path.write_text(src.replace("elements: 6", "elements: 100"))
    compiled = phc.compile_model(str(path), certify=False, backend="numpy")
    calls = []
    lstsq = sla.lstsq

    def counting(*args, **kwargs):
        calls.append(np.shape(args[0]))
        return lstsq(*args, **kwargs)

    monkeypatch.setattr(sla, "lstsq", counting)
    init = _start(compiled)
    assert not calls, f"dense least squares on {calls}"
    assert init.residual <= 1e-10


def _singular_system(n):
    """A consistent system of n unknowns above the dense limit that is rank-deficient in a
    way its pattern does not show: first differences v_{i+1} - v_i = 1 (rows 0..n-2), their
    sum v_{n-1} - v_0 = n - 1 written as one more row over the end values, and a row of
    the same unknowns as row 0 whose value is twice row 0's."""
    import scipy.sparse as sps

    rows, cols, vals = [], [], []
    for i in range(n - 1):
        rows += [i, i]
        cols += [i + 1, i]
        vals += [1.0, -1.0]
    rows += [n - 1, n - 1, n, n]
    cols += [n - 1, 0, 1, 0]
    vals += [1.0, -1.0, 2.0, -2.0]
    A = sps.csr_matrix((vals, (rows, cols)), shape=(n + 1, n))
    b = np.concatenate([np.ones(n - 1), [n - 1.0, 2.0]])
    return A, b


def test_a_large_singular_system_gets_its_least_norm_solution_and_one_lu_attempt(monkeypatch):
    n = 300
    A, b = _singular_system(n)
    assert A.shape[0] * A.shape[1] > minnorm.DENSE_SOLVE_LIMIT
    # closed form: v = c + i, and the least norm puts the mean of v at 0: c = -(n - 1)/2
    exact = np.arange(n) - (n - 1) / 2.0
    attempts = []
    regular_factor = minnorm._regular_factor

    def counting(*args):
        attempts.append(1)
        return regular_factor(*args)

    monkeypatch.setattr(minnorm, "_regular_factor", counting)
    # LSMR stops at the relative round-off of the data (1e-15); the error of a least-norm
    # solution is that times the condition of A on its row space (σ₁/σ_r, of the order of
    # (2n/π)² for differences), with 10 for the accumulated rounding of its recurrences
    sigma = np.linalg.svd(A.toarray(), compute_uv=False)
    kappa = sigma[0] / sigma[sigma > 1e-12 * sigma[0]][-1]
    solver = minnorm.LeastNorm()
    for _ in range(3):  # the Newton steps of one problem: the LU is tried once
        v = solver.solve(A, b)
        assert np.max(np.abs(v - exact)) <= 10 * kappa * 1e-15 * np.max(np.abs(exact))
    assert len(attempts) == 1 and solver.singular


def test_a_regular_large_system_is_solved_by_lu_every_time(monkeypatch):
    import scipy.sparse as sps

    n = 300
    A = sps.diags([np.full(n - 1, -1.0), np.full(n, 3.0), np.full(n - 1, -1.0)], [-1, 0, 1], format="csr")
    x = np.linspace(-1.0, 1.0, n)
    solver = minnorm.LeastNorm()
    for _ in range(2):
        v = solver.solve(A, A @ x)
        # diagonally dominant, κ₁ <= 5: LU with a step of refinement leaves round-off
        assert np.max(np.abs(v - x)) <= 5 * 10 * np.finfo(float).eps
    assert not solver.singular


def _counting_splu(monkeypatch):
    import scipy.sparse.linalg as spla

    calls = []
    splu = spla.splu

    def counting(K, *args, **kwargs):
        calls.append(K.shape)
        return splu(K, *args, **kwargs)

    monkeypatch.setattr(spla, "splu", counting)
    return calls


@pytest.mark.parametrize("rows", ["square", "wide", "dropped"])
def test_the_same_matrix_is_factored_once_and_solves_as_a_fresh_factorization(rows, monkeypatch):
    """The polishing steps of a linear problem: the same matrix, new right-hand sides. The
    sequence factors it once and returns what a fresh solver (its own factorization) does,
    bit for bit; a changed entry is factored again."""
    import scipy.sparse as sps

    n = 300
    T = sps.diags([np.full(n - 1, -1.0), np.full(n, 3.0), np.full(n - 1, -1.0)], [-1, 0, 1], format="csr")
    if rows == "square":
        A = T
    elif rows == "wide":  # full row rank, fewer rows than unknowns: the augmented system
        A = T[: n - 20]
    else:  # a row repeated twice over (structurally dependent, consistent right-hand sides)
        A = sps.vstack([T, 2.0 * T[5]]).tocsr()
    rng = np.random.default_rng(3)
    rhs = [A @ rng.standard_normal(n) for _ in range(3)]
    fresh = [minnorm.min_norm_solve(A, b) for b in rhs]
    calls = _counting_splu(monkeypatch)
    solver = minnorm.LeastNorm()
    for b, v in zip(rhs, fresh):
        assert np.array_equal(solver.solve(A.copy(), b), v)
    assert len(calls) == 1 and not solver.singular
    # the least-norm solution: it solves the system and lies in the row space of A
    v = fresh[0]
    assert np.max(np.abs(A @ v - rhs[0])) <= 1e-13 * np.max(np.abs(rhs[0]))
    if rows == "wide":
        lam = np.linalg.lstsq(A.toarray().T, v, rcond=None)[0]
        assert np.max(np.abs(A.T @ lam - v)) <= 1e-12 * np.max(np.abs(v))
    B = A.copy()
    B.data[0] *= 1.5
    solver.solve(B, rhs[0])
    assert len(calls) == 2


def test_a_zero_right_hand_side_is_answered_by_zero_without_a_factorization(monkeypatch):
    import scipy.sparse as sps

    n = 300
    A = sps.diags([np.full(n - 1, -1.0), np.full(n, 3.0), np.full(n - 1, -1.0)], [-1, 0, 1], format="csr")
    calls = _counting_splu(monkeypatch)
    solver = minnorm.LeastNorm()
    v = solver.solve(A, np.zeros(n))
    assert v.shape == (n,) and not v.any() and not calls
    # a large rank-deficient system where no dense solve is affordable: zero, not None
    S, _ = _singular_system(n)
    assert not minnorm.min_norm_solve(S, np.zeros(n + 1), dense_limit=0, iterative=False).any()


def test_a_string_start_is_found_without_a_factorization_when_it_is_consistent(monkeypatch, tmp_path):
    """A 300-element string at rest (every state held at 0) is consistent as given: its
    Newton steps have G = 0, the start is all zero and no LU is made."""
    src = (MODELS / "vibrating_string.yaml").read_text()
    assert "elements: 16" in src
    path = tmp_path / "string.yaml"
    path.write_text(src.replace("elements: 16", "elements: 300").replace("    energy: H\n", ""))
    mod = phc.compile_model(str(path), certify=False, backend="numpy").module
    p = mod.full_parameters()
    dif = [j for j in range(mod.N) if mod.DIFFERENTIAL[j]]
    calls = _counting_splu(monkeypatch)
    init = initial.consistent_initial_conditions(mod, p, 0.0, {j: 0.0 for j in dif}, set(dif))
    assert not calls
    assert not init.y0.any() and not init.yp0.any() and init.residual == 0.0


def test_one_blas_thread_is_scoped_and_nests():
    threadpoolctl = pytest.importorskip("threadpoolctl")

    def blas_threads():
        return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]

    # the suite runs with one thread (conftest.py, as the `phc` command): two, as a user may
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        with minnorm.one_blas_thread():
            inside = blas_threads()
            with minnorm.one_blas_thread():
                nested = blas_threads()
            after_nested = blas_threads()
        assert inside == nested == after_nested == [1] * len(before)
        assert blas_threads() == before


def test_one_blas_thread_limits_a_blas_loaded_after_its_first_use():
    """scikit-sundae brings its own OpenBLAS, loaded when IDA is first imported: a block after
    that import limits it too (a controller made before the import does not know it)."""
    pytest.importorskip("threadpoolctl")
    script = textwrap.dedent("""
        import threadpoolctl
        import phc.simulation.minnorm as minnorm

        def blas():
            return {i["filepath"]: i["num_threads"] for i in threadpoolctl.threadpool_info()
                    if i["user_api"] == "blas"}

        with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
            with minnorm.one_blas_thread():
                first = blas()
            import sksundae.ida  # noqa: F401 — loads scikit-sundae's libraries
            later = blas()
            with minnorm.one_blas_thread():
                inside = blas()
        print(len(first), len(later), sorted(set(inside.values())))
    """)
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env,
                         timeout=SUBPROCESS_TIMEOUT)
    assert out.returncode == 0, out.stderr
    n_first, n_later, inside = out.stdout.split(maxsplit=2)
    assert int(n_later) >= int(n_first)
    assert inside.strip() == "[1]"  # every BLAS loaded, the one IDA brought included
