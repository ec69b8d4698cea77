"""Input signals on exposed ports: expressions in `t`, piecewise definitions, CSV tables.

Every signal becomes a sympy expression in ``t`` (pipeline stage 5). A piecewise signal is a
``Piecewise``; a table is an :class:`InputTable` node that the code printer turns into
``numpy.interp`` over constant arrays in the generated module (so the module stays
standalone). The times where a signal is not smooth — the ends of pieces, the jumps of a
zero-order-hold table and (up to :data:`MAX_KINK_BREAKPOINTS`) the kinks of a linear one,
see :func:`table_breakpoints` — are *breakpoints*: the integrators stop there and restart
from a consistent state, so a step input is located exactly instead of being found by step
rejections.

Tables are read with the csv module (numbers only), through :mod:`phc.frontend.files` (inside the
model's tree, regular files, bounded size, at most :data:`MAX_TABLE_ROWS` rows); nothing in
a model or scene file is executed, and no message quotes a table's content beyond the
column names of a header that parsed as one.
"""

from __future__ import annotations

import csv
import difflib
import io
import re
from pathlib import Path
from typing import Optional

import numpy as np
import sympy as sp

from phc.errors import TableError
from phc.ir.dae import T
from phc.frontend.files import FileAccess, FileRefused
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


MAX_KINK_BREAKPOINTS = 256
"""At most this many kinks of one linearly interpolated table become breakpoints (see
:func:`table_breakpoints`)."""

_COLUMN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.\[\]()/ -]{0,63}")
"""What a header cell must look like for phc to show it in a message."""


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _shown_columns(header: list[str], first_row: Optional[list[str]]) -> Optional[list[str]]:
    """The header's column names if they may be shown in a message, else None.

    A message about a table must not leak the file's content (a table name can point at
    a file of secrets): names are shown only when the first row parsed as a header —
    every cell a plain name — above a row of numbers."""
    if not header or len(header) > 64 or not all(_COLUMN_NAME.fullmatch(h) for h in header):
        return None
    if first_row is None or not first_row or not all(_is_number(c) for c in first_row):
        return None
    return header


def _csv_problem(err: csv.Error, line: int, name: str) -> str:
    text = str(err)
    if "field larger than field limit" in text:
        return (f"table `{name}` line {line}: a field is longer than {csv.field_size_limit()} characters; a table "
                "holds numbers")
    if "NUL" in text:
        return f"table `{name}` line {line}: contains a NUL byte; a table is a text file of numbers"
    return f"table `{name}` line {line}: not valid CSV (unbalanced quotes or a stray line break)"


_HEADER_UNIT = re.compile(r"^(.*?)\s*\[([^\[\]]*)\]$")
"""A header cell with a trailing unit, as phc writes its own results: `P [Pa]`, `t [s]`."""


def split_header(cell: str) -> tuple[str, Optional[str]]:
    """``("P", "Pa")`` for the header cell `P [Pa]`; ``(cell, None)`` without a unit."""
    match = _HEADER_UNIT.match(cell)
    if match is None or not match.group(1).strip():
        return cell, None
    return match.group(1).strip(), match.group(2).strip()


def _find_column(header: list[str], name: str) -> Optional[int]:
    """The index of column `name`: the header cell written so (`P [bar]`), or the one cell
    whose name without its `[unit]` is `name` (`P` for `P [Pa]`: phc's own CSV output)."""
    if name in header:
        return header.index(name)
    bare = [i for i, h in enumerate(header) if split_header(h)[0] == name]
    return bare[0] if len(bare) == 1 else None


