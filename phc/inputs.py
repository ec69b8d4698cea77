"""Input signals on exposed ports: expressions in `t`, piecewise definitions, CSV tables.

Every signal becomes a sympy expression in ``t`` (pipeline stage 5). A piecewise signal is a
``Piecewise``; a table is an :class:`InputTable` node that the code printer turns into
``numpy.interp`` over constant arrays in the generated module (so the module stays
standalone). The times where a signal is not smooth — the ends of pieces and the rows of a
table — are *breakpoints*: the integrators stop there and restart from a consistent state,
so a step input is located exactly instead of being found by step rejections.

Tables are read with the csv module (numbers only); nothing in a model or scene file is
executed.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
import numpy as np
import sympy as sp

from phc.dae import T
from phc.spec.model import PieceSpec, TableSpec

MAX_TABLE_ROWS = 1_000_000


class InputTable(sp.Function):
    """``InputTable(k, t)``: value of input table k at time t (printed as ``np.interp``)."""

    nargs = 2

    def fdiff(self, argindex=2):
        if argindex != 2:
            raise sp.ArgumentIndexError(self, argindex)
        return InputTableSlope(*self.args)


class InputTableSlope(sp.Function):
    """``d/dt InputTable(k, t)``: the slope of the interpolant (zero for a zero-order hold)."""

    nargs = 2

    def fdiff(self, argindex=2):
        return sp.Integer(0)


class TableError(Exception):
    """A table file that cannot be used; `message` says why."""


def read_table(path: Path, spec: TableSpec) -> tuple[np.ndarray, np.ndarray]:
    """Times and values of a CSV table (header row, numeric columns)."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as err:
        raise TableError(f"cannot read table `{spec.file}` ({err.__class__.__name__}: {err})") from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if len(rows) < 2:
        raise TableError(f"table `{spec.file}` needs a header row and at least one data row")
    if len(rows) > MAX_TABLE_ROWS:
        raise TableError(f"table `{spec.file}` has more than {MAX_TABLE_ROWS} rows")
    header = [h.strip() for h in rows[0]]
    for col in (spec.time_column, spec.column):
        if col not in header:
            raise TableError(f"table `{spec.file}` has no column `{col}`; its columns: {', '.join(header)}")
    it, iv = header.index(spec.time_column), header.index(spec.column)
    times, values = [], []
    for n, row in enumerate(rows[1:], start=2):
        try:
            t, v = float(row[it]), float(row[iv])
        except (IndexError, ValueError):
            raise TableError(f"table `{spec.file}` row {n}: `{spec.time_column}` and `{spec.column}` must be "
                             "numbers") from None
        if not (math.isfinite(t) and math.isfinite(v)):
            raise TableError(f"table `{spec.file}` row {n}: values must be finite")
        times.append(t)
        values.append(v)
    times_a = np.array(times)
    if np.any(np.diff(times_a) <= 0):
        raise TableError(f"table `{spec.file}`: column `{spec.time_column}` must increase strictly")
    return times_a, np.array(values)


class SignalBuilder:
    """Turns input signals into expressions; collects tables and breakpoints."""

    def __init__(self) -> None:
        self.tables: list[tuple[np.ndarray, np.ndarray, str]] = []  # (times, values, interpolation)
        self.breakpoints: set[float] = set()

    def signal(self, b, ctx, value, path, scope) -> sp.Expr:
        if isinstance(value, TableSpec):
            return self._table(b, ctx, value, path)
        if isinstance(value, list) and value and all(isinstance(p, PieceSpec) for p in value):
            return self._pieces(b, ctx, value, path, scope)
        return b.expr(ctx, value, path, scope)

    def _pieces(self, b, ctx, pieces, path, scope) -> sp.Expr:
        args, last = [], None
        for i, piece in enumerate(pieces):
            expr = b.expr(ctx, piece.value, (*path, i, "value"), scope)
            if piece.until is None:
                if i != len(pieces) - 1:
                    b.error("PHC-E212", "only the last piece may omit `until`", ctx, (*path, i))
                args.append((expr, True))
                break
            if last is not None and piece.until <= last:
                b.error("PHC-E212", f"pieces must end in increasing time order (`until: {piece.until}` after "
                        f"`until: {last}`)", ctx, (*path, i, "until"))
            last = piece.until
            self.breakpoints.add(float(piece.until))
            args.append((expr, T < piece.until))
        else:
            args.append((args[-1][0], True))  # the last value holds after the last `until`
        return sp.Piecewise(*args)

    def _table(self, b, ctx, spec: TableSpec, path) -> sp.Expr:
        try:
            times, values = read_table(Path(ctx.file).parent / spec.file, spec)
        except TableError as err:
            b.error("PHC-E213", str(err), ctx, (*path, "file"))
            return sp.Integer(0)
        self.tables.append((times, values, spec.interpolation))
        self.breakpoints.update(float(t) for t in times)
        return InputTable(sp.Integer(len(self.tables) - 1), T)


def table_arrays(tables) -> list[str]:
    """Module constants for the input tables (see :class:`InputTable`)."""
    lines = []
    for k, (times, values, kind) in enumerate(tables):
        lines.append(f"_TABLE{k}_T = np.array({times.tolist()!r})")
        lines.append(f"_TABLE{k}_V = np.array({values.tolist()!r})")
        lines.append(f"_TABLE{k}_KIND = {kind!r}")
    return lines


def breakpoints_within(points, t0: float, t1: float) -> list[float]:
    """Sorted breakpoints strictly inside (t0, t1)."""
    return sorted(p for p in points if t0 < p < t1)


__all__ = ["InputTable", "InputTableSlope", "SignalBuilder", "read_table", "table_arrays", "breakpoints_within",
           "TableError"]
