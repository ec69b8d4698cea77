"""What a mesh's compile and start keep per unknown (issue 35): counted on the structure,
never timed. A Euler–Bernoulli cantilever of n Hermite elements (8 n + 7 unknowns, 54 n
Jacobian entries) is compiled at two sizes; what grows with the mesh must be arrays, and
the Python objects the compiler makes for it must not grow with the elements."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import phc
from phc.codegen.lower import lower_residual
from phc.codegen.printer import ModulePrinter, _distinct_cleaned, _identifiers
from phc.pipeline import build_dae
from phc.simulation import initial

BEAM = """format_version: 1
name: cantilever{n}
parameters: {{EI: 68.27, rhoA: 0.50368, F: 1.0}}
components:
  beam: {{type: euler_bernoulli_beam, length: 0.3, elements: {n}, rhoA: rhoA, EI: EI}}
  clamp: {{type: zero_flow, domain: mechanical.translational}}
  clamp_rot: {{type: zero_flow, domain: mechanical.rotational}}
  load: {{type: effort_source, domain: mechanical.translational, value: "F*sin(100*t)"}}
  free_rot: {{type: zero_effort, domain: mechanical.rotational}}
connections:
  - [beam.a, clamp.port]
  - [beam.a_rot, clamp_rot.port]
  - [beam.b, load.port]
  - [beam.b_rot, free_rot.port]
simulation:
  outputs: {{tip_velocity: beam.b.f, energy: H}}
