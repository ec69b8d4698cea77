"""The Jacobian of consistent initialization (`phc.simulation.initial._Problem`).

A synthetic residual module with a Jacobian that varies with y and ẏ (products of
velocities, as in the forces of a rotating body) and explicit time dependence, built with
sympy here, independently of phc's code generator. Its derivative rows D = F_y ẏ + F_ẏ ÿ
+ F_t and their Jacobian are differentiated symbolically and compared with the solver's
values; the grouped finite differences must match column by column and need a number of
D evaluations that does not grow with the size of a banded system.
"""

from types import SimpleNamespace

import numpy as np
import pytest
import sympy as sp

from phc.simulation.initial import _Problem


def _chain(n: int):
    """Module for a cyclic chain of n differential x and n algebraic z (2n rows), plus the
    symbolic pieces for the reference."""
    t = sp.Symbol("t")
    x, z = sp.symbols(f"x0:{n}"), sp.symbols(f"z0:{n}")
    xd, zd = sp.symbols(f"xd0:{n}"), sp.symbols(f"zd0:{n}")
    y, yp = list(x) + list(z), list(xd) + list(zd)
    F = [xd[i] * (1 + x[(i + 1) % n] ** 2 / 10) - z[i] - z[i] ** 2 / 10 - sp.sin(t) * x[i] / 5 for i in range(n)]
    F += [z[i] - x[i] * x[(i + 1) % n] + xd[(i + 2) % n] ** 2 / 20 + sp.cos(t) * xd[i] * x[(i + 3) % n] / 7
          for i in range(n)]
    N = 2 * n
    entries = sorted({(i, j) for i, f in enumerate(F) for j in range(N) if f.has(y[j]) or f.has(yp[j])},
                     key=lambda ij: (ij[1], ij[0]))
    cj = sp.Symbol("cj")
    jac = [sp.diff(F[i], y[j]) + cj * sp.diff(F[i], yp[j]) for i, j in entries]
    used = set().union(*(e.free_symbols for e in jac))
    f_res = sp.lambdify((t, y, yp), F, "math")
    f_jac = sp.lambdify((t, y, yp, cj), jac, "math")
    f_t = sp.lambdify((t, y, yp), [sp.diff(f, t) for f in F], "math")
    calls = {"residual_t": 0}

    def residual(tt, yy, yyp, p, out):
        out[:] = f_res(tt, yy, yyp)

    def jacobian(tt, yy, yyp, p, c, out):
        out[:] = f_jac(tt, yy, yyp, c)

    def residual_t(tt, yy, yyp, p, out):
        calls["residual_t"] += 1
        out[:] = f_t(tt, yy, yyp)

    mod = SimpleNamespace(
        N=N, VARIABLES=tuple(str(s) for s in y), ROLES=("state",) * N,
        EQUATIONS=tuple(f"row{i}" for i in range(N)), DIFFERENTIAL=np.array([True] * n + [False] * n),
        JAC_ROWS=np.array([i for i, _ in entries], dtype=np.int64),
        JAC_COLS=np.array([j for _, j in entries], dtype=np.int64),
        JAC_DEPENDS_ON_Y=np.array([j for j in range(N) if y[j] in used], dtype=np.int64),
        JAC_DEPENDS_ON_YP=np.array([j for j in range(N) if yp[j] in used], dtype=np.int64),
        INITIAL=("x0 = x1",), INITIAL_ROWS=np.array([0, 0]), INITIAL_COLS=np.array([0, 1]),
        INITIAL_DATA=np.array([1.0, -1.0]),
        residual=residual, jacobian=jacobian, residual_t=residual_t)
    return mod, calls, (t, y, yp, F)


def _reference(prob, sym, t0, u):
    """D and the Jacobian of G = [s F; s D; C y] from symbolic derivatives."""
    t, y, yp, F = sym
    N = len(y)
    z, w = sp.symbols(f"zz0:{N}"), sp.symbols(f"ww0:{N}")
    dif = set(prob.dif.tolist())
    ydot = [yp[j] if j in dif else z[j] for j in range(N)]
    D = [sum(sp.diff(f, y[j]) * ydot[j] + sp.diff(f, yp[j]) * w[j] for j in range(N)) + sp.diff(f, t) for f in F]
    unknowns = ([y[j] for j in prob.free] + [yp[j] for j in prob.dif] + [z[j] for j in prob.zc]
                + [w[j] for j in prob.wc])
    k = prob.kept
    G = [prob.row_scale[i] * F[i] for i in range(len(F))] + [prob.row_scale[i] * D[i] for i in k]
    args = (t, y, yp, z, w)
    values = (t0, *prob.unpack(u))
    J = np.array(sp.lambdify(args, sp.Matrix(G).jacobian(unknowns).tolist(), "math")(*values), dtype=float)
    J = np.vstack([J, prob.C[:, prob.free].toarray() @ np.eye(len(prob.free), J.shape[1])])
    return np.array(sp.lambdify(args, [D[i] for i in k], "math")(*values), dtype=float), J


