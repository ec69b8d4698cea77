"""What every pass has: a :class:`Reporter` (located diagnostics, expressions parsed
into sympy without evaluating user text), the :class:`FileContext` of a model file, and
the :class:`Port` a lowerer declares. Used by the elaborate pass (:mod:`phc.frontend.elaborate`),
lowering (:mod:`phc.frontend.lowering`) and the assemble pass (:mod:`phc.ir.assemble`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import sympy as sp

from phc.diagnostics import Diagnostic, DiagnosticList
from phc.frontend.files import FileAccess
from phc.frontend.source import SourceMap, SourceSpan
from phc.frontend.source_map import path_text
from phc.spec import ModelSpec
from phc.spec.expressions import ExpressionError, parse_equation, parse_expression


@dataclass
class Port:
    """A power port after lowering: flow and effort symbols of one component."""

    name: str
    component: str
    domain: str
    dimension: int
    frame: Optional[str]
    f: list[sp.Symbol]
    e: list[sp.Symbol]
    position: Optional[list[sp.Expr]] = None
    span: Optional[SourceSpan] = None


@dataclass
class FileContext:
    """Where a (possibly nested) model file sits: its source map and name prefix."""

    file: str
    smap: SourceMap
    prefix: str
    spec: ModelSpec
    params: dict[str, Any] = field(default_factory=dict)


class Reporter:
    """Collects located diagnostics and parses expressions into sympy (never evaluating
    user text): the part of a pass's state that every pass has. `files` is the
    :class:`~phc.frontend.files.FileAccess` that referenced files (tables) are read through."""

    def __init__(self, files: Optional[FileAccess] = None) -> None:
        self.diags = DiagnosticList()
        self.files = files if files is not None else FileAccess()
        self.units: dict = {}  # symbol -> its unit (a pint quantity in SI base units), see phc.frontend.units
        self.unit_text: dict = {}  # symbol -> its unit as the model wrote it (for messages)
        self.expr_dims: dict = {}  # (source map id, path) -> dimension of the expression parsed there
        self.field_dims: dict = {}  # (source map id, path[:3]) -> [(path, dimension)]: by component field
        self.units_declared = False  # some parameter has a unit (pint installed)
        self.units_si = True  # every declared unit is a coherent SI unit (no mm, MPa, ...)
        self.fields_si = True  # every component field of known dimension is in coherent SI units
        self.fields_checked = False  # some component field's dimension was known
        self.scale_system = None  # phc.frontend.units.ScaleSystem: the model's unit system, from its fields' units
        self.param_overrides: dict[str, float] = {}  # top-level parameters set from outside the files
        self.override_note = ""  # the scene's parameter overrides, named in refusals of their values

    # -- diagnostics ----------------------------------------------------------------
    def error(self, code: str, message: str, ctx: Optional[FileContext], path: Sequence = (),
              hint: Optional[str] = None, severity: str = "error", key: bool = False) -> None:
        span = None
        if self.override_note and " at the default parameters" in message:  # a value the scene set
            message = message.replace(" at the default parameters", f" with {self.override_note}")
        if ctx is not None:
            span = ctx.smap.locate_key(tuple(path)) if key else ctx.smap.locate(tuple(path))
        dotted = path_text(path)
        if ctx is not None and hasattr(ctx.smap, "dotted") and path:  # as written there (scene entries too)
            dotted = ctx.smap.dotted(tuple(path))
        self.diags.append(Diagnostic(code, message, span=span, hint=hint, severity=severity, path=dotted))

    # -- expressions ----------------------------------------------------------------
    def expr(self, ctx: FileContext, value: Any, path: Sequence, names: dict,
             equation: bool = False, check_units: bool = True, rates: Optional[dict] = None) -> sp.Expr:
        """Parse a number or expression string at `path`; on error record it and return 0.
        `rates`: the states' rates for ``der(x)`` (outputs)."""
        try:
            if equation:
                result = parse_equation(value, names)
            else:
                result = parse_expression(value, names, rates=rates)
        except ExpressionError as err:
            span = (ctx.smap.locate_in_value(tuple(path), err.col) if isinstance(value, str)
                    else ctx.smap.locate(tuple(path)))
            dotted = ctx.smap.dotted(tuple(path)) if hasattr(ctx.smap, "dotted") else path_text(path)
            self.diags.append(Diagnostic("PHC-E101", f"in expression `{value}`: {err.message}", span=span,
                                         hint=err.hint, path=dotted))
            return sp.Integer(0)
        if self.units and check_units and not (result.free_symbols & getattr(self, "unset_parameters", set())):
            dim = self.dimension(ctx, value, path, result)
            self.expr_dims[(id(ctx.smap), tuple(path))] = dim
            self.field_dims.setdefault((id(ctx.smap), tuple(path[:3])), []).append((tuple(path), dim))
        return result

    def dimension(self, ctx: FileContext, value: Any, path: Sequence, expr: sp.Basic):
        """The dimension of `expr` (parsed from `value` at `path`): a pint quantity,
        :data:`phc.frontend.units.NUMBER` or None (unknown); an inconsistency is reported (PHC-E171)."""
        from phc.frontend.units import DimensionError, dimension

        try:
            return dimension(expr, self.units, self.unit_text)
        except DimensionError as err:
            self.error("PHC-E171", f"in expression `{value}`: {err}", ctx, path,
                       hint="every term of a sum (and both sides of a comparison) needs the same unit; "
                       "check the units of the parameters it uses")
            return None

    def vector(self, ctx, values, path, names, length: Optional[int] = None, what: str = "vector") -> list[sp.Expr]:
        if not isinstance(values, list):
            values = [values]
        if length is not None and len(values) != length:
            self.error("PHC-E102", f"{what} has {len(values)} entries, expected {length}", ctx, path)
            # reported: callers index `length` entries, so pad or cut (no IndexError later)
            values = (values + [0] * length)[:length]
        return [self.expr(ctx, v, (*path, i), names) for i, v in enumerate(values)]

    def matrix(self, ctx, rows, path, names, shape: tuple[Optional[int], Optional[int]], what: str) -> sp.Matrix:
        n, m = shape
        if n is not None and len(rows) != n:
            self.error("PHC-E102", f"{what} has {len(rows)} rows, expected {n}", ctx, path)
        out = []
        for i, row in enumerate(rows):
            if not isinstance(row, list):
                row = [row]
            if m is not None and len(row) != m:
                self.error("PHC-E102", f"row {i} of {what} has {len(row)} entries, expected {m}", ctx, (*path, i))
            out.append([self.expr(ctx, v, (*path, i, j), names) for j, v in enumerate(row)])
        if n is not None and m is not None and (len(out) != n or any(len(r) != m for r in out)):
            return sp.zeros(n, m)
        if not out:
            return sp.zeros(0, m or 0)
        return sp.Matrix(out)


__all__ = ["FileContext", "Port", "Reporter"]
