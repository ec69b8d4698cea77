"""Long sums in the generated module: the energy of a chain of thousands of springs and
masses is one sum of thousands of terms, and Python refuses to compile ``a + b + c + …``
nested a few thousand levels deep. The printer writes such a sum as statements of at most
``LONG_SUM`` terms each that add the terms in the same order, so the module computes the
same values to the bit."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.codegen import printer
from phc.codegen.load import load_generated
from phc.codegen.lower import lower_residual
from phc.codegen.printer import print_module

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_component_scaling import damped_chain  # noqa: E402

SHORT = 8
"""A ``LONG_SUM`` small enough that a chain of a few dozen cells has several long sums."""


def _longest_sum(source: str) -> int:
    """The most terms of one chain of ``+``/``-`` in the source."""
    longest = 0
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub)):
            length, left = 2, node.left
            while isinstance(left, ast.BinOp) and isinstance(left.op, (ast.Add, ast.Sub)):
                length, left = length + 1, left.left
            longest = max(longest, length)
    return longest


@pytest.fixture(scope="module")
def chain_ir(tmp_path_factory):
    path = tmp_path_factory.mktemp("chain") / "chain.yaml"
    path.write_text(damped_chain(12))
    dae, diags = phc.build_dae(path)
    assert dae is not None, [d.render() for d in diags]
    return lower_residual(dae)


def test_a_long_sum_becomes_short_statements_with_the_same_values(chain_ir, monkeypatch):
    whole = print_module(chain_ir)
    monkeypatch.setattr(printer, "LONG_SUM", SHORT)
    split = print_module(chain_ir)
    assert _longest_sum(whole) > 2 * SHORT  # the energy: about 24 terms on one line
    # at most SHORT terms, plus the local the statement adds them to
    assert _longest_sum(split) <= SHORT + 1
    a, _ = load_generated(whole, "whole")
    b, _ = load_generated(split, "split")
    rng = np.random.default_rng(7)
    p = a.full_parameters()
    n = len(a.VARIABLES)
    for _ in range(5):
        t, y, yp = float(rng.uniform(0, 1)), rng.standard_normal(n), rng.standard_normal(n)
        # left-to-right additions in the same order: the same doubles, not merely close ones
        assert a.hamiltonian(t, y, p) == b.hamiltonian(t, y, p)
        ra, rb = np.empty(n), np.empty(n)
        a.residual(t, y, yp, p, ra)
        b.residual(t, y, yp, p, rb)
        assert np.array_equal(ra, rb)
        ja, jb = np.empty(len(a.JAC_ROWS)), np.empty(len(b.JAC_ROWS))
        a.jacobian(t, y, yp, p, 0.5, ja)
        b.jacobian(t, y, yp, p, 0.5, jb)
        assert np.array_equal(ja, jb)
        assert np.array_equal(np.asarray(a.powers(t, y, yp, p)), np.asarray(b.powers(t, y, yp, p)))
        assert np.array_equal(np.asarray(a.outputs(t, y, yp, p)), np.asarray(b.outputs(t, y, yp, p)))


def test_a_short_sum_is_printed_as_before(chain_ir):
    source = print_module(chain_ir)
    assert printer.LONG_SUM > 24 and "_c0 = _c0 +" not in source


@pytest.mark.slow
def test_a_chain_of_thousands_of_components_compiles_and_runs(tmp_path):
    path = tmp_path / "chain.yaml"
    path.write_text(damped_chain(1500))  # 4501 components; its energy: about 3000 terms
    compiled = phc.compile_model(path, certify=False, backend="numpy")
    result = phc.simulate(compiled, t_end=1e-2, solver="midpoint", step=1e-3)
    assert result.success, result.message
