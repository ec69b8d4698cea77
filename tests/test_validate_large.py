"""``phc validate`` of a chain of 10⁴ components (issue 38): identical components are lowered
once and the others built from that template, and nothing of what validate checks is
skipped on the way.

* errors planted in the 9000th cell of a chain of 9001 cells (a field of the wrong unit, an
  unknown name, an unknown port) are each reported at their own line and column, exactly
  where the text has them: the template path does not stand in for a component that
  differs from its neighbours, nor the per-connection checks for the 18 000th connection;
* work counted, not timed: the instances built from a template create their symbols
  without sympy's deduction of assumptions, so that deduction runs a number of times
  independent of the chain's length (it ran 8 times per cell before).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sps
import sympy as sp
from sympy.core.cache import clear_cache

import phc
from phc.analysis.matching import bipartite_matching, check_balance, perfect_without_search
from phc.frontend.elaborate import elaborate
from time_limits import SUBPROCESS_TIMEOUT

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_components import chain_yaml  # noqa: E402


def _where(lines: list[str], needle: str, value: str) -> tuple[int, int]:
    """(line, column), 1-based, of `value` after `needle` on the only line holding `needle`."""
    found = [i for i, line in enumerate(lines) if needle in line]
    assert len(found) == 1, needle
    line = lines[found[0]]
    return found[0] + 1, line.index(value, line.index(needle) + len(needle)) + 1


def test_errors_in_the_9000th_cell_are_reported_at_their_lines(tmp_path):
    cells, at = 9001, 9000
    text = chain_yaml(2 * cells + 1)
    planted = {  # line as generated -> line with the error
        f"  k{at}: {{type: spring, k: k, terminals: [a, b]}}": f"  k{at}: {{type: spring, k: m, terminals: [a, b]}}",
        f"  m{at}: {{type: mass, m: m, ports: [l, r]}}": f"  m{at}: {{type: mass, m: mm, ports: [l, r]}}",
        f"  - [k{at + 1}.b, m{at + 1}.l]": f"  - [k{at + 1}.b, m{at + 1}.q]",
    }
    for old, new in planted.items():
        assert text.count(old + "\n") == 1
        text = text.replace(old + "\n", new + "\n")
    path = tmp_path / "chain.yaml"
    path.write_text(text)
    lines = text.splitlines()
    dae, diags, _ = phc.validate_file(path)
    assert dae is None
    errors = {(d.code, d.span.line, d.span.col) for d in diags if d.severity == "error"}
    expected = {("PHC-E172", *_where(lines, f"k{at}: {{type: spring, k: ", "m")),
                ("PHC-E101", *_where(lines, f"m{at}: {{type: mass, m: ", "mm")),
                ("PHC-E201", *_where(lines, f"[k{at + 1}.b, ", f"m{at + 1}.q"))}
    assert errors == expected, [d.render() for d in diags]
    # as the user reads them: `file:line:col: ...`
    assert {d.render().split(": ", 1)[0] for d in diags if d.severity == "error"} == {
        f"{path}:{line}:{col}" for _, line, col in expected}
    # the positions are those of the planted cell, not of the template (k1, m1) or of a neighbour
    assert {line for _, line, _ in expected} == {i + 1 for i, line in enumerate(lines) if line in planted.values()}


def test_sympy_deduces_assumptions_a_bounded_number_of_times_whatever_the_chain(tmp_path, monkeypatch):
    """Symbols of the instances built from a template are real symbols equal to sympy's,
    made without its deduction: the count for 32, 64 and 128 cells is the same (the
    templates' own symbols, the parameters'), where it grew by 8 per cell."""
    real = sp.Symbol._canonical_assumptions
    calls = []

    def counting(**assumptions):
        calls.append(1)
        return real(**assumptions)

    monkeypatch.setattr(sp.Symbol, "_canonical_assumptions", staticmethod(counting))
    counts = {}
    for cells in (16, 32, 64, 128):  # the first pays what any first elaboration pays
        path = tmp_path / f"chain_{cells}.yaml"
        path.write_text(chain_yaml(2 * cells + 1))
        clear_cache()  # symbols made by an earlier size are not found in sympy's cache
        calls.clear()
        elab, diags = elaborate(path)
        assert elab is not None and not diags.has_errors
        counts[cells] = len(calls) if cells > 16 else None
        # and the instances' symbols are sympy's: equal, same hash, same assumptions
        last = next(v.symbol for v in elab.variables if v.name == f"k{cells}.x")
        assert last == sp.Symbol(f"k{cells}.x", real=True) and hash(last) == hash(sp.Symbol(f"k{cells}.x", real=True))
        assert last.assumptions0 == sp.Symbol("x", real=True).assumptions0 and last.is_real and last.is_positive is None
    assert counts[32] == counts[64] == counts[128], counts


def test_components_named_on_both_sides_of_a_parameter_share_two_templates(tmp_path, monkeypatch):
    """Springs `h1…h4` and `v1…v4` beside the parameter `k` (as the grid of
    bench_components.py names them): renaming `h1` to `v2` would move its names past `k`,
    so `v1` is lowered by its lowerer and kept as a second template; the other six are
    built, and the elaboration is the lowerers' own term by term. With one template per
    kind every `v` spring was lowered on its own (half the grid's validate)."""
    from test_component_sharing import _shared_and_alone

    lines = ["format_version: 1", "name: both_sides", "parameters:", "  k: {value: 100.0}", "components:"]
    lines += [f"  {side}{i}: {{type: spring, k: k, terminals: [a, b]}}" for side in "hv" for i in (1, 2, 3, 4)]
    path = tmp_path / "both_sides.yaml"
    path.write_text("\n".join(lines) + "\n")
    (diags, dump), (diags_alone, dump_alone), counts = _shared_and_alone(path, monkeypatch)
    assert dump is not None and diags == diags_alone and dump == dump_alone
    # v1 refused by h1's template, then a template itself; v2…v4 refused by h1's too (the
    # order of names, checked before anything is built), then built from v1's
    assert counts == {"built": 3 + 3, "refused": 1 + 3}


VALIDATE_NEVER = ("scipy", "phc.codegen.lower", "phc.codegen.printer", "phc.codegen.backends",
                  "phc.library.beams", "phc.discretize.fem1d", "phc.checks.certify")
"""What ``phc validate`` of a valid model of lumped components does not import: the code
generator's passes (validate stops at the assembled, matched system), scipy (its sparse
matrices belong to meshes, its maximum flow to models that no matching without search
pairs: :func:`phc.analysis.matching.perfect_without_search`), the distributed components'
modules and the certificate's."""


def test_validate_of_a_lumped_chain_loads_no_code_generator_and_no_scipy(tmp_path):
    """`phc validate` of a chain of springs and masses, in a fresh process: the model is
    valid (exit 0, its counts printed) and none of :data:`VALIDATE_NEVER` was imported.
    Fails where the validate path imports one of them at the top of a module."""
    path = tmp_path / "chain.yaml"
    path.write_text(chain_yaml(41))
    code = ("import sys\nfrom phc._entry import main\n"
            f"code = main(['validate', {str(path)!r}])\n"
            f"print(code, sorted(m for m in {VALIDATE_NEVER!r} if m in sys.modules))\n")
    env = dict(os.environ, PHC_CACHE_DIR=str(tmp_path / "cache"), PHC_STATE_DIR=str(tmp_path / "state"))
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         cwd=Path(__file__).resolve().parents[1], timeout=SUBPROCESS_TIMEOUT)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.strip().splitlines()
    assert lines[-2].endswith("chain.yaml: ok (40 states, 41 equations, 41 unknowns)"), run.stdout
    assert lines[-1] == "0 []", run.stdout + run.stderr[-2000:]


