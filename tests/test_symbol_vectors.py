"""Vectors of a sparse description without one sympy symbol per entry (issue 35): the
storage vectors of a string are eliminated by emit_sparse as whole vectors, and their
symbols are never made; when they are read, they are those the scalar code made."""

from pathlib import Path

import pytest
import sympy as sp

from phc.codegen.printer import _identifier, _identifiers
from phc.ir.dae import Chained, SymbolVector
from phc.library.dirac import _distinct
from phc.pipeline import build_dae

MODELS = Path(__file__).resolve().parents[1] / "models"


def test_a_string_compiles_without_making_its_storage_vectors():
    dae, _ = build_dae(MODELS / "vibrating_string.yaml", None)
    structures = [d.structure for d in dae.topology.dirac if d.component == "string" and d.structure is not None]
    assert structures
    vectors = [v for s in structures for sv in s.storage_vectors for v in (sv.flows, sv.efforts)]
    assert vectors and all(isinstance(v, SymbolVector) and not v.made for v in vectors)
    # read, they are the symbols `stem[i]` (real), in the description's flows at their place
    flows = structures[0].flows
    assert isinstance(flows, Chained)
    v = structures[0].storage_vectors[0].flows
    assert v[3] == sp.Symbol(f"{v.stem}[3]", real=True) and v.made
    assert list(flows) == [flows[k] for k in range(len(flows))]
    assert flows[-1] == list(flows)[-1]


@pytest.mark.parametrize("parts", [
    lambda v: [v, v],                                       # one vector twice
    lambda v: [v, SymbolVector(v.stem, 2)],                 # two vectors of one stem
    lambda v: [v, sp.Symbol(f"{v.stem}[2]", real=True)],    # a symbol named as an entry
    lambda v: [sp.Symbol("a"), sp.Symbol("a")],             # a symbol twice
])
def test_a_symbol_declared_twice_is_refused(parts):
    with pytest.raises(ValueError, match="declared twice"):
        _distinct("c", parts(SymbolVector("cert:c.f_x", 3)))


def test_an_entry_past_the_end_is_not_a_clash():
    _distinct("c", [SymbolVector("cert:c.f_x", 3), sp.Symbol("cert:c.f_x[3]", real=True), sp.Symbol("cert:c.f_x")])


def test_identifiers_in_one_pass_are_those_made_one_by_one():
    names = ["a.b[3]", "a_b_3", "x", "_", "", "[]", "def", "a.b[3]", "é", "y", "y", "rod.w[10]", "rod.w_10"]
    one, batch = set(), set()
    assert _identifiers("y_", names, batch) == [_identifier("y_", n, one) for n in names]
    assert one == batch
    # a name with a line break (quoted YAML key) falls back to one by one
    assert _identifiers("yp_", ["a\nb", "a_b"], set()) == ["yp_a_b", "yp_a_b_2"]