"""
"""The cantilever of benchmarks/bench_beam_scale.py, with the stored energy as an output."""


def _ir(tmp_path, n: int):
    path = tmp_path / f"beam{n}.yaml"
    path.write_text(BEAM.format(n=n))
    dae, diags = build_dae(path)
    assert dae is not None, [str(d) for d in diags.errors]
    return lower_residual(dae)


def test_the_ir_keeps_only_the_symbolic_jacobian_entries(tmp_path):
    """The Jacobian pattern grows by 54 entries an element; the entries with a symbolic part
    (the boundary couplings, the load, the energy balance) do not grow at all: the blocks'
    entries are data of the blocks, not sympy zeros held one by one. The full columns
    (``jac_dy``, ``jac_dyp``) are still what they were: zero wherever no symbolic entry is."""
    small, large = _ir(tmp_path, 40), _ir(tmp_path, 400)
    assert len(large.jac_rows) - len(small.jac_rows) == 54 * 360
    assert len(large.jac_symbolic) == len(small.jac_symbolic)
    ks = [k for k, _, _ in large.jac_symbolic]
    assert ks == sorted(set(ks))
    dy, dyp = large.jac_dy, large.jac_dyp
    assert len(dy) == len(dyp) == len(large.jac_rows)
    symbolic = dict((k, (a, b)) for k, a, b in large.jac_symbolic)
    assert all((dy[k], dyp[k]) == symbolic.get(k, (0, 0)) for k in range(len(dy)))


def test_the_printer_names_only_the_variables_it_prints(tmp_path):
    """The module's functions read a fixed handful of a mesh's variables; the printer makes
    names for those only, and each is the name the eager naming of every variable
    (:func:`phc.codegen.printer._identifiers`) gives it."""
    sizes = []
    for n in (40, 400):
        ir = _ir(tmp_path, n)
        printer = ModulePrinter(ir)
        printer.print()
        named = {s: name for s, name in printer.names.items() if s in printer.unpack_y or s in printer.unpack_yp}
        sizes.append(len(named))
        taken: set = set()
        eager_y = _identifiers("y_", ir.variables, taken)
        eager_yp = _identifiers("yp_", ir.variables, taken)
        for s, name in named.items():
            j = printer.unpack_y.get(s)
            assert name == (eager_y[j] if j is not None else eager_yp[printer.unpack_yp[s]])
    assert sizes[0] == sizes[1] > 0


def test_names_that_clean_alike_are_named_eagerly():
    """Two model names that make the same identifier (``a.b`` and ``a_b``) are told apart by
    a suffix, which only the eager naming of every variable gives."""
    assert _distinct_cleaned(["beam.p[0]", "beam.p[1]", "clamp.port.e"])
    assert not _distinct_cleaned(["a.b", "a_b"])
    assert not _distinct_cleaned(["x[1]", "x_1"])
    assert _identifiers("y_", ["a.b", "a_b"], set()) == ["y_a_b", "y_a_b_2"]


def _compiled(tmp_path, n: int):
    path = tmp_path / f"beam{n}.yaml"
    path.write_text(BEAM.format(n=n))
    return phc.compile_model(path, backend="numpy", certify=False)


def test_a_mesh_at_rest_starts_without_a_newton_matrix(tmp_path, monkeypatch):
    """A cantilever at rest is consistent as it stands: its start evaluates the rows and their
    derivative, and builds no Newton matrix (the structure of the Jacobian of [F; D] is
    built on the first Newton step only)."""
    mod = _compiled(tmp_path, 400).module
    p = mod.full_parameters()
    dif = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))

    def refuse(self):
        raise AssertionError("the Newton matrix's structure was built for a consistent start")

    monkeypatch.setattr(initial._Problem, "_prepare", refuse)
    init = initial.consistent_initial_conditions(mod, p, 0.0, {int(j): 0.0 for j in dif}, set(dif.tolist()))
    assert not init.y0.any() and not init.yp0.any()


@pytest.mark.parametrize("moving", [False, True])
def test_the_start_of_a_mesh_holds_no_more_than_a_few_jacobians(tmp_path, monkeypatch, moving):
    """Consistent initialization of a 400-element cantilever (3 207 unknowns, 21 624
    Jacobian entries) allocates at most 24 arrays the size of the Jacobian's data at once at
    rest (an n × n dense matrix would be 480 of them): no Newton matrix — the module's memo of
    its blocks (four), the flat F_y and F_ẏ, the rows' scales and the matching's pattern of
    F_ẏ, the nominal scales' entries; building the Newton structure there took 34. Moving the
    clamped end's momentum onto the clamp's constraint (Newton steps) adds the step's KKT
    matrix, built as triplets and held in CSC (24 + 12 bytes an entry), and its sparse LU
    factors (8 bytes a value and 4 an index an entry of L and U), whose sizes the test reads
    from the factorization (the fill of SuperLU's ordering: 2.7 and 7.5 Jacobians' entries
    here, 40 arrays in all measured against a bound of 48)."""
    from phc.simulation import sparse_lu as sparse_lu_module

    factored = []

    def recorded(K):
        lu = sparse_lu_module.sparse_lu(K)
        factored.append((K.nnz, lu.L.nnz + lu.U.nnz))
        return lu

    monkeypatch.setattr(initial, "sparse_lu", recorded)
    mod = _compiled(tmp_path, 400).module
    p = mod.full_parameters()
    dif = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))
    values = {int(j): 0.0 for j in dif}
    fixed = set(dif.tolist())
    if moving:  # a momentum guessed that the clamp does not allow: the start must move it
        values[int(dif[0])] = 1e-3
        fixed.discard(int(dif[0]))
    nnz = len(mod.JAC_ROWS)
    tracemalloc.start()
    try:
        start = tracemalloc.get_traced_memory()[0]
        init = initial.consistent_initial_conditions(mod, p, 0.0, values, fixed)
        peak = tracemalloc.get_traced_memory()[1] - start
    finally:
        tracemalloc.stop()
    kkt, factors = max(factored, default=(0, 0))
    assert bool(factored) == moving  # at rest, no Newton step
    arrays = 24 + (36 * kkt + 12 * factors) / (8 * nnz)
    assert peak < arrays * 8 * nnz, (peak / (8 * nnz), arrays)
    res = np.zeros(mod.N)
    mod.residual(0.0, init.y0, init.yp0, p, res)
    assert np.abs(res).max() < 1e-8


def test_the_newton_matrix_is_scaled_as_the_sparse_products_scaled_it(tmp_path, monkeypatch):
    """The midpoint Newton matrix is scaled on its own arrays: the matrix factored is the one
    ``D_r @ J @ D_c`` gives (the same pattern, stored zeros dropped, the same bits: the scales
    are powers of two)."""
    import scipy.sparse as sps

    from phc.simulation import midpoint

    mod = _compiled(tmp_path, 30).module
    p = mod.full_parameters()
    matrix = midpoint.NewtonMatrix(mod, p)
    factored = []
    import scipy.sparse.linalg as spla  # what phc.simulation.sparse_lu factorizes with

    monkeypatch.setattr(spla, "splu", lambda J, *a, **k: factored.append(J.copy()) or object())
    rng = np.random.default_rng(1)
    y, y1 = rng.standard_normal(mod.N), rng.standard_normal(mod.N)
    y[0] = y1[0] = 0.0  # an entry that is zero here
    assert matrix.factor(0.1, 1e-3, y, y1)
    buf = np.zeros(len(mod.JAC_ROWS))
    d = y1 - y
    mod.jacobian(0.1 + 0.5e-3, y + 0.5 * d, d / 1e-3, p, 1.0 / 0.5e-3, buf)
    J = sps.csc_matrix((0.5 * buf, (mod.JAC_ROWS, mod.JAC_COLS)), shape=(mod.N, mod.N))
    expected = sps.csc_matrix(sps.diags(matrix.row_scale) @ J @ sps.diags(matrix.col_scale))
    got = factored[0]
    got.sort_indices()
    expected.sort_indices()
    assert np.array_equal(got.indptr, expected.indptr) and np.array_equal(got.indices, expected.indices)
    assert np.array_equal(got.data, expected.data)


def test_kind_groups_are_the_names_grouped_by_kind():
    """The nominal scales' groups of variables of one kind (their names without indices),
    found by runs, are those a dictionary of every name gives: each kind with more than one
    variable, its indices ascending, interleaved kinds included."""
    from phc.simulation.scaling import kind_groups, kind_of

    rng = np.random.default_rng(2)
    names = [f"{rng.choice(['a.p', 'a.e', 'b.q', 'c'])}[{i}]" if rng.random() < 0.8 else f"x{i % 3}"
             for i in range(400)]
    expected: dict = {}
    for j, name in enumerate(names):
        expected.setdefault(kind_of(name), []).append(j)
    got = kind_groups(names)
    assert [g.tolist() for g in got] == [m for m in expected.values() if len(m) > 1]


def test_a_mesh_keeps_no_object_per_row_beyond_its_rows(tmp_path):
    """Issue 35: what the assembled system holds per unknown. Its variables and equations
    are slotted (no ``__dict__`` each), a sparse block's rows are a ``range`` (no Python int
    per row), and the component rows the rows check reads are views of the same objects
    (no tuple per row), read as the tuples they stand for; the system pickles (the caches,
    Dask) and comes back equal."""
    import pickle

    from phc.ir.dae import FieldTuples

    path = tmp_path / "beam40.yaml"
    path.write_text(BEAM.format(n=40))
    dae, _ = build_dae(path)
    assert not any(hasattr(v, "__dict__") for v in dae.variables)
    assert not any(hasattr(eq, "__dict__") for eq in dae.equations)
    assert dae.linear_blocks and all(isinstance(b.rows, range) for b in dae.linear_blocks)
    covered = sorted(r for b in dae.linear_blocks for r in b.rows)
    assert covered == sorted(i for i, eq in enumerate(dae.equations) if eq.kind == "linear")
    for b in dae.linear_blocks:  # the block's rows are its own, in order: label[0], label[1], ...
        assert [dae.equations[r].label for r in b.rows] == [f"{b.label}[{k}]" for k in range(len(b.rows))]
    (beam,) = [r for r in dae.topology.rows if r.component == "beam"]
    assert isinstance(beam.equations, FieldTuples) and isinstance(beam.variables, FieldTuples)
    pairs = tuple(beam.equations)
    assert beam.equations == pairs and len(pairs) == len(beam.equations) and beam.equations[-1] == pairs[-1]
    assert beam.equations[1:3] == pairs[1:3] and all(type(p) is tuple and len(p) == 2 for p in pairs)
    linear = {eq.label: eq.expr for eq in dae.equations if eq.kind == "linear" and eq.component == "beam"}
    assert set(linear) <= set(dict(pairs))  # the boundary rows' couplings are assembled into them
    viewed = {id(eq) for eq in beam.equations.objects}  # the rows assembly kept as they were: shared
    shared = [eq for eq in dae.equations if id(eq) in viewed]
    assert len(shared) >= len(linear) - 8 and all(dict(pairs)[eq.label] is eq.expr for eq in shared)
    own = {v.symbol: (v.dsymbol, v.role) for v in dae.variables if v.component == "beam"}
    assert all(own[s] == (ds, role) for s, ds, role in beam.variables if s in own)
    back = pickle.loads(pickle.dumps(dae))
    assert back.variables == dae.variables and back.equations == dae.equations
    assert [b.rows for b in back.linear_blocks] == [b.rows for b in dae.linear_blocks]
    assert tuple(back.topology.rows[0].equations) == tuple(dae.topology.rows[0].equations)


def test_shifted_rows_are_a_range_exactly_when_consecutive():
    from phc.ir.dae import shifted_rows

    assert shifted_rows(range(3, 7), 10) == range(13, 17)
    assert shifted_rows((3, 4, 5), 2) == range(5, 8)
    assert shifted_rows((3, 5), 2) == (5, 7)
    index = {0: 4, 1: 5, 2: 6, 3: 9}
    assert shifted_rows(range(3), index.__getitem__) == range(4, 7)
    assert shifted_rows(range(4), index.__getitem__) == (4, 5, 6, 9)
    assert shifted_rows((), 5) == ()