def read_table(path: Path, spec: TableSpec, data: Optional[bytes] = None,
               units: Optional[dict] = None) -> tuple[np.ndarray, np.ndarray]:
    """Times and values of a CSV table (header row, numeric columns).

    A column is named as its header cell is written, or by its name without a trailing
    `[unit]` (`column: P` for the header `P [Pa]`). When `units` is a dict, it receives the
    header cells and units of the two columns: ``{"time": ("t [ms]", "ms"), "value":
    ("P [bar]", "bar")}`` (the unit None where the header gives none).

    `data` is the file's content when the caller has read it (through
    :class:`phc.frontend.files.FileAccess`, as elaboration does); otherwise `path` is opened the
    same safe way (a regular file within the size limit). At most :data:`MAX_TABLE_ROWS`
    data rows; rows are streamed, so a larger file stops at the limit."""
    name = spec.file
    if data is None:
        access = FileAccess([Path(path).parent])
        try:
            data = access.read_bytes(Path(path), name, "table")
        except FileRefused as err:
            raise TableError(err.message) from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        raise TableError(f"table `{name}` is not valid UTF-8 (line {line})") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    header: Optional[list[str]] = None
    it = iv = 0
    times, values = [], []
    row_no = 0  # rows with content, the header being row 1 (as a spreadsheet numbers them)
    first_row = None
    try:
        for row in reader:
            if not row or not any(c.strip() for c in row):
                continue
            row_no += 1
            if header is None:
                header = [h.strip() for h in row]
                continue
            if first_row is None:
                first_row = [c.strip() for c in row]
                found = [_find_column(header, c) for c in (spec.time_column, spec.column)]
                if None in found:
                    break
                it, iv = found
            if row_no - 1 > MAX_TABLE_ROWS:
                raise TableError(f"table `{name}` has more than {MAX_TABLE_ROWS:,} data rows")
            try:
                times.append(float(row[it]))
                values.append(float(row[iv]))
            except (IndexError, ValueError):
                raise TableError(f"table `{name}` row {row_no}: `{spec.time_column}` and `{spec.column}` must be "
                                 "numbers") from None
    except csv.Error as err:
        raise TableError(_csv_problem(err, reader.line_num, name)) from None
    if header is None or first_row is None:
        raise TableError(f"table `{name}` needs a header row and at least one data row")
    for col in (spec.time_column, spec.column):
        if _find_column(header, col) is None:
            shown = _shown_columns(header, first_row)
            if shown is None:
                raise TableError(f"table `{name}` has no column `{col}`; its first row is not a header of column "
                                 "names (phc does not show the file's content)")
            close = difflib.get_close_matches(col, shown, n=1)
            raise TableError(f"table `{name}` has no column `{col}`; its columns: {', '.join(shown)}"
                             + (f" (did you mean `{close[0]}`?)" if close else ""))
    if units is not None:
        units["time"] = (header[it], split_header(header[it])[1])
        units["value"] = (header[iv], split_header(header[iv])[1])
    times_a, values_a = np.array(times, dtype=float), np.array(values, dtype=float)
    bad = np.flatnonzero(~(np.isfinite(times_a) & np.isfinite(values_a)))
    if bad.size:
        raise TableError(f"table `{name}` row {int(bad[0]) + 2}: values must be finite")
    if np.any(np.diff(times_a) <= 0):
        first = int(np.flatnonzero(np.diff(times_a) <= 0)[0]) + 3
        raise TableError(f"table `{name}` row {first}: column `{spec.time_column}` must increase strictly")
    return times_a, values_a


def table_breakpoints(times: np.ndarray, values: np.ndarray, kind: str) -> tuple[list[float], int]:
    """``(breakpoints, kinks)``: the times of one table where the integrators stop and
    restart, and for a linear table the number of its kinks (0 for a zero-order hold).

    The rule, and why it is sound:

    * ``previous`` (zero-order hold): every row whose value differs from the previous
      row's is a **jump** of the input, and every jump is a breakpoint. Across a jump the
      solution's derivative is discontinuous and algebraic variables jump; stepping over
      it unannounced would cost many rejected steps or a failed error test, and the
      restart's consistent initialization is what makes the jumped algebraic values right.
      Rows that repeat the previous value are not breakpoints (nothing changes there).
    * ``linear``: the input is continuous; only its slope changes at a **kink** (a row
      where the slopes on both sides differ by more than 1e-9 of the table's largest slope;
      the ends count when the slope is not zero, since the end values hold outside). The
      solution stays continuously differentiable in its differential states, so a
      variable-step integrator's local error estimate sees a kink and shortens its step
      there; the error stays controlled by rtol/atol without a restart. Restarting is
      still cheaper and more exact for a few kinks, so up to :data:`MAX_KINK_BREAKPOINTS`
      kinks are breakpoints. Above that the table is a sampled signal (100 000 rows made
      every row a restart: 253 s for a one-state model) and none of its kinks is a
      breakpoint: the solver's error control resolves them, and a note says so.
    """
    if len(times) < 2:
        return [], 0
    if kind == "previous":
        return times[1:][values[1:] != values[:-1]].tolist(), 0
    slopes = np.diff(values) / np.diff(times)
    outside = np.concatenate([[0.0], slopes, [0.0]])
    scale = float(np.abs(slopes).max())
    if scale == 0.0 or not np.isfinite(scale):
        return [], 0
    kinks = np.abs(np.diff(outside)) > 1e-9 * scale
    count = int(kinks.sum())
    if count > MAX_KINK_BREAKPOINTS:
        return [], count
    return times[kinks].tolist(), count


