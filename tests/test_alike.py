"""Rows alike but for their symbols' names are rebuilt from one sympy rebuild per shape
(:class:`phc.ir.alike.AlikeReplacer`, issue 38): the results are sympy's own, argument
order included, and sympy rebuilds a number of rows that does not grow with the chain."""

from __future__ import annotations

import sys
from pathlib import Path

import sympy as sp

from phc.ir.alike import AlikeReplacer

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_components import chain_yaml  # noqa: E402


def R(name):
    return sp.Symbol(name, real=True)


def _same(a, b) -> bool:
    """Equal as sympy sees it, and built alike: same arguments in the same order, same hash."""
    return a == b and sp.srepr(a) == sp.srepr(b) and hash(a) == hash(b)


def test_renamed_rows_equal_sympys_and_one_rebuild_per_shape():
    m, k = R("m"), R("k")
    rows, rule = [], {}
    for i in range(1, 40):
        der, fa, fb = R(f"der(k{i}.x)"), R(f"k{i}.a.f"), R(f"k{i}.b.f")
        rows.append(der - fa + fb)
        rule[fa], rule[fb] = R(f"m{i - 1}.p") / m, R(f"m{i}.p") / m
    alike = AlikeReplacer(rule)
    out = [alike(row) for row in rows]
    assert all(_same(o, row.xreplace(rule)) for o, row in zip(out, rows))
    # k1..k9 against k10..k39: `m0.p` < `m1.p` but `m9.p` > `m10.p` as strings, so the
    # relative order of names differs for some rows: those are rebuilt by sympy
    assert alike.rebuilt < 6 and alike.rebuilt + alike.renamed == len(rows)


def test_names_in_another_order_are_rebuilt_by_sympy():
    a, b, c, d, x = R("a"), R("b"), R("c"), R("d"), R("x")
    alike = AlikeReplacer()
    first = alike(x + a, {x: 2 * b})  # 2*b + a -> a + 2*b
    # same shape, but the replacement's name sorts before the other one: sympy's order differs
    second = alike(x + d, {x: 2 * c})
    third = alike(x + c, {x: 2 * d})
    assert _same(first, a + 2 * b) and _same(second, 2 * c + d) and _same(third, c + 2 * d)
    assert alike.renamed == 1 and alike.rebuilt == 2  # `third` renames `first`; `second` does not


def test_coinciding_symbols_and_cancellation_are_not_renamed_blindly():
    a, b, x, y = R("a"), R("b"), R("x"), R("y")
    alike = AlikeReplacer()
    assert _same(alike(x - y, {x: a, y: b}), a - b)
    assert alike(x - y, {x: a, y: a}) == 0  # the same symbol twice: another shape, sympy cancels
    assert alike(x - y, {x: b, y: b}) == 0
    # symbols that are not phc's real symbols are left to sympy
    z = sp.Symbol("z")
    d = sp.Dummy("d")
    before = alike.rebuilt
    assert _same(alike(x + z, {x: a}), a + z) and _same(alike(x + d, {x: a}), a + d)
    assert alike.rebuilt == before + 2


def test_assembly_of_a_chain_rebuilds_a_bounded_number_of_rows(tmp_path, monkeypatch):
    """Counted, not timed: the rows sympy rebuilds in assembly are as many for 150 as for
    300 cells (the first of each shape, and those whose names sort otherwise), and the
    assembled model is the one plain xreplace gives."""
    import phc.ir.alike as alike_module
    from phc.frontend.elaborate import elaborate
    from phc.ir.assemble import assemble
    from phc.ir.interconnect import interconnect

    made = []

    class Counting(AlikeReplacer):
        def __init__(self, rule=None):
            super().__init__(rule)
            made.append(self)

    monkeypatch.setattr("phc.ir.assemble.AlikeReplacer", Counting)
    rebuilt = {}
    for cells in (150, 300):  # names of as many digits: as many orders of names
        path = tmp_path / f"chain_{cells}.yaml"
        path.write_text(chain_yaml(2 * cells + 1))
        elab, diags = elaborate(path)
        assert elab is not None and not diags.has_errors
        made.clear()
        dae, found = assemble(elab, interconnect(elab))
        assert dae is not None and not found.has_errors
        rebuilt[cells] = sum(r.rebuilt for r in made)
        assert sum(r.renamed for r in made) > cells  # most rows renamed
        # the rows as sympy's xreplace makes them: a spring's rate from its two masses
        i = cells // 2
        row = next(eq.expr for eq in dae.equations if eq.label == f"k{i}.rate[0]")
        mm = R("m")
        assert _same(row, R(f"der(k{i}.x)") - R(f"m{i - 1}.p") / mm + R(f"m{i}.p") / mm)
    assert rebuilt[150] == rebuilt[300], rebuilt
    assert alike_module.AlikeReplacer is AlikeReplacer


def test_a_row_the_rule_does_not_touch_is_the_row_itself():
    """As ``xreplace`` returns the very expression when nothing in it is replaced (an energy
    term ``k·x²/2`` in states only), so does the replacer, without rebuilding it; a row with
    one replaced symbol deep inside is rebuilt as sympy does."""
    k, x, y, f, g = R("k"), R("s1.x"), R("s2.x"), R("s1.a.f"), R("m1.p")
    alike = AlikeReplacer({f: g / R("m")})
    energy = k * x**2 / 2
    assert alike(energy) is energy is energy.xreplace(alike.rule)
    assert alike.unchanged == 1 and alike.rebuilt == alike.renamed == 0
    row = sp.sin(k * y**2 + f) - x
    assert _same(alike(row), row.xreplace(alike.rule)) and alike(row) is not row


def test_rows_whose_names_sort_otherwise_are_renamed_from_a_plan_for_that_order():
    """A shape's rows whose names sort otherwise than its first row's: the first of each
    order is rebuilt by sympy, the next ones of that order renamed from it, all equal to
    xreplace's (the rows of a grid's masses, `h9_9` beside `m10_9`)."""
    alike = AlikeReplacer()
    rows = []
    for lo, hi in (("a", "b"), ("d", "c"), ("f", "e"), ("g", "h"), ("j", "i")):
        x, y = R(f"{lo}1.x"), R(f"{hi}2.x")  # the replaced symbol's name sorts before, then after
        rows.append((R("z") + 3 * x, {R("z"): 2 * y}))
    out = [alike(row, rule) for row, rule in rows]
    assert all(_same(o, row.xreplace(rule)) for o, (row, rule) in zip(out, rows))
    # orders: (a1 < b2), (d1 > c2), (f1 > e2), (g1 < h2), (j1 > i2): the first and second
    # of each are rebuilt, the others renamed from the plan of their order
    assert alike.rebuilt == 2 and alike.renamed == 3
