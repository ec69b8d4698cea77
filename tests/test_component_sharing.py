"""Many lumped components of the same kind: work done once per kind, not once per component
(issue 38), counted in operations, never in time — and every check as strong as before.

* ``phc check``'s rows check: components whose rows and description are the same systems
  up to names (the masses of a chain) share one lambdified function and one verdict; a
  component that differs (one wrong sign among a hundred identical springs) is still
  compared on its own and reported at its own position;
* the Dirac certificate: one Jacobian per distinct set of relations;
* the scaling's energy sizes: H evaluated for many perturbed states in one call;
* lowering: the coefficient of a solved variable taken without sympy's ``diff`` when the
  terms are plain products (the very expression ``diff`` gives);
* large model files are scanned and parsed by libyaml (when PyYAML has it) into the same
  nodes, data and positions as the pure-Python parser, and any problem is reported by the
  pure-Python parser with the same message.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sps
import pytest
import sympy as sp
import yaml

import phc
import phc.frontend.source
from phc.checks import rows as rows_module
from phc.checks.certify import certify
from phc.frontend.budget import derivative as _coefficient

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_components import chain_yaml  # noqa: E402


def _dae(tmp_path: Path, n: int):
    path = tmp_path / f"chain_{n}.yaml"
    path.write_text(chain_yaml(n))
    dae, diags, _ = phc.validate_file(path)
    assert dae is not None, [d.render() for d in diags]
    return dae


# ---------------------------------------------------------------------------------------
# the rows check


@pytest.fixture
def lambdified(monkeypatch):
    """Counts of the systems the rows check lambdifies, with its kept functions emptied."""
    calls = []
    real = sp.lambdify
    monkeypatch.setattr(rows_module, "_FUNCTIONS", {})
    monkeypatch.setattr(rows_module.sp, "lambdify", lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


@pytest.mark.parametrize("n", [11, 41])
def test_rows_check_lambdifies_each_kind_of_component_once(tmp_path, lambdified, n):
    cert = rows_module.check_rows(_dae(tmp_path, n))
    assert cert.ok and not cert.inconclusive and not cert.not_compared
    assert len(cert.compared) == n  # a wall, (n − 1)/2 springs and masses, the last mass with one port
    # wall, spring, inner mass, last mass: at most 2 systems each (rows, description)
    assert len(lambdified) <= 8
    # the first spring and the first inner mass are compared; every other one shares the verdict
    # (only the last mass, with one port, differs)
    assert cert.shared == n - 4


def test_rows_check_builds_the_systems_of_each_kind_once(tmp_path, monkeypatch):
    """Components equal up to the names of their own symbols are recognised before their
    systems are built: the systems of a chain are made once per kind of cell, not per cell."""
    built = []
    real = rows_module._prepare
    monkeypatch.setattr(rows_module, "_prepare", lambda *a, **k: built.append(a[1].component) or real(*a, **k))
    cert = rows_module.check_rows(_dae(tmp_path, 41))
    assert cert.ok and len(cert.compared) == 41 and cert.shared == 41 - 4
    assert len(built) == 4  # the wall, the first spring, the first inner mass, the last mass


def test_rows_check_does_not_share_across_different_parameters(tmp_path):
    """Springs alike but for the parameter they read are different systems: a verdict is
    shared only between components whose rows name the same symbols outside their own."""
    text = chain_yaml(9)
    assert "  k3: {type: spring, k: k," in text
    text = text.replace("  k3: {type: spring, k: k,", "  k3: {type: spring, k: k_other,")
    text = text.replace("parameters:\n", "parameters:\n  k_other: {value: 30.0, unit: N/m}\n", 1)
    path = tmp_path / "two_k.yaml"
    path.write_text(text)
    dae, diags, _ = phc.validate_file(path)
    assert dae is not None, [d.render() for d in diags]
    cert = rows_module.check_rows(dae)
    assert cert.ok and len(cert.compared) == 9
    # compared on their own: the wall, k1, m1, k3 (k_other) and the last mass m4; k2 and k4
    # share k1's verdict, m2 and m3 share m1's
    assert cert.shared == 4


def test_placeholders_are_the_symbols_sympy_makes_and_keep_assumptions_apart():
    """The canonical keys' placeholders are made once (rows check and Dirac certificate):
    each is equal to the symbol made afresh, and a variable with other assumptions gets
    another placeholder (a derivative of |x| depends on them, so such components must not
    share a key)."""
    real, positive = sp.Symbol("x", real=True), sp.Symbol("y", positive=True)
    a = rows_module.placeholder("phc own 0", frozenset(real.assumptions0.items()))
    assert a == sp.Symbol("phc own 0", **real.assumptions0) and a.assumptions0 == real.assumptions0
    assert a is rows_module.placeholder("phc own 0", frozenset(real.assumptions0.items()))
    b = rows_module.placeholder("phc own 0", frozenset(positive.assumptions0.items()))
    assert b != a and b.is_positive and a.is_positive is None


def test_a_component_unlike_its_neighbours_is_compared_on_its_own(tmp_path):
    """One spring among 20 with a sign flipped in its rows: found and located at it, although
    20 other springs passed the same (up to names) comparison before and after it."""
    import dataclasses

    dae = _dae(tmp_path, 41)
    top = dae.topology
    victim = "k7"
    rows = []
    for r in top.rows:
        if r.component == victim:
            (label, expr), *rest = r.equations
            r = dataclasses.replace(r, equations=((label, -expr + 2 * sorted(expr.free_symbols, key=str)[0]),
                                                  *rest))
        rows.append(r)
    dae = dataclasses.replace(dae, topology=dataclasses.replace(top, rows=tuple(rows)))
    cert = rows_module.check_rows(dae)
    assert [d.code for d in cert.diagnostics] == ["PHC-E452"]
    assert f"`{victim}`" in cert.diagnostics[0].message
    spans = {name: span for name, _, span in top.components}
    assert cert.diagnostics[0].span == spans[victim]
    assert victim not in cert.compared and len(cert.compared) == 40


# ---------------------------------------------------------------------------------------
# the Dirac certificate


def test_dirac_certificate_takes_one_jacobian_per_kind(tmp_path, monkeypatch):
    calls = []
    real = sp.Matrix.jacobian
    monkeypatch.setattr(sp.MatrixBase, "jacobian", lambda self, *a, **k: calls.append(1) or real(self, *a, **k))
    monkeypatch.setattr(rows_module, "check_rows", lambda *a, **k: rows_module.RowsCertificate())
    dae = _dae(tmp_path, 41)
    cert = certify(dae)
    assert cert.certified, cert.render_text()
    assert len(calls) <= 4  # wall, spring, inner mass, last mass
    # the same result as each component on its own: a Dirac structure of its dimension
    for c in cert.components:
        if c.dirac is not None:
            assert c.dirac and c.dim_d == c.dim_z and c.isotropy <= 1e-12, c


@pytest.mark.parametrize("rank_deficient", [False, True])
def test_constant_structures_are_certified_once_with_the_same_result(tmp_path, monkeypatch, rank_deficient):
    """Structures with no state and no time (every cell of a chain) are projected once and
    their couplings ranked at one sample: the certificate is the one every sample gives when
    each is computed (the shortcut switched off), a failing connection included."""
    from phc.checks import certify as certify_module

    dae = _dae(tmp_path, 21)
    if rank_deficient:  # besides the chain, two zero-flow sources joined: Γ has rank 1 of 2
        text = chain_yaml(21).replace("connections:\n", "  far: {type: zero_flow, domain: mechanical.translational}\n"
                                      "  far2: {type: zero_flow, domain: mechanical.translational}\n"
                                      "connections:\n  - [far.port, far2.port]\n", 1)
        path = tmp_path / "walls.yaml"
        path.write_text(text)
        from phc.pipeline import elaborate_file

        dae, _ = elaborate_file(path)  # before the structural check, which refuses the joined sources
        assert dae is not None
    monkeypatch.setattr(rows_module, "check_rows", lambda *a, **k: rows_module.RowsCertificate())
    fast = certify(dae, n_random=3)
    monkeypatch.setattr(certify_module._Component, "is_constant", property(lambda self: False))
    slow = certify(dae, n_random=3)

    def summary(cert):
        return ([(c.label, c.achieved, c.needed, c.conditioning, c.failing_samples) for c in cert.connections],
                [(c.name, c.dirac, c.dim_d, c.isotropy) for c in cert.components])

    assert summary(fast) == summary(slow)
    assert fast.certified is (not rank_deficient)
    if rank_deficient:
        failing = [c for c in fast.connections if not c.surjective]
        assert failing and all(len(c.failing_samples) == 4 for c in failing)  # the initial state + 3


# ---------------------------------------------------------------------------------------
# the energy sizes of the scaling


class _Springs:
    """A module of n decoupled springs: H = Σ ½ k_j y_j², straight-line NumPy as generated."""

    def __init__(self, k):
        self.k = np.asarray(k, dtype=float)
        self.N = len(k)
        self.DIFFERENTIAL = [True] * len(k)
        self.VARIABLES = [f"s{j}.x" for j in range(len(k))]
        self.calls = 0

    def hamiltonian(self, t, y, p):
        self.calls += 1
        H = 0.0
        for j in range(self.N):
            H = H + 0.5 * self.k[j] * y[j] ** 2
        return H


@pytest.mark.parametrize("n", [50, 400])
def test_energy_sizes_evaluate_h_a_bounded_number_of_times(n):
    from phc.simulation.energy_sizes import energy_sizes

    rng = np.random.default_rng(1)
    mod = _Springs(rng.uniform(1.0, 1e4, n))
    y0 = rng.normal(size=n)
    E = 2.0
    sizes = energy_sizes(mod, None, 0.0, y0, np.abs(y0), E)
    # closed form: ½ k s² = E; central differences are exact for a quadratic up to round-off
    np.testing.assert_allclose(sizes, np.sqrt(2 * E / mod.k), rtol=1e-7)
    # h0, one batch each way, and two single calls per batch to check it: not one per variable
    assert mod.calls <= 1 + 2 * 3


class _ScalarSprings(_Springs):
    """The springs with an H that takes one state at a time (as a NumPy module's H with math.sin)."""

    def hamiltonian(self, t, y, p):
        if np.ndim(y) != 1:
            raise TypeError("one state at a time")
        return super().hamiltonian(t, y, p)


def test_energy_sizes_fall_back_to_single_calls_for_a_scalar_only_h():
    from phc.simulation.energy_sizes import energy_sizes

    k = np.array([1.0, 4.0, 9.0])
    mod = _ScalarSprings(k)
    sizes = energy_sizes(mod, None, 0.0, np.ones(3), np.ones(3), 0.5)
    np.testing.assert_allclose(sizes, np.sqrt(1.0 / k), rtol=1e-7)


class _Forms(_Springs):
    """A module whose H is what the NumPy back end generates for distributed components:
    sparse quadratic forms ``c · y[C] @ (Q @ y[C])`` of index blocks, plus a straight-line
    term ``½ k y_0²`` (a spring at the end)."""

    def __init__(self, n, repeat=False):
        rng = np.random.default_rng(2)
        super().__init__(np.ones(n))
        half = (n - 1) // 2
        self.blocks = []
        for cols in (np.arange(1, 1 + half), np.arange(1 + half, n)):
            m = len(cols)
            # a symmetric positive definite tridiagonal matrix (a mass or stiffness matrix)
            d = rng.uniform(2.0, 4.0, m)
            Q = sps.diags([d, -np.ones(m - 1), -np.ones(m - 1)], [0, -1, 1], format="csr")
            self.blocks.append((rng.uniform(0.5, 2.0), Q, cols))
        if repeat:  # an index block that names a state twice: not what the lazy columns take
            c, Q, cols = self.blocks[0]
            self.blocks[0] = (c, sps.csr_matrix(sps.block_diag([Q, sps.eye(1)])), np.append(cols, cols[0]))
        self.k0 = 5.0

    def hamiltonian(self, t, y, p):
        self.calls += 1
        H = 0
        H += 0.5 * self.k0 * y[0] ** 2
        for c, Q, cols in self.blocks:
            H += c * (y[cols] @ (Q @ y[cols]))
        return H

    def curvature(self):
        """∂²H/∂y_j² in closed form: k₀, then 2 c Q_jj summed over the positions of state j."""
        out = np.zeros(self.N)
        out[0] = self.k0
        for c, Q, cols in self.blocks:
            np.add.at(out, cols, 2 * c * Q.diagonal())  # a repeated state: each of its diagonal entries
        return out


@pytest.mark.parametrize("n", [41, 3001])
def test_energy_sizes_of_sparse_quadratic_forms_take_one_batched_call_each_way(n, monkeypatch):
    """The generated H of a string or a beam (sparse forms of index blocks) is evaluated for all
    perturbed states at once, without a matrix of states (:class:`phc.simulation.energy_sizes.
    _OneEntryColumns`): the sizes are the closed form's, with a bounded number of calls (the
    small size with the lazy columns switched on from the first entry)."""
    from phc.simulation import energy_sizes as module
    from phc.simulation.energy_sizes import energy_sizes

    monkeypatch.setattr(module, "LAZY_MIN_ENTRIES", 0)

    mod = _Forms(n)
    rng = np.random.default_rng(3)
    y0 = rng.normal(size=n)
    E = 3.0
    sizes = energy_sizes(mod, None, 0.0, y0, np.maximum(np.abs(y0), 1.0), E)
    # central differences are exact for a quadratic up to round-off: H ≲ 1e4 differenced over
    # steps of at least 1 (the scales given) leaves ~1e-12 of a curvature ≥ 1
    np.testing.assert_allclose(sizes, np.sqrt(2 * E / mod.curvature()), rtol=1e-7)
    # h0, one batched call each way, and two single calls each to check it
    assert mod.calls <= 1 + 2 * 3


def test_energy_sizes_of_a_block_naming_a_state_twice_fall_back():
    """A repeated index is not taken by the lazy columns (their blocks assume distinct
    states): the other ways give the same closed-form sizes."""
    from phc.simulation.energy_sizes import energy_sizes

    mod = _Forms(41, repeat=True)
    y0 = np.random.default_rng(4).normal(size=41)
    curv = mod.curvature()  # the repeated state's two positions are not coupled in Q (block diagonal)
    sizes = energy_sizes(mod, None, 0.0, y0, np.maximum(np.abs(y0), 1.0), 3.0)  # steps ≥ 1: round-off as above
    np.testing.assert_allclose(sizes, np.sqrt(6.0 / curv), rtol=1e-7)


# ---------------------------------------------------------------------------------------
# the coefficient of a solved variable


def test_coefficient_is_the_expression_diff_gives():
    x, y, k, m, c = sp.symbols("x y k m c", real=True)
    f = sp.Function("f")
    for expr in (x, -x, 2 * x, k * x, -k * x / m + y, k * x + c * x + y, y - x * k * m, x * y + x,
                 sp.sin(y) * x - c, x ** 2 + y, sp.sin(x) * k, (x + 1) * k, f(x) + x, y, sp.Integer(0),
                 x / m - c * y * x):
        assert _coefficient(expr, x) == sp.diff(expr, x), expr
        assert sp.srepr(_coefficient(expr, x)) == sp.srepr(sp.diff(expr, x)), expr


# ---------------------------------------------------------------------------------------
# large files: libyaml's events, PyYAML's nodes

libyaml = pytest.mark.skipif(not phc.frontend.source._LIBYAML, reason="PyYAML without libyaml")


def _big(text: str) -> str:
    """`text` followed by enough comment lines to take the fast path."""
    pad = "# " + "x" * 78 + "\n"
    return text + pad * (phc.frontend.source.FAST_MIN_CHARS // len(pad) + 1)


def _both(text: str, monkeypatch):
    fast = phc.frontend.source.load_yaml(text, "m.yaml")
    monkeypatch.setattr(phc.frontend.source, "FAST_MIN_CHARS", 10 ** 12)
    slow = phc.frontend.source.load_yaml(text, "m.yaml")
    monkeypatch.undo()
    return fast, slow


def _walk(node, path=()):
    yield path, node
    if isinstance(node, yaml.MappingNode):
        for i, (k, v) in enumerate(node.value):
            yield from _walk(k, (*path, i, "k"))
            yield from _walk(v, (*path, i, "v"))
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            yield from _walk(v, (*path, i))


@libyaml
def test_large_file_same_nodes_data_and_positions(tmp_path, monkeypatch):
    text = _big(chain_yaml(301) + "notes:\n  é: \"ünïcode ✓ 😀\"\n  multi: |\n    line one\n    line two\n"
                "  folded: >-\n    a\n    b\n  quoted: 'it''s'\n  anchors: {a: &A [1, 2.5, true, null, 0x1F], b: *A}\n"
                "  flow: {x: [1, {y: 2}], z: ~}\n  crlf: [1, 2]\r\n  date: 2024-01-02\n")
    calls = []
    real = yaml.SafeLoader

    def counting(text, *rest):  # the pure-Python parser on the text (not on "" for its resolver)
        if text:
            calls.append(1)
        return real(text, *rest)

    monkeypatch.setattr(phc.frontend.source.yaml, "SafeLoader", counting)
    (d1, m1, g1), (d2, m2, g2) = _both(text, monkeypatch)
    assert calls == [1]  # the second parse only: the first was libyaml's
    assert g1 == g2 == [] and d1 == d2
    nodes1, nodes2 = list(_walk(m1.root)), list(_walk(m2.root))
    assert len(nodes1) == len(nodes2) > 2000
    for (p1, a), (p2, b) in zip(nodes1, nodes2):
        assert p1 == p2 and type(a) is type(b) and a.tag == b.tag, p1
        assert (getattr(a, "style", None) or None) == (getattr(b, "style", None) or None), p1
        if isinstance(a, yaml.ScalarNode):
            assert a.value == b.value
        assert m1._node_span(a) == m2._node_span(b), p1
    assert m1.node(("notes", "anchors", "b")) is m1.node(("notes", "anchors", "a"))  # an alias: one node
    for path, offset in ((("notes", "multi"), 12), (("notes", "folded"), 2), (("notes", "é"), 4),
                         (("components", "m77", "ports", 1), 0), (("connections", 5, 1), 3)):
        assert m1.locate_in_value(path, offset) == m2.locate_in_value(path, offset), path
        assert m1.locate_key(path) == m2.locate_key(path), path


@libyaml
@pytest.mark.parametrize("problem", [
    "a: 1\na: 2\n",                      # duplicate key (a diagnostic; the data is built)
    "a: [1, 2\n",                         # syntax error
    "a: *nowhere\n",                      # undefined alias
    "a: &x 1\nb: &x 2\n",                 # duplicate anchor
    "a: 1\n---\nb: 2\n",                  # two documents
    "a:\n\t- 1\n",                        # a tab
    "a: !!python/object:os.system x\n",   # unsafe tag
    "a: \x07\n",                          # a control character
    "- " * 3000 + "x\n",                 # nested very deeply (block lists)
    # the checks the composition of a large file makes itself, or leaves to _Checker
    "a: {b: 1, c: 2, b: 3}\n",          # duplicate key inside a nested mapping
    "1: a\n0x1: b\n",                    # two integer keys of one value
    "? [a, b]\n: 1\n",                   # a list as a key
    "a: !!binary aGk=\n",                # a tag SafeLoader knows but a model does not take
    "a: !custom x\n",                    # an unknown tag
    "a: &x [1]\nb: *x\nc: {d: 1, d: 2}\n",  # an alias, then a duplicate
])
def test_large_file_problems_are_reported_as_by_the_pure_python_parser(problem, monkeypatch):
    text = _big("") + problem  # the problem at the end, after the padding
    (d1, m1, g1), (d2, m2, g2) = _both(text, monkeypatch)
    assert g1 and [(d.code, d.message, d.span) for d in g1] == [(d.code, d.message, d.span) for d in g2]
    assert d1 == d2


@libyaml
@pytest.mark.parametrize("clean", [
    "a: 1\nb: {c: [1, 2], d: x}\n",       # plain: no walk of _Checker
    "b: &x {c: 1}\nd: {<<: *x, e: 2}\n",  # a merge key and an alias: _Checker walks it
    "1: a\n2: b\n",                      # integer keys: _Checker compares their values
])
def test_large_plain_file_is_not_walked_twice_and_loads_alike(clean, monkeypatch):
    """Counted, not timed (issue 38): a large file of safe tags and string keys, none twice,
    without aliases, is checked while it is composed: ``_Checker`` does not walk it again.
    Its data, positions and diagnostics are those of the pure-Python parser's path."""
    walks = []
    real = phc.frontend.source._Checker.visit

    def counting(self, node):
        walks.append(1)
        return real(self, node)

    monkeypatch.setattr(phc.frontend.source._Checker, "visit", counting)
    text = _big(chain_yaml(41) + clean)
    fast = phc.frontend.source.load_yaml(text, "m.yaml")
    walked = bool(walks)
    monkeypatch.setattr(phc.frontend.source, "FAST_MIN_CHARS", 10 ** 12)
    slow = phc.frontend.source.load_yaml(text, "m.yaml")
    assert fast[0] == slow[0] and fast[2] == slow[2] == []
    assert [fast[1]._node_span(n) for _, n in _walk(fast[1].root)] == [
        slow[1]._node_span(n) for _, n in _walk(slow[1].root)]
    assert walked == (not clean.startswith("a: 1")), clean


def test_without_libyaml_a_large_file_is_parsed_in_python_and_said_once(monkeypatch):
    import warnings

    monkeypatch.setattr(phc.frontend.source, "_LIBYAML", False)
    monkeypatch.setattr(phc.frontend.source, "_SLOW_SAID", False)
    text = _big("a: 1\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        first = phc.frontend.source.load_yaml(text, "m.yaml")
        second = phc.frontend.source.load_yaml(text, "m.yaml")
    assert first[0] == second[0] == {"a": 1} and not first[2]
    said = [w for w in caught if issubclass(w.category, phc.PhcWarning)]
    assert len(said) == 1 and "libyaml" in str(said[0].message)


# ---------------------------------------------------------------------------------------
# lowering: identical components lowered once, the others renamed


def _elaboration_dump(value):
    """Everything an elaboration holds, in order, sympy expressions as their full tree
    (``srepr``: the order of a sum's terms included), so that two elaborations compare
    equal only when they are the same term by term."""
    import dataclasses

    if isinstance(value, sp.Basic):
        return ("sympy", sp.srepr(value))
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, [_elaboration_dump(x) for x in value])
    if isinstance(value, (set, frozenset)):
        return ("set", sorted(repr(_elaboration_dump(x)) for x in value))
    if hasattr(value, "items"):
        return ("map", [(_elaboration_dump(k), _elaboration_dump(x)) for k, x in value.items()])
    if dataclasses.is_dataclass(value):
        return (type(value).__name__, [(f.name, _elaboration_dump(getattr(value, f.name)))
                                       for f in dataclasses.fields(value)])
    return repr(value)


def _shared_and_alone(path, monkeypatch):
    """(diagnostics, dump, instances built, instances refused) of `path` elaborated with
    shared lowerings, then (diagnostics, dump) with every component lowered by its lowerer."""
    import dataclasses

    import phc.frontend.lowering as lowering_module
    from phc.frontend.elaborate import elaborate

    counts = {"built": 0, "refused": 0}
    real = lowering_module._Template.build

    def build(self, new, spans):
        out = real(self, new, spans)
        counts["built" if out is not None else "refused"] += 1
        return out

    monkeypatch.setattr(lowering_module._Template, "build", build)

    def run():
        elab, diags = elaborate(path)
        dump = None if elab is None else {f.name: _elaboration_dump(getattr(elab, f.name))
                                          for f in dataclasses.fields(elab)
                                          if f.name not in ("top", "files", "scene", "sources")}
        return [d.render() for d in diags], dump

    shared = run()
    monkeypatch.setattr(lowering_module, "SHAREABLE_TYPES", frozenset())
    alone = run()
    return shared, alone, counts


def test_shared_lowerings_are_the_lowerers_own_term_by_term(tmp_path, monkeypatch):
    """Masses, springs, dampers (terminals and ports, scalar and 2-D), capacitors,
    inductors and resistors, three of each kind: every variable, row, port, description,
    energy and dissipation term is what each component's own lowering gives, in the same
    order; the components named so that renaming would move their names past the
    parameter `m` (`a…` to `z…`) are lowered on their own."""
    lines = ["format_version: 1", "name: kinds", "parameters:", "  m: {value: 1.0}", "  k: {value: 100.0}",
             "  d: {value: 0.5}", "  C: {value: 1.0e-3}", "  L: {value: 2.0e-3}", "  R: {value: 10.0}",
             "components:"]
    for i in (1, 2, 3):
        lines += [f"  m{i}: {{type: mass, m: 2*m, ports: [l, r]}}",
                  f"  k{i}: {{type: spring, k: k, terminals: [a, b]}}",
                  f"  d{i}: {{type: damper, d: d + 1, terminals: [a, b]}}",
                  f"  v{i}: {{type: mass, m: m, dimension: 2}}",
                  f"  s{i}: {{type: spring, k: k/2, dimension: 2}}",
                  f"  c{i}: {{type: capacitor, C: C, terminals: [p, n]}}",
                  f"  l{i}: {{type: inductor, L: L}}",
                  f"  r{i}: {{type: resistor, R: R, terminals: [p, n]}}"]
    lines += ["  a1: {type: spring, k: m}", "  z1: {type: spring, k: m}"]
    path = tmp_path / "kinds.yaml"
    path.write_text("\n".join(lines) + "\n")
    (diags, dump), (diags_alone, dump_alone), counts = _shared_and_alone(path, monkeypatch)
    assert dump is not None and diags == diags_alone
    assert dump == dump_alone
    assert counts == {"built": 2 * 8, "refused": 1}  # z1 after a1: `z1.x` > `m` > `a1.x`


def test_components_with_problems_are_each_lowered_and_reported(tmp_path, monkeypatch):
    """A kind whose first component has an error is never shared: each of its components
    reports the error at its own line, as without sharing."""
    lines = ["format_version: 1", "name: bad", "parameters:", "  k: {value: -1.0}", "components:"]
    lines += [f"  k{i}: {{type: spring, k: k}}" for i in (1, 2, 3)]
    path = tmp_path / "bad.yaml"
    path.write_text("\n".join(lines) + "\n")
    (diags, _), (diags_alone, _), counts = _shared_and_alone(path, monkeypatch)
    assert diags == diags_alone and counts == {"built": 0, "refused": 0}
    assert [d.split(":")[1] for d in diags if "PHC-E405" in d] == ["6", "7", "8"]


def test_a_chain_shares_its_lowerings_and_validates_as_before(tmp_path, monkeypatch):
    """The benchmark's chain: one lowering per kind, the rest renamed, the same elaboration."""
    path = tmp_path / "chain.yaml"
    path.write_text(chain_yaml(41))
    (diags, dump), (diags_alone, dump_alone), counts = _shared_and_alone(path, monkeypatch)
    assert diags == diags_alone and dump == dump_alone
    # 20 springs and 20 masses; the last mass has one port; k1 and m1 are the templates
    assert counts == {"built": 19 + 18, "refused": 0}


def test_sharing_survives_a_cleared_sympy_cache(tmp_path, monkeypatch):
    """After sympy's cache was cleared, symbols phc made before (still held) and after are
    distinct objects of one name; the shared lowering counts names, so the chain is shared
    as in a fresh process (counted twice, every mass was refused: 18 instances lowered on
    their own — the full suite failed this file's chain test after
    tests/test_component_scaling.py on one worker)."""
    from sympy.core.cache import clear_cache

    import test_component_scaling as scaling

    # what tests/test_component_scaling.py does before this file on one worker: it clears
    # sympy's cache before each size it measures (after it, 18 of 19 masses were refused)
    scaling.test_front_end_work_is_linear_in_components(tmp_path)
    path = tmp_path / "chain.yaml"
    path.write_text(chain_yaml(41))
    (diags, dump), (diags_alone, dump_alone), counts = _shared_and_alone(path, monkeypatch)
    assert diags == diags_alone and dump == dump_alone
    assert counts == {"built": 19 + 18, "refused": 0}


def test_energy_sizes_of_a_guarded_module_call_its_own_h_and_the_guard_only_where_that_fails():
    """Single calls go to the module's own H (the guard costs tens of µs a call); a value that
    is not finite goes to the guarded H, which decides (here: a ModelEvaluationError, so no sizes)."""
    from phc.simulation.energy_sizes import energy_sizes
    from phc.simulation.guard import GuardedModule

    k = np.array([1.0, 4.0, 9.0])
    raw = _ScalarSprings(k)
    guarded = GuardedModule(raw)
    through_guard = []
    wrapped = guarded.hamiltonian
    guarded.hamiltonian = lambda t, y, p: through_guard.append(np.ndim(y)) or wrapped(t, y, p)
    sizes = energy_sizes(guarded, None, 0.0, np.ones(3), np.ones(3), 0.5)
    np.testing.assert_allclose(sizes, np.sqrt(1.0 / k), rtol=1e-7)  # ½ k s² = E, as above
    # one state through the guard: H at the start only (the others: the batch it refuses), every
    # perturbed state by the module's own H
    assert through_guard.count(1) == 1

    class Pole(_ScalarSprings):  # H not finite once y_0 moves up: the guard's verdict
        def hamiltonian(self, t, y, p):
            return super().hamiltonian(t, y, p) + (np.inf if y[0] > 1.0 else 0.0)

    guarded = GuardedModule(Pole(k))
    assert not energy_sizes(guarded, None, 0.0, np.ones(3), np.ones(3), 0.5).any()


def test_energy_sizes_of_a_c_module_take_the_later_rounds_from_one_call_and_read_only_what_a_round_needs(
        monkeypatch):
    """On the C back end the rounds after the first come from one call of the step library at every
    step a variable may still need (phc.simulation.energy_sizes._c_ahead); a value there that is not
    finite goes to the guarded H only where a round reads it, so the sizes and the guard's verdicts
    are those of one round at a time (here: single calls, with the library not at hand)."""
    from phc.codegen import c_steps
    from phc.simulation.energy_sizes import energy_sizes
    from phc.simulation.guard import GuardedModule

    class Fake:
        """H = ½ y0² + 9.81 y1 + c y2²: y0 curved at the first step, y1 linear (every round), y2
        curved only at the second step (2c below H's round-off at a unit step), and no value once
        y2 passes 1e7 (steps 1e9 and more, which only the rounds after y2's own are at)."""
        BACKEND, N, DIFFERENTIAL, VARIABLES = "c", 3, [True] * 3, ["a.x", "b.x", "c.x"]
        c, pole = 1e-13, (2, 1e7)

        def hamiltonian(self, t, y, p):
            j, at = self.pole
            return 0.5 * y[0] ** 2 + 9.81 * y[1] + self.c * y[2] ** 2 + (np.inf if y[j] > at else 0.0)

    calls = []

    def along(raw, p, t, Y, Yp, only_h=False):  # the step library: one value per state, as single calls
        calls.append(len(t))
        return {"H": np.array([raw.hamiltonian(0.0, y, p) for y in Y])}

    def run(raw, batched):
        guarded, through_guard = GuardedModule(raw), []
        wrapped = guarded.hamiltonian
        guarded.hamiltonian = lambda t, y, p: through_guard.append(1) or wrapped(t, y, p)
        monkeypatch.setattr(c_steps, "along", along if batched else (lambda *a, **k: None))
        return energy_sizes(guarded, None, 0.0, np.ones(3), np.ones(3), 0.5), len(through_guard)

    raw = Fake()
    sizes, guard_calls = run(raw, True)
    # the first round: ±1 for the three states; then rounds 2..8 at ±1e3…±1e21 for y1 and y2
    assert calls == [2 * 3, 2 * 7 * 2]
    single, single_guard_calls = run(raw, False)
    assert np.array_equal(sizes, single)
    assert guard_calls == single_guard_calls == 1  # H at the start: no perturbed state reaches the guard
    # ½ k s² = E with k = 1 and k = 2c (the second difference at step 1e3 is exact to ~1e-15/1e-7)
    np.testing.assert_allclose(sizes, [1.0, 0.0, np.sqrt(0.5 / raw.c)], rtol=1e-6)

    raw.pole = (1, 1e5)  # y1 has no value at its third step (1e6): the guard's verdict, no sizes, both ways
    calls.clear()
    sizes, _ = run(raw, True)
    assert not sizes.any() and calls == [6, 28]
    assert not run(raw, False)[0].any()


@libyaml
def test_plain_large_file_is_built_as_the_general_builder_builds_it(monkeypatch):
    """A plain document (no alias, string keys, none twice) is built by ``build_plain``,
    without the memo of shared nodes: the same data and the same diagnostics as
    ``_Builder.build``, for every kind of scalar, the tagged collections that ``build``
    hands to PyYAML's constructor, and a value that cannot be built (issue 38)."""
    text = _big(chain_yaml(41) + "extra:\n  i: 0x1F\n  f: 2.5e-3\n  b: [on, false]\n  n: ~\n"
                "  d: 2024-01-02\n  q: '007'\n  o: !!omap [{a: 1}, {b: 2}]\n  s: !!set {x, y}\n"
                "  p: !!pairs [{a: 1}]\n  bad: !!int twelve\n  nested: {a: [[1, {b: c}]]}\n")
    ok, root, plain = phc.frontend.source._fast_compose(text)
    assert ok and plain is not None  # the composition found it plain
    general = phc.frontend.source._Builder("m.yaml")
    fast = phc.frontend.source._Builder("m.yaml")
    data = general.build(root)
    assert fast.build_plain(root) == data
    assert data["extra"]["i"] == 31 and data["extra"]["b"] == [True, False] and data["extra"]["q"] == "007"
    assert data["extra"]["bad"] is None and data["extra"]["nested"] == {"a": [[1, {"b": "c"}]]}
    assert [(d.code, d.message, d.span) for d in fast.diags] == [(d.code, d.message, d.span) for d in general.diags]
    assert [d.span.line for d in general.diags] == [text.splitlines().index("  bad: !!int twelve") + 1]
    used = []
    monkeypatch.setattr(phc.frontend.source._Builder, "build_plain",
                        lambda self, node: used.append(1) or phc.frontend.source._Builder.build(self, node))
    phc.frontend.source.load_yaml(text, "m.yaml")
    assert used == [1]  # load_yaml took the plain builder
