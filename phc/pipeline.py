"""The compiler pipeline, one readable sequence (DESIGN.md, "Pipeline").

parse → elaborate (library lowering, nesting) → assemble (alias elimination, GGL) →
analyse (balance, matching) → lower (Jacobian) → print → load.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Optional

from phc.analysis.matching import check_balance
from phc.codegen.load import load_generated
from phc.codegen.lower import lower_residual
from phc.codegen.printer import print_module
from phc.dae import Dae
from phc.diagnostics import DiagnosticList
from phc.elaborate import elaborate
from phc.errors import ModelError


@dataclass
class CompiledModel:
    """A compiled model: the assembled DAE, the generated module and its source."""

    name: str
    dae: Dae
    module: ModuleType
    source: str
    module_path: Path
    diagnostics: DiagnosticList
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_states(self) -> int:
        return self.dae.n_states - 1  # without the energy accumulator

    @property
    def n_equations(self) -> int:
        return len(self.dae.equations)

    @property
    def jacobian_nnz(self) -> int:
        return len(self.module.JAC_ROWS)


def build_dae(path: str | os.PathLike) -> tuple[Optional[Dae], DiagnosticList]:
    """Stages 1–7: read, elaborate, assemble and check one model file."""
    dae, diags = elaborate(path)
    if dae is not None:
        # Structural solvability before any code is generated.
        diags.extend(check_balance(dae))
        if diags.has_errors:
            dae = None
    return dae, DiagnosticList(diags).sorted()


def compile_model(path: str | os.PathLike) -> CompiledModel:
    """Compile a model file to a loaded residual module.

    Raises
    ------
    ModelError
        When the model has errors (``err.diagnostics`` lists them, located).
    """
    timings = {}
    t = time.perf_counter()
    dae, diags = build_dae(path)
    timings["elaborate"] = time.perf_counter() - t
    if dae is None:
        raise ModelError(diags)
    t = time.perf_counter()
    ir = lower_residual(dae)
    timings["lower"] = time.perf_counter() - t
    t = time.perf_counter()
    source = print_module(ir)
    timings["print"] = time.perf_counter() - t
    t = time.perf_counter()
    module, module_path = load_generated(source, dae.name)
    timings["load"] = time.perf_counter() - t
    return CompiledModel(dae.name, dae, module, source, module_path, diags, timings)
