"""Repeated components are generated once (:func:`phc.codegen.repeat.repeated`).

An expression that recurs at many entries of a generated function, up to which entries of
y, ẏ and p it reads (the rows of 10⁴ identical spring–mass cells, the terms of their
energy), is written once as a loop over index arrays by the C and numba back ends, and as a
vectorized statement by the NumPy module where it is rational. Checked
here: the split loses and invents nothing (every target and every term of a long sum is
written exactly once, and the template at each instance's entries is the original
expression, exactly, as sympy expressions); the C functions' code does not grow with the
number of cells (only the constant index arrays do); and the loops compute what the NumPy
reference computes, to the bound of tests/codegen/test_c_backend.py (a loop only changes
the order in which a long sum adds its terms: (number of terms)·ε relative to the sum of
their magnitudes, far below 1e-12 for the few hundred terms here).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import sympy as sp

import phc
from phc.codegen import c_backend
from phc.codegen.kernels import REPEAT_MIN, function_kernels, repeated, slot
from phc.codegen.lower import lower_residual
from phc.pipeline import build_dae
from compiled_loading import assert_close, call

_OK, _WHY = c_backend.available()
needs_cc = pytest.mark.skipif(not _OK, reason=f"C backend not tested: {_WHY}")

TOL = 1e-12
"""As tests/codegen/test_c_backend.py (see the module docstring)."""


def chain(cells: int, nonlinear: bool = False) -> str:
    """A wall, then cells spring–mass; odd cells use `ka`, `ma`, even ones `kb`, `mb` (a
    parameter read at an entry that changes from instance to instance). With `nonlinear`,
    an output per cell with functions and a condition (a nonlinear template)."""
    # no units: the outputs mix a length and a momentum in functions on purpose
    lines = ["format_version: 1", f"name: chain_{cells}", "parameters:",
             "  ka: 100.0", "  kb: 70.0", "  ma: 1.0", "  mb: 2.5", "components:",
             "  wall: {type: zero_flow, domain: mechanical.translational}"]
    for i in range(1, cells + 1):
        ports = "[l, r]" if i < cells else "[l]"
        side = "a" if i % 2 else "b"
        lines += [f"  k{i}: {{type: spring, k: k{side}, terminals: [a, b]}}",
                  f"  m{i}: {{type: mass, m: m{side}, ports: {ports}}}"]
    lines += ["connections:", "  - [wall.port, k1.a]", "  - [k1.b, m1.l]"]
    for i in range(2, cells + 1):
        lines += [f"  - [m{i - 1}.r, k{i}.a]", f"  - [k{i}.b, m{i}.l]"]
    lines += ["simulation:", "  t_end: 1.0", "  initial: {k1.x: 0.01}", "  outputs:"]
    lines += ["    x1: k1.x"]
    if nonlinear:
        lines += [f"    o{i}: \"sin(k{i}.x)*m{i}.p + ifelse(m{i}.p > 0, k{i}.x**2, -sqrt(1 + m{i}.p**2))\""
                  for i in range(1, cells + 1)]
    return "\n".join(lines) + "\n"


def _ir(tmp_path, text, name="chain.yaml"):
    path = tmp_path / name
    path.write_text(text)
    dae, _ = build_dae(path)
    return lower_residual(dae), path


def _value_at(ir, r, k):
    """Instance k of a Repeated: its template with its slots replaced by the entries it reads."""
    vectors = {"y": ir.y_symbols, "yp": ir.yp_symbols, "p": ir.p_symbols}
    return r.template.xreplace({slot(j): vectors[v][int(at[k])] for j, (v, at) in enumerate(r.slots)})


def test_the_split_writes_every_target_and_term_once_as_it_was(tmp_path):
    ir, _ = _ir(tmp_path, chain(40, nonlinear=True))
    rng = np.random.default_rng(5)
    symbols = [s for s in (*ir.y_symbols, *ir.yp_symbols, *ir.p_symbols) if s is not None]
    point = {s: sp.Float(rng.uniform(-1.5, 1.5)) for s in symbols}
    kinds = set()
    for f in function_kernels(ir):
        targets = f.kernel.targets
        left, loops = repeated(ir, targets)
        original = {i: (e, acc) for i, e, acc in targets}
        written: dict = {i: [] for i in original}
        for i, e, acc in left:
            assert acc == original[i][1]
            written[i].append(e)
        for r in loops:
            assert r.count >= REPEAT_MIN and len(r.index) == r.count
            summed = bool((r.index == r.index[0]).all())
            kinds.add(summed)
            for k in range(r.count):
                i = int(r.index[k])
                assert summed or r.accumulate == original[i][1]
                written[i].append(_value_at(ir, r, k))
        for i, (e, _) in original.items():
            # a target is written by one statement, or by one statement and the loops of its
            # long sum's terms: the parts add up to the expression (sympy may evaluate a
            # template in its own way, Abs(1/m) as 1/Abs(m): compared at a point, where the
            # parts' sum has the round-off of sympy's 15-digit evaluation of a few hundred terms)
            assert written[i], (f.name, i)
            whole = sp.Add(*written[i])
            if whole != e:
                a, b = float(whole.xreplace(point).evalf()), float(e.xreplace(point).evalf())
                assert abs(a - b) <= 1e-12 * max(1.0, abs(b)), (f.name, i, whole, e)
        if f.name in ("residual", "jacobian", "hamiltonian", "outputs"):
            assert loops, f.name  # 40 cells: every one of these has a repeated expression
    assert kinds == {True, False}  # rows and terms of one sum were both looped


def test_fewer_instances_than_the_minimum_stay_straight_line(tmp_path):
    ir, _ = _ir(tmp_path, chain(REPEAT_MIN // 2 - 1))
    for f in function_kernels(ir):
        left, loops = repeated(ir, f.kernel.targets)
        assert not loops and left == tuple(f.kernel.targets), f.name


def _bodies(source: str) -> str:
    """The C text without its constant arrays and comments: the code."""
    code = re.sub(r"static const (int|double) \w+\[\d+\] = \{[^}]*\};", "", source)
    code = re.sub(r"/\*.*?\*/", "", code, flags=re.S)
    return "\n".join(line for line in code.splitlines() if line.strip())


@needs_cc
def test_c_code_of_a_chain_does_not_grow_with_its_cells(tmp_path):
    small = phc.compile_model(_ir(tmp_path, chain(40), "a.yaml")[1], certify=False, backend="c").module
    large = phc.compile_model(_ir(tmp_path, chain(400), "b.yaml")[1], certify=False, backend="c").module
    assert "a loop over the entries" in large.C_SOURCE
    a, b = _bodies(small.C_SOURCE), _bodies(large.C_SOURCE)
    # the same statements; only loop counts, and the entries that are not in any loop (the
    # wall's and the free end's cells) change their numbers
    assert len(a.splitlines()) == len(b.splitlines())
    assert len(b) < 1.1 * len(a)
    assert len(large.C_SOURCE) < 4 * len(small.C_SOURCE)  # 10x the cells: index arrays only


@pytest.mark.parametrize("backend", ["c", "numba"])
def test_loops_compute_what_the_reference_computes(tmp_path, backend):
    if backend == "c" and not _OK:
        pytest.skip(f"C backend not tested: {_WHY}")
    if backend == "numba":
        pytest.importorskip("numba")
    path = _ir(tmp_path, chain(60, nonlinear=True))[1]
    fast = phc.compile_model(path, certify=False, backend=backend).module
    assert fast.BACKEND == backend
    ref = fast.REFERENCE
    rng = np.random.default_rng(7)
    p = np.asarray(ref.full_parameters(), dtype=float)
    for _ in range(4):
        t, cj = float(rng.uniform(0.0, 2.0)), float(rng.uniform(0.1, 50.0))
        y, yp = rng.uniform(-1.0, 1.0, ref.N), rng.uniform(-1.0, 1.0, ref.N)
        for name in ("residual", "jacobian", "hamiltonian", "energy_scale", "powers", "outputs"):
            assert_close(name, call(ref, name, t, y, yp, p, cj), call(fast, name, t, y, yp, p, cj), TOL)


@needs_cc
def test_a_chain_run_on_the_loops_is_the_midpoint_rule_of_the_chain_written_here(tmp_path):
    """End to end: the chain's trajectory on the C back end (its functions are loops) against
    the implicit midpoint rule applied in this test to the chain's equations of motion,
    m_i ü_i = k_i (u_{i−1} − u_i) + k_{i+1} (u_{i+1} − u_i), u_0 = 0 (the wall), the last
    cell free. The rule's step map of a linear system, (I − hA/2)⁻¹(I + hA/2), commutes
    with a linear change of variables, so phc's steps in spring elongations and momenta are
    these steps in positions and momenta, and k1.x = ±u_1 (k1.x(0) = 0.01 with every other
    elongation 0 is u_i(0) = ±0.01 for all i). The model is linear, so Newton ends on its
    first correction; what is left is round-off, a few ε per step times the 500 steps here
    relative to the amplitude (about 1e-13 of it): 1e-10 of it is far above that and far
    below the change a wrong entry or a wrong step would make."""
    cells, h, steps = 24, 2e-3, 500
    path = tmp_path / "chain.yaml"
    path.write_text(chain(cells))
    compiled = phc.compile_model(path, certify=False, backend="c")
    assert "a loop over the entries" in compiled.module.C_SOURCE
    t_eval = h * np.arange(steps + 1)
    result = phc.simulate(compiled, t_eval=t_eval, solver="midpoint", step=h)
    assert result.success, result.message

    k = np.array([100.0 if i % 2 else 70.0 for i in range(1, cells + 1)])
    m = np.array([1.0 if i % 2 else 2.5 for i in range(1, cells + 1)])
    K = np.zeros((cells, cells))  # stiffness: spring i joins mass i−1 (the wall for i = 1) and mass i
    for i in range(cells):
        K[i, i] += k[i]
        if i > 0:
            K[i - 1, i - 1] += k[i]
            K[i - 1, i] -= k[i]
            K[i, i - 1] -= k[i]
    A = np.block([[np.zeros((cells, cells)), np.diag(1.0 / m)], [-K, np.zeros((cells, cells))]])
    eye = np.eye(2 * cells)
    step = np.linalg.solve(eye - 0.5 * h * A, eye + 0.5 * h * A)
    z = np.concatenate([np.full(cells, 0.01), np.zeros(cells)])
    u1 = [z[0]]
    for _ in range(steps):
        z = step @ z
        u1.append(z[0])
    x1 = result.y[:, list(result.variables).index("k1.x")]
    assert x1[0] == pytest.approx(0.01)
    assert np.ptp(x1) > 0.01  # it moves: the first spring swings through more than its start
    # k1.x = ±(u_1 − u_0) and u(0) = ±0.01: either sign gives the same function (docstring)
    assert np.abs(x1 - np.asarray(u1)).max() <= 1e-10 * 0.01


def _numpy_module(tmp_path, cells, name, nonlinear=False):
    path = tmp_path / name
    path.write_text(chain(cells, nonlinear=nonlinear))
    return phc.compile_model(path, certify=False, backend="numpy")


def test_numpy_module_vectorizes_and_computes_the_equations(tmp_path):
    """The NumPy module (the reference of the compiled back ends) writes a recurring rational
    expression once, on arrays; each function's value is the value of the lowered equations
    at the same point, evaluated here by sympy (no printer involved). Bound: the functions add
    at most a few hundred terms, each rounded: 1e-12 of the sum of the terms' magnitudes
    (sympy's value is exact at the point, to 15 digits)."""
    compiled = _numpy_module(tmp_path, 40, "a.yaml", nonlinear=True)
    mod, source = compiled.module, compiled.source
    ir = lower_residual(build_dae(tmp_path / "a.yaml")[0])
    assert not ir.linear_terms and not ir.quadratic_energy  # every row is an expression here
    assert source.count("one expression at") >= 4 and "terms of H: one expression" in source
    body = source.split("def _residual(", 1)[1].split("\ndef ", 1)[0]
    assert body.count("\n") < 40  # 80 rows, a handful of statements
    assert source.count("math.sin(") >= 40  # a template with functions stays one statement per entry
    rng = np.random.default_rng(11)
    p = np.asarray(mod.full_parameters(), dtype=float)
    for _ in range(3):
        t, cj = float(rng.uniform(0.0, 2.0)), float(rng.uniform(0.1, 50.0))
        y, yp = rng.uniform(-1.0, 1.0, mod.N), rng.uniform(-1.0, 1.0, mod.N)
        point = {sym: sp.Float(v) for syms, vals in ((ir.y_symbols, y), (ir.yp_symbols, yp), (ir.p_symbols, p))
                 for sym, v in zip(syms, vals) if sym is not None}
        point[sp.Symbol("cj")] = sp.Float(cj)

        def exact(e):
            return float(sp.sympify(e).xreplace(point).evalf(20)) if e != 0 else 0.0

        def magnitude(e):
            return sum(abs(exact(term)) for term in sp.Add.make_args(sp.expand(e))) if e != 0 else 0.0

        out = np.zeros(mod.N)
        mod.residual(t, y, yp, p, out)
        for i, e in enumerate(ir.residual):
            assert abs(out[i] - exact(e)) <= 1e-12 * max(magnitude(e), 1e-300), (i, e)
        jac = np.zeros(len(mod.JAC_ROWS))
        mod.jacobian(t, y, yp, p, cj, jac)
        for k, dy, dyp in ir.jac_symbolic:
            e = dy + sp.Symbol("cj") * dyp
            assert abs(jac[k] - exact(e)) <= 1e-12 * max(magnitude(e), 1e-300), (k, e)
        H = ir.hamiltonian
        assert abs(mod.hamiltonian(t, y, p) - exact(H)) <= 1e-12 * magnitude(H)
        assert abs(mod.energy_scale(t, y, p) - magnitude(H)) <= 1e-12 * magnitude(H)


def test_numpy_module_of_a_chain_does_not_grow_with_its_cells(tmp_path):
    small = _numpy_module(tmp_path, 40, "a.yaml").source
    large = _numpy_module(tmp_path, 400, "b.yaml").source

    def functions(source):  # the code of the functions, without the module's constant tables
        return [line for line in source.split("\ndef full_parameters(", 1)[1].splitlines() if line.strip()]

    # the same statements; only the bounds of slices and the names of the entries outside the
    # repeated cells (the wall's, the free end's) change
    assert len(functions(small)) == len(functions(large))
    assert len("".join(functions(large))) < 1.1 * len("".join(functions(small)))


def test_numpy_module_divides_by_zero_as_numpy_does(tmp_path):
    """A vectorized statement that divides by a zero mass raises inside the fast path on
    Python floats, as the scalar statements do; the call is then evaluated on NumPy scalars
    and arrays: inf or nan where the mass is 0, every other entry as with the mass set."""
    mod = _numpy_module(tmp_path, 40, "a.yaml").module
    p = np.asarray(mod.full_parameters(), dtype=float)
    zero = p.copy()
    zero[list(mod.PARAMETERS).index("mb")] = 0.0
    rng = np.random.default_rng(3)
    y, yp = rng.uniform(-1.0, 1.0, mod.N), rng.uniform(-1.0, 1.0, mod.N)
    a, b = np.zeros(mod.N), np.zeros(mod.N)
    mod.residual(0.0, y, yp, p, a)
    with np.errstate(all="ignore"):
        mod.residual(0.0, y, yp, zero, b)
    bad = ~np.isfinite(b)
    assert bad.any() and np.isfinite(a).all()
    assert np.array_equal(a[~bad], b[~bad])
