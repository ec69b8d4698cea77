"""Common subexpressions searched once per IR (:func:`phc.codegen.printer.shared_cse`).

The NumPy module's printer runs first and records each search; the C printer and the numba
emitter (:func:`phc.codegen.kernels.kernel_cse`) take the result for the same list of target
expressions from there and search only the sums' coefficients (parameters only) themselves.
That the values stay the NumPy module's is tests/codegen/test_c_backend.py's job; these tests
check that no list of rows is searched twice and that what is reused is the search's result.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import sympy as sp

from phc.codegen import kernels, printer
from phc.codegen.c_printer import c_source
from phc.codegen.lower import lower_residual
from phc.codegen.printer import print_module
from phc.pipeline import build_dae

ROOT = Path(__file__).resolve().parents[2]


def _ir(name: str):
    dae, diags = build_dae(str(ROOT / "models" / name))
    assert dae is not None, diags
    return lower_residual(dae)


def _searches(monkeypatch) -> list:
    """Record the expression lists :func:`printer._cse` is given (by the printers and kernels)."""
    seen: list = []
    real = printer._cse

    def counting(exprs, symbols):
        seen.append(tuple(exprs))
        return real(exprs, symbols)

    monkeypatch.setattr(printer, "_cse", counting)
    monkeypatch.setattr(kernels, "_cse", counting)
    return seen


def test_c_printer_searches_only_the_coefficients_after_the_numpy_module(monkeypatch):
    # the flexible slider-crank: nonlinear rows and a beam's linear blocks (sum coefficients)
    ir = _ir("flexible_slider_crank.yaml")
    seen = _searches(monkeypatch)
    print_module(ir)
    numpy_searches = len(seen)
    assert numpy_searches and ir.common_subexpressions
    c_source(ir)
    again = seen[numpy_searches:]
    coefficients = {kernels._coefficient(op) for f in kernels.function_kernels(ir) for op in f.kernel.sums}
    assert coefficients, "the model was chosen for its linear blocks"
    assert again, "the sums' coefficients are searched (among themselves)"
    for exprs in again:
        assert set(exprs) <= coefficients, "a list of rows was searched a second time"


def test_shared_result_is_the_search_of_that_list(monkeypatch):
    # a model without linear blocks: every kernel's list is a NumPy printer's list
    ir = _ir("pendulum.yaml")
    print_module(ir)
    seen = _searches(monkeypatch)
    rng = np.random.default_rng(0)
    for f in kernels.function_kernels(ir):
        replacements, reduced = kernels.kernel_cse(ir, f.kernel)
        assert len(reduced) == len(f.kernel.targets) + len(f.kernel.sums)
        for (_, e, _), r in zip(f.kernel.targets, reduced):
            # the reduced expression with its locals' values is the target's value, at a random
            # point with every symbol in [0.5, 1.5] (the locals regroup a few operations: 1e-12
            # relative is a few hundred roundings of margin)
            point = {s: sp.Float(rng.uniform(0.5, 1.5)) for s in e.free_symbols}
            local = {}
            for sym, rhs in replacements:
                local[sym] = rhs.xreplace(local).xreplace(point).evalf()
            got = complex(r.xreplace(local).xreplace(point).evalf())
            want = complex(e.xreplace(point).evalf())
            assert abs(got - want) <= 1e-12 * max(1.0, abs(want)), (e, r)
    assert seen == []  # all found in the record of the NumPy module's printer