class SignalBuilder:
    """Turns input signals into expressions; collects tables and breakpoints."""

    def __init__(self, elab=None) -> None:
        self.elab = elab  # the phc.frontend.elaborate.Elaboration whose inputs these are (its units check them)
        self.tables: list[tuple[np.ndarray, np.ndarray, str]] = []  # (times, values, interpolation)
        self.breakpoints: set[float] = set()
        self.expect: Optional[tuple[str, str, str]] = None  # (domain, "effort"|"flow", port) of the signal
        self.scales: dict = {}  # the model's system of units (Elaboration.scales)

    def signal(self, b, ctx, value, path, scope) -> sp.Expr:
        if isinstance(value, TableSpec):
            return self._table(b, ctx, value, path)
        if isinstance(value, list) and value and all(isinstance(p, PieceSpec) for p in value):
            return self._pieces(b, ctx, value, path, scope)
        return self._checked(b, ctx, value, path, b.expr(ctx, value, path, scope))

    def _want(self):
        """The unit of the port variable the signal sets, in the model's system of units, with
        a description of it; None where unknown (generic domain, no pint)."""
        from phc.frontend.units import DOMAIN_UNITS, domain_scale, domain_units, have_pint

        if not have_pint() or self.expect is None or self.expect[0] not in DOMAIN_UNITS:
            return None
        domain, which, port = self.expect
        want = domain_units(domain)[0 if which == "effort" else 1]
        want = want * 10.0 ** domain_scale(self.scales, domain, "E" if which == "effort" else "F")
        return want, f"the input {which} of port `{port}` ({domain})"

    def _checked(self, b, ctx, value, path, expr):
        """An input given as an expression must be in the unit of the port variable it sets
        (its domain's effort or flow, in the model's system of units): PHC-E172 otherwise."""
        from phc.frontend.units import NUMBER, DimensionError, describe, dimension, scale_factor, scaled_label

        expected = self._want()
        elab = self.elab
        if expected is None or elab is None or not getattr(elab, "units", None):
            return expr
        want, what = expected
        try:
            dim = dimension(expr, elab.units, elab.unit_text)
        except DimensionError:
            return expr  # reported where the expression's parameters are checked
        if dim is None or dim is NUMBER:
            return expr
        need = scaled_label(want)
        name = value.strip() if isinstance(value, str) else None
        sym = next((s for s in elab.units if s.name == (ctx.prefix or "") + (name or "")), None)
        written = elab.unit_text.get(sym) if sym is not None else None
        if dim.dimensionality != want.dimensionality:
            b.error("PHC-E172", f"{what} is in {describe(want)}, but `{value}` is in {describe(dim, written)}", ctx,
                    path, hint="check the units of the parameters it uses (or the port's domain)")
            return expr
        ratio = scale_factor(dim, want)
        if abs(ratio - 1.0) <= 1e-9:
            return expr
        shown = written or scaled_label(dim)
        param = elab.parameters.get(sym.name) if sym is not None else None
        hint = (f"give {name} in {need}: {param.default:g} {shown} = {param.default * ratio:.4g} {need}"
                if param is not None and written else f"give it in {need}: multiply the number by {ratio:.4g}")
        b.error("PHC-E172", f"{what} is in {need}, but `{value}` is in {shown}: the same dimension in another "
                f"scale, and phc does not convert units (1 {shown} = {ratio:.4g} {need})", ctx, path, hint=hint)
        return expr

    def _pieces(self, b, ctx, pieces, path, scope) -> sp.Expr:
        args, last = [], None
        for i, piece in enumerate(pieces):
            expr = self._checked(b, ctx, piece.value, (*path, i, "value"),
                                 b.expr(ctx, piece.value, (*path, i, "value"), scope))
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
        # Relative to the file that names the table (a scene's own entries are located in
        # the scene), inside the top-level file's directory (phc.frontend.files).
        span = ctx.smap.locate((*path, "file"))
        referrer = span.file if span is not None and span.file else ctx.file
        files = getattr(b, "files", None) or FileAccess()
        try:
            _, real = files.resolve(referrer, spec.file, "table")
            data = files.read_bytes(real, spec.file, "table")
        except FileRefused as err:
            b.error("PHC-E213" if err.reason == "missing" else "PHC-E116", err.message, ctx, (*path, "file"),
                    hint=err.hint)
            return sp.Integer(0)
        units: dict = {}
        try:
            times, values = read_table(real, spec, data, units)
        except TableError as err:
            b.error("PHC-E213", str(err), ctx, (*path, "file"))
            return sp.Integer(0)
        if not self._check_units(b, ctx, spec, path, units):
            return sp.Integer(0)
        self.tables.append((times, values, spec.interpolation))
        points, kinks = table_breakpoints(times, values, spec.interpolation)
        self.breakpoints.update(points)
        if kinks > MAX_KINK_BREAKPOINTS:
            b.error("PHC-I214", f"table `{spec.file}` has {kinks:,} kinks (rows where the slope changes); "
                    f"above {MAX_KINK_BREAKPOINTS} they are not breakpoints: the solver's error control resolves "
                    "them instead of a restart at each", ctx, (*path, "file"), severity="info")
        elif spec.interpolation == "previous" and len(points) > MAX_KINK_BREAKPOINTS:
            b.error("PHC-I214", f"table `{spec.file}` (zero-order hold) jumps at {len(points):,} rows; each jump "
                    "is a breakpoint where the integrator restarts, which takes time", ctx, (*path, "file"),
                    severity="info", hint="use `interpolation: linear` for a sampled signal")
        return InputTable(sp.Integer(len(self.tables) - 1), T)


    def _check_units(self, b, ctx, spec: TableSpec, path, units: dict) -> bool:
        """The `[unit]` of a header must be the unit the model's numbers are in (phc does not
        convert units): the time column the model's time unit (s), the value column the
        effort or flow unit of the port's domain (Pa for a hydraulic effort). Refused at the
        `column:` (or `time_column:`) entry with PHC-E170/E172; False when refused."""
        from phc.frontend.units import UnitError, describe, have_pint, parse_unit, scale_factor, scaled_label, time_scale

        if not have_pint():
            return True
        ok = True
        for key, entry in (("time", "time_column"), ("value", "column")):
            header, text = units.get(key, (None, None))
            if text is None:
                continue
            where = (*path, entry) if entry in spec.model_fields_set else (*path, "file")
            try:
                got = parse_unit(text)
            except UnitError as err:
                b.error("PHC-E170", f"table `{spec.file}`, column `{header}`: {err.message}", ctx, where,
                        hint=err.hint)
                ok = False
                continue
            if key == "time":
                want, what = parse_unit("s") * 10.0 ** time_scale(self.scales), "the model's time"
            else:
                expected = self._want()
                if expected is None:
                    continue
                want, what = expected
            need = scaled_label(want)
            if got.dimensionality != want.dimensionality:
                b.error("PHC-E172", f"table `{spec.file}`, column `{header}` is in {describe(got, text)}, but "
                        f"{what} is in {describe(want)}", ctx, where,
                        hint=f"use the column that holds {what}, or correct the unit in the file's header")
                ok = False
            elif abs(scale_factor(got, want) - 1.0) > 1e-9:
                ratio = scale_factor(got, want)
                name = split_header(header)[0]
                b.error("PHC-E172", f"table `{spec.file}`, column `{header}` is in {text}, but {what} is in "
                        f"{need}: the same dimension in another scale, and phc does not convert units "
                        f"(1 {text} = {ratio:.4g} {need})", ctx, where,
                        hint=f"give the column in {need}: multiply its numbers by {ratio:.4g} and write "
                        f"`{name} [{need}]` in the header")
                ok = False
        return ok


def table_arrays(tables) -> list[str]:
    """Module constants for the input tables (see :class:`InputTable`)."""
    from phc.codegen.printer import _array  # long tables as packed bytes: literals compile slowly

    lines = []
    for k, (times, values, kind) in enumerate(tables):
        lines.append(f"_TABLE{k}_T = {_array(np.asarray(times, dtype=float).tolist(), 'float')}")
        lines.append(f"_TABLE{k}_V = {_array(np.asarray(values, dtype=float).tolist(), 'float')}")
        lines.append(f"_TABLE{k}_KIND = {kind!r}")
    return lines


__all__ = ["InputTable", "InputTableSlope", "SignalBuilder", "read_table", "table_arrays",
           "TableError", "table_breakpoints", "MAX_TABLE_ROWS", "MAX_KINK_BREAKPOINTS"]