def _pattern(text: str) -> tuple[int, int, np.ndarray, np.ndarray]:
    """(rows, columns, row indices, column indices) of a 0/1 matrix written row by row."""
    a = np.array([[int(ch) for ch in line.split()] for line in text.strip().splitlines()])
    rows, cols = np.nonzero(a)
    return a.shape[0], a.shape[1], rows, cols


def test_a_matching_without_search_never_calls_a_singular_pattern_solvable():
    """On 3000 random square patterns (1 to 11 rows, densities 5–50 %), whenever
    :func:`perfect_without_search` says True the maximum matching (scipy's maximum flow) pairs
    every row: its True is a matching found, never a guess. (It may say False where a
    perfect matching exists; the check then searches: the next test.)"""
    rng = np.random.default_rng(38)
    solvable = found = 0
    for _ in range(3000):
        n = int(rng.integers(1, 12))
        a = (rng.random((n, n)) < rng.uniform(0.05, 0.5)).astype(np.int8)
        rows, cols = np.nonzero(a)
        perfect = bool(np.all(bipartite_matching(sps.csr_matrix(a)) >= 0))
        fast = perfect_without_search(n, n, rows, cols)
        assert perfect or not fast, a
        solvable, found = solvable + perfect, found + fast
    assert found > solvable / 2  # it does find most: otherwise it would only cost time


def test_a_wrong_guess_falls_back_to_the_search():
    """A pattern whose every row and column has two or more entries, so that the rule must
    guess: row 0 takes column 1, which rows 1 and 3 both need. The matching without search
    says False, and :func:`check_balance` of a system with this incidence still finds it
    solvable (no diagnostics) through the maximum matching; with a fifth unknown that no
    row holds it reports that unknown (PHC-E303)."""
    m, n, rows, cols = _pattern("""
        0 1 1 1
        1 1 0 0
        0 0 1 1
        1 1 0 0""")
    assert not perfect_without_search(m, n, rows, cols)
    assert np.all(bipartite_matching(sps.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, n))) >= 0)
    assert check_balance(_system(m, n, rows, cols)) == []
    codes = [d.code for d in check_balance(_system(m, n + 1, rows, cols))]
    assert codes == ["PHC-E303"], codes