@pytest.mark.parametrize("stage", ["states held", "states free"])
def test_jacobian_matches_symbolic_derivatives(stage):
    mod, _, sym = _chain(5)
    rng = np.random.default_rng(3)
    y = rng.normal(size=mod.N)
    dif = set(range(5))
    fixed = dif | {7} if stage == "states held" else {7}
    prob = _Problem(mod, None, 0.4, y, fixed)
    assert len(prob.kept) and len(prob.fd_y) and len(prob.fd_yp)  # every branch is exercised
    u = prob.pack() + rng.normal(size=len(prob.pack()))
    D_ref, J_ref = _reference(prob, sym, 0.4, u)
    np.testing.assert_allclose(prob.D(*prob.unpack(u)), D_ref, rtol=1e-12, atol=1e-12)
    J = prob.jacobian(u).toarray()
    assert J.shape == J_ref.shape
    # forward differences with steps of 1e-7 relative: errors of order 1e-7 times the
    # second derivatives (O(1) here); a column grouped with one that shares a row is O(1) off
    np.testing.assert_allclose(J, J_ref, rtol=0, atol=1e-5)


def test_finite_differences_are_grouped():
    for n in (10, 20):
        mod, calls, _ = _chain(n)
        y = np.random.default_rng(5).normal(size=mod.N)
        prob = _Problem(mod, None, 0.1, y, set())
        calls["residual_t"] = 0
        prob.jacobian(prob.pack())
        # columns needing finite differences (y and ẏ), each with the kept rows it enters
        kept = set(prob.kept.tolist())
        rows_of = [{i for i, j in zip(mod.JAC_ROWS, mod.JAC_COLS) if j == c and i in kept}
                   for c in list(prob.fd_y) + list(prob.fd_yp)]
        assert len(rows_of) == 3 * n  # one evaluation of D per column would need 3n
        # greedy grouping needs at most (largest number of columns one column shares a row with) + 1
        # groups, a bound that does not grow along a banded chain; plus the base point
        degree = max(sum(1 for b in rows_of if b is not a and a & b) for a in rows_of)
        assert calls["residual_t"] <= 1 + degree + 1 < len(rows_of)


class _Module(SimpleNamespace):
    """A module object that can be weakly referenced and hashed by identity, as a generated
    module can (the structure cache, phc.simulation.initial._structures, keys on it)."""

    __eq__ = object.__eq__
    __hash__ = object.__hash__


@pytest.mark.parametrize("stage", ["states held", "states free"])
def test_dense_jacobian_is_the_sparse_one(stage):
    mod, _, _ = _chain(5)
    rng = np.random.default_rng(4)
    fixed = set(range(5)) | {7} if stage == "states held" else {7}
    prob = _Problem(mod, None, 0.4, rng.normal(size=mod.N), fixed)
    u = prob.pack() + rng.normal(size=len(prob.pack()))
    dense = prob.dense_jacobian(u)
    assert dense.shape == prob.shape()
    # the same entries put in place: equal to the last bit
    np.testing.assert_array_equal(dense, prob.jacobian(u).toarray())


def test_structure_is_reused_with_this_start_s_row_scaling():
    base, _, _ = _chain(6)
    cached = _Module(**vars(base))  # the same functions; `base` itself cannot be cached
    rng = np.random.default_rng(6)
    held = set(range(6)) | {8}
    first = _Problem(cached, None, 0.2, rng.normal(size=base.N), held)
    first.jacobian(first.pack())
    for fixed in (held, {8}):  # the same unknowns (reused), other unknowns (built anew)
        y = 3.0 * rng.normal(size=base.N)
        again = _Problem(cached, None, 0.7, y, fixed)
        fresh = _Problem(base, None, 0.7, y, fixed)
        u = again.pack() + rng.normal(size=len(again.pack()))
        J = again.jacobian(u).toarray()
        assert (again._csr_indices is first._csr_indices) == (fixed == held)
        assert not np.array_equal(again.row_scale, first.row_scale)  # another start: other row scales
        np.testing.assert_array_equal(again.kept, fresh.kept)
        np.testing.assert_array_equal(J, fresh.jacobian(u).toarray())
        np.testing.assert_array_equal(again.G(u), fresh.G(u))
