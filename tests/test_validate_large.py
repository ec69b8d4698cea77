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

import sys
from pathlib import Path

import sympy as sp
from sympy.core.cache import clear_cache

import phc
from phc.frontend.elaborate import elaborate

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
