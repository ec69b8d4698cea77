"""Lowering is a function: :func:`phc.frontend.lowering.lower` of a component's spec and a read-only
context returns a frozen :class:`~phc.frontend.lowering.ComponentLowering`, and the elaborate pass
only folds those lowerings (issue 31: no shared builder, no `_Assembly`)."""

from __future__ import annotations

import dataclasses
from types import MappingProxyType

import pytest

import phc.ir.assemble
import phc.frontend.elaborate
from phc.frontend.elaborate import elaborate
from phc.library import LOWERERS
from phc.frontend.lowering import ComponentLowering, LoweringContext, ReadOnlySequence, lower
from model_texts import PDE1D

# PDE1D with the string written after its terminations: its sparse rows follow theirs
STRING_LAST = PDE1D.replace("""components:
  s:""", """components:
  m: {type: mass, m: rho, domain: mechanical.translational}
  k: {type: spring, k: T, domain: mechanical.translational}
  s:""")


def _elaborate(tmp_path, text):
    path = tmp_path / "model.yaml"
    path.write_text(text)
    elab, diags = elaborate(path)
    assert elab is not None and not diags.has_errors, diags.render_text()
    return elab


def _context(elab) -> LoweringContext:
    """A context with every parameter of `elab` and no variables or ports yet."""
    return LoweringContext(default_values=MappingProxyType(dict(elab.default_values)),
                           variables=ReadOnlySequence([]), ports=MappingProxyType({}),
                           unset_parameters=frozenset(), files=elab.files)


def _lower(elab, name):
    spec = elab.component_specs[name]
    return lower(LOWERERS[spec.type], _context(elab), elab.top, name, spec, ("components", name))


def _rows(lowering: ComponentLowering):
    return [(eq.label, str(eq.expr), eq.kind) for eq in lowering.equations]


def test_a_lowering_is_frozen_and_the_same_for_the_same_spec_and_context(tmp_path):
    elab = _elaborate(tmp_path, STRING_LAST)
    first, second = _lower(elab, "s"), _lower(elab, "s")
    assert isinstance(first, ComponentLowering)
    with pytest.raises(dataclasses.FrozenInstanceError):
        first.equations = ()
    assert all(isinstance(getattr(first, f.name), (tuple, frozenset, str)) for f in dataclasses.fields(first))
    assert _rows(first) == _rows(second)
    assert [v.name for v in first.variables] == [v.name for v in second.variables]
    assert [p.name for p in first.ports] == ["s.left", "s.right"]
    assert not first.diagnostics


def test_the_context_is_read_only(tmp_path):
    elab = _elaborate(tmp_path, STRING_LAST)
    context = _context(elab)
    with pytest.raises(TypeError):
        context.default_values[next(iter(context.default_values))] = 0  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        context.ports = {}  # type: ignore[misc]
    before = dict(context.default_values)
    _lower(elab, "s")
    assert dict(context.default_values) == before


def test_sparse_rows_count_from_the_component_and_are_shifted_when_folded(tmp_path):
    """A sparse block's rows are the component's own (from 0) in its lowering; the
    elaboration appends them after the rows of the components lowered before it."""
    elab = _elaborate(tmp_path, STRING_LAST)
    alone = _lower(elab, "s")
    assert alone.linear_blocks and alone.linear_blocks[0].rows[0] == 0
    before = sum(1 for eq in elab.equations if eq.component in ("m", "k"))
    own = [i for i, eq in enumerate(elab.equations) if eq.component == "s"]
    assert before > 0 and own[0] == before
    for block, folded in zip(alone.linear_blocks, [b for b in elab.linear_blocks if b.component == "s"]):
        assert tuple(folded.rows) == tuple(before + r for r in block.rows)  # a range (consecutive rows)
    assert [(elab.equations[i].label, str(elab.equations[i].expr)) for i in own] == \
        [(label, expr) for label, expr, _ in _rows(alone)]


def test_no_shared_builder_remains():
    assert not hasattr(phc.frontend.elaborate, "Builder")
    assert not hasattr(phc.ir.assemble, "_Assembly")