def _system(m: int, n: int, rows, cols):
    """A stand-in for a :class:`phc.ir.dae.Dae` with `m` rows over `n` algebraic unknowns:
    row i is the sum of the unknowns its pattern entries name (what :func:`check_balance` reads)."""
    from types import SimpleNamespace

    from phc.ir.dae import Equation, Variable

    xs = [sp.Symbol(f"v{j}", real=True) for j in range(n)]
    variables = tuple(Variable(x.name, x, False, "effort", "c", None, None) for x in xs)
    equations = tuple(Equation(sp.Add(*[xs[j] for i2, j in zip(rows, cols) if i2 == i]), f"c.row[{i}]", "law", "c",
                               None) for i in range(m))
    return SimpleNamespace(variables=variables, equations=equations, linear_blocks=())


def test_the_stored_energy_is_the_sum_of_the_cells_energies_whenever_it_is_read(tmp_path):
    """Assembly leaves H unsummed until it is read (:class:`phc.ir.dae.TermSum`): what is
    read, directly, through ``dataclasses.replace``, a pickle or an output ``H``, is the sum
    of the cells' energies written here, and its unit, found from the terms, is J."""
    import dataclasses
    import pickle

    from phc.ir.dae import TermSum

    cells = 10
    text = chain_yaml(2 * cells + 1).replace("  outputs: {x1: k1.x}", "  outputs: {x1: k1.x, E: 2*H}")
    path = tmp_path / "chain.yaml"
    path.write_text(text)
    dae, diags, _ = phc.validate_file(path)
    assert dae is not None, [str(d) for d in diags]
    m, k = sp.Symbol("m", real=True), sp.Symbol("k", real=True)
    expected = sp.Add(*[k * sp.Symbol(f"k{i}.x", real=True) ** 2 / 2 + sp.Symbol(f"m{i}.p", real=True) ** 2 / (2 * m)
                        for i in range(1, cells + 1)])
    assert dict(dae.outputs)["E"] == 2 * expected  # an output reading H has the sum
    assert dae.units["H"] == "J"

    path.write_text(chain_yaml(2 * cells + 1))  # no output reads H: nothing sums it until read
    dae, _, _ = phc.validate_file(path)
    assert type(dae.__dict__["hamiltonian"]) is TermSum
    assert dae.units["H"] == "J"
    copied = dataclasses.replace(dae, name="copy")
    assert copied.hamiltonian == expected and dae.hamiltonian == expected
    assert type(dae.__dict__["hamiltonian"]) is not TermSum  # summed once, kept
    assert pickle.loads(pickle.dumps(dae)).hamiltonian == expected


def test_the_rows_free_symbols_are_found_once_and_are_each_rows_own(tmp_path):
    """:meth:`phc.ir.dae.Dae.row_symbols`, read by the budget's count of nonzeros and the
    structural check's incidence: each row's set is the one sympy finds in that row (the
    chain's rows written out here: a spring's ``der(k_i.x)`` reads the flows of its two
    masses), found once per system, not carried by a copy or a pickle."""
    import dataclasses
    import pickle

    from phc.analysis.matching import incidence

    cells = 4
    path = tmp_path / "chain.yaml"
    path.write_text(chain_yaml(2 * cells + 1))
    dae, diags, _ = phc.validate_file(path)
    assert dae is not None, [str(d) for d in diags]
    found = dae.row_symbols()
    assert len(found) == len(dae.equations)
    for eq, symbols in zip(dae.equations, found):
        assert symbols == (set() if eq.expr.is_Number else eq.expr.free_symbols), eq.label
    sym = {name: sp.Symbol(name, real=True) for name in ("der(k2.x)", "m1.p", "m2.p", "m")}
    spring = next(s for s in found if sym["der(k2.x)"] in s)
    assert spring == set(sym.values())  # der(k2.x) − m1.p/m + m2.p/m
    assert dae.row_symbols() is found  # kept
    assert "_row_symbols" not in dataclasses.replace(dae, name="copy").__dict__
    again = pickle.loads(pickle.dumps(dae))
    assert "_row_symbols" not in again.__dict__ and again.row_symbols() == found
    # the incidence is read from them: variable j in row i exactly where its symbol is there
    col = {s: j for j, v in enumerate(dae.variables) for s in (v.symbol, v.dsymbol) if s is not None}
    rows, cols = incidence(dae)
    assert sorted(zip(rows.tolist(), cols.tolist())) == sorted(
        {(i, col[s]) for i, eq in enumerate(dae.equations) for s in eq.expr.free_symbols if s in col})
