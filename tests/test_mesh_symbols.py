"""The unknowns of a mesh are made without sympy's per-symbol work (issue 35).

A distributed component of n elements has a few n states, rates and co-energies. They are
sympy symbols (the rows, the description and the printer read them as such), made by
:func:`phc.ir.dae.real_symbol`: equal to ``sp.Symbol(name, real=True)``, hashing alike,
answering every assumption query alike, but sharing one table of deduced facts instead of
running sympy's assumption system once per symbol. Counted, never timed: the calls of
sympy's ``Symbol`` constructor while a mesh is assembled do not grow with its elements.
"""

from __future__ import annotations

import pickle

import pytest
import sympy as sp

from phc.ir.dae import real_symbol
from phc.pipeline import build_dae

STRING = """format_version: 1
name: string{n}
components:
  s: {{type: string, length: 1, elements: {n}, rho: 1, T: 1}}
  wall: {{type: zero_flow, domain: mechanical.translational}}
  free: {{type: zero_effort, domain: mechanical.translational}}
connections:
  - [s.a, wall.port]
  - [s.b, free.port]
"""

BEAM = """format_version: 1
name: beam{n}
components:
  beam: {{type: euler_bernoulli_beam, length: 0.3, elements: {n}, rhoA: 0.5, EI: 68.0}}
  clamp: {{type: zero_flow, domain: mechanical.translational}}
  clamp_rot: {{type: zero_flow, domain: mechanical.rotational}}
  free: {{type: zero_effort, domain: mechanical.translational}}
  free_rot: {{type: zero_effort, domain: mechanical.rotational}}
connections:
  - [beam.a, clamp.port]
  - [beam.a_rot, clamp_rot.port]
  - [beam.b, free.port]
  - [beam.b_rot, free_rot.port]
"""

QUERIES = ("real", "extended_real", "complex", "imaginary", "finite", "infinite", "positive", "negative",
           "nonnegative", "nonzero", "zero", "integer", "rational", "commutative", "hermitian", "algebraic")


def _symbols_made(monkeypatch, path) -> tuple[int, object]:
    """Calls of sympy's ``Symbol(...)`` while `path` is assembled, and the assembled system."""
    calls = [0]
    original = sp.Symbol.__new__

    def counting(cls, *args, **kwargs):
        calls[0] += 1
        return original(cls, *args, **kwargs)

    monkeypatch.setattr(sp.Symbol, "__new__", counting)
    dae, diags = build_dae(path)
    monkeypatch.setattr(sp.Symbol, "__new__", original)
    assert dae is not None, [str(d) for d in diags.errors]
    return calls[0], dae


@pytest.mark.parametrize("text, per_element", [(STRING, 6), (BEAM, 12)])
def test_sympy_symbols_made_do_not_grow_with_the_elements(tmp_path, monkeypatch, text, per_element):
    """From 40 to 400 elements the unknowns grow by 360 · (unknowns per element) — P1/P0
    string: a state, its rate and a co-energy at each node and cell (6 symbols an element);
    Hermite/DP1 beam: 2 Hermite DOFs a node and 2 DP1 DOFs a cell (12) — and sympy's
    constructor is called a fixed number of times more (the rows and the description use
    those symbols; none is made per unknown). The old lowering called it once per symbol."""
    counts, sizes = [], []
    for n in (40, 400):
        path = tmp_path / f"m{n}.yaml"
        path.write_text(text.format(n=n))
        made, dae = _symbols_made(monkeypatch, path)
        counts.append(made)
        sizes.append(len(dae.variables))
    assert sizes[1] - sizes[0] >= 360 * per_element // 3  # the mesh did grow (3 symbols per state)
    assert counts[1] - counts[0] < 36, counts  # < 0.1 per element; the old code made > 6 per element


def test_mesh_unknowns_are_sympys_real_symbols(tmp_path):
    """Each variable of an assembled mesh is equal to, and hashes like, the symbol sympy makes
    for its name with ``real=True`` (so a lookup by either finds the other); the rates too."""
    path = tmp_path / "s.yaml"
    path.write_text(STRING.format(n=8))
    dae, _ = build_dae(path)
    for v in dae.variables:
        for sym, name in ((v.symbol, v.name), (v.dsymbol, f"der({v.name})")):
            if sym is None:
                continue
            ref = sp.Symbol(name, real=True)
            assert sym == ref and hash(sym) == hash(ref) and {sym: 1}[ref] == 1
            assert sym != sp.Symbol(name)  # the assumption is part of the identity, as in sympy


def test_real_symbol_answers_every_assumption_like_sympy():
    """Every fact sympy derives for ``Symbol(name, real=True)`` (queried on a fresh symbol of
    each kind, in two orders: the shared table of :func:`real_symbol` fills as it is asked),
    and the simplifications that rest on them."""
    for order in (QUERIES, tuple(reversed(QUERIES))):
        ours, ref = real_symbol(f"x{len(order)}{order[0]}"), sp.Symbol(f"x{len(order)}{order[0]}", real=True)
        for q in order:
            assert getattr(ours, f"is_{q}") == getattr(ref, f"is_{q}"), q
    x = real_symbol("a_real_variable")
    assert sp.conjugate(x) == x and sp.im(x) == 0 and sp.Abs(x) ** 2 == x ** 2
    assert sp.sqrt(x ** 2) == sp.Abs(x) and (x ** 2).is_nonnegative
    assert x.assumptions0 == sp.Symbol("y", real=True).assumptions0


def test_real_symbol_survives_pickling_and_sympys_cache():
    """A copy through pickle (the front end's cache) is an ordinary sympy symbol equal to it;
    sympy's own constructor still returns its cached symbols, equal to ours."""
    x = real_symbol("beam.p[3]")
    y = pickle.loads(pickle.dumps(x))
    assert y == x and hash(y) == hash(x) and y.is_real
    assert sp.Symbol("beam.p[3]", real=True) is sp.Symbol("beam.p[3]", real=True)
    assert (x + sp.Symbol("beam.p[3]", real=True)) == 2 * x
