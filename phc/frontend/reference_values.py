"""Reference values of outputs at given times: what `phc bench` measures errors against
when a scene (``reference_values:``) or the command line (``--reference FILE.csv``) gives a
published reference solution or measurements instead of a closed form.

One mechanism, two spellings (:class:`phc.spec.scene.ReferenceValuesSpec`):

* a CSV file — a header row with the time column (``t`` unless ``time_column`` says
  otherwise) and one column per output, one row per time; lines whose first character
  (after blanks) is ``#`` are comments (where the source is cited); an empty cell is no
  value of that output at that time. A scene's file is resolved relative to the scene and
  read through :class:`phc.frontend.files.FileAccess` like an input table (inside the scene's or
  the model's directory, a regular file, at most the table size limit);
* inline — ``t: [...]`` and ``values: {output: [...]}`` (``null``: no value).

:func:`check` then requires every column to be a requested output and every time to lie
within the run (``t_start … t_end``). Problems are located diagnostics (PHC-E607): inside
the CSV file at the row and cell, or at the scene's entry; no message quotes a cell.
"""

from __future__ import annotations

import csv
import difflib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from phc.diagnostics import Diagnostic
from phc.errors import ReferenceValuesError
from phc.io import csv_rows
from phc.frontend.source import SourceSpan

CODE = "PHC-E607"
MAX_ROWS = 1_000_000
"""Most data rows of a reference-values file."""


@dataclass
class ReferenceValues:
    """Reference values by output: ``series[name] = (times, values)`` (finite values only)."""

    label: str
    """`crank_reference.csv` (the file as named) or `inline`."""
    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    source: str = ""
    locations: dict[str, SourceSpan] = field(default_factory=dict)
    """Where each output's column (or inline entry) is, for located errors."""
    time_locations: list[SourceSpan] = field(default_factory=list)
    """Where each time is (one per row or inline entry)."""
    times: np.ndarray = field(default_factory=lambda: np.empty(0))
    """All reference times, increasing."""

    def kind(self, output: str) -> str:
        """The reference kind `phc bench` reports for `output`."""
        n = len(self.series[output][0])
        return f"published reference ({self.label}, {n} point{'s' if n != 1 else ''})"


def parse_csv(data: bytes, name: str, shown: str, time_column: str = "t") -> ReferenceValues:
    """Reference values from the bytes of a CSV file; `name` is the file as written (for
    messages and the label), `shown` the path located diagnostics point into."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        raise ReferenceValuesError("reference values must be UTF-8 text",
                                   SourceSpan(shown, line, 1)) from None
    header: Optional[list[str]] = None
    header_line = 0
    columns: list[list[float]] = []
    times: list[float] = []
    where_t: list[SourceSpan] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        try:
            cells, offsets = _split(raw)
        except csv.Error as err:  # a NUL byte, for one
            raise ReferenceValuesError(f"this line is not valid CSV ({err})", SourceSpan(shown, lineno, 1)) from None
        if header is None:
            header = [c.strip().strip('"').strip() for c in cells]
            header_line = lineno
            if time_column not in header:
                close = difflib.get_close_matches(time_column, header, n=1)
                raise ReferenceValuesError(
                    f"no time column `{time_column}`; the first line that is not a comment must be the header of "
                    f"the reference values (columns: {', '.join(f'`{h}`' for h in header) or 'none'})",
                    SourceSpan(shown, lineno, 1),
                    hint=(f"did you mean `{close[0]}`? " if close else "")
                    + "name the time column `t` (or set `time_column`)")
            seen = set()
            for k, h in enumerate(header):
                if not h:
                    raise ReferenceValuesError(f"column {k + 1} of the header has no name",
                                               SourceSpan(shown, lineno, offsets[k] + 1))
                if h in seen:
                    raise ReferenceValuesError(f"column `{h}` appears twice in the header",
                                               SourceSpan(shown, lineno, offsets[k] + 1))
                seen.add(h)
            columns = [[] for _ in header]
            continue
        if len(cells) != len(header):
            raise ReferenceValuesError(f"this row has {len(cells)} cells, the header "
                                       f"{len(header)}", SourceSpan(shown, lineno, 1),
                                       hint="one cell per column; leave a cell empty for no value")
        if len(times) >= MAX_ROWS:
            raise ReferenceValuesError(f"more than {MAX_ROWS:,} rows of reference values",
                                       SourceSpan(shown, lineno, 1))
        for k, cell in enumerate(cells):
            cell = cell.strip().strip('"').strip()
            span = SourceSpan(shown, lineno, offsets[k] + 1)
            if not cell:
                if header[k] == time_column:
                    raise ReferenceValuesError(f"the time `{time_column}` is empty", span)
                columns[k].append(math.nan)
                continue
            try:
                value = float(cell)
            except ValueError:
                raise ReferenceValuesError(f"the cell of column `{header[k]}` is not a number", span, hint="write numbers; leave a cell empty for no value"
                                           ) from None
            if not math.isfinite(value):
                raise ReferenceValuesError(f"the cell of column `{header[k]}` must be finite", span, hint="leave the cell empty for no value")
            columns[k].append(value)
        times.append(columns[header.index(time_column)][-1])
        where_t.append(SourceSpan(shown, lineno, offsets[header.index(time_column)] + 1))
    if header is None or not times:
        raise ReferenceValuesError("reference values need a header row and at least one row of values",
                                   SourceSpan(shown, max(header_line, 1), 1))
    it = header.index(time_column)
    rv = ReferenceValues(label=name, time_locations=where_t)
    for k, h in enumerate(header):
        if k != it:
            rv.locations[h] = SourceSpan(shown, header_line, offsets_of(text, header_line, k) + 1)
    _fill(rv, np.array(times), {h: np.array(columns[k]) for k, h in enumerate(header) if k != it},
          lambda i: where_t[i])
    return rv


def from_spec(spec, smap) -> ReferenceValues:
    """Inline reference values of a scene (``t`` and ``values``), located through `smap`."""
    t = np.array(spec.t, dtype=float)
    rv = ReferenceValues(label="inline", time_locations=[smap.locate(("reference_values", "t", i))
                                                         for i in range(len(t))])
    cols = {}
    for name, vals in spec.values.items():
        rv.locations[name] = smap.locate_key(("reference_values", "values", name))
        if len(vals) != len(t):
            raise ReferenceValuesError(f"`{name}` has {len(vals)} value{'s' if len(vals) != 1 else ''}, `t` has "
                                       f"{len(t)}", smap.locate(("reference_values", "values", name)),
                                       hint="one value per time (`null` for no value)")
        cols[name] = np.array([math.nan if v is None else v for v in vals], dtype=float)
    _fill(rv, t, cols, lambda i: rv.time_locations[i])
    return rv


def _fill(rv: ReferenceValues, times: np.ndarray, cols: dict, where) -> None:
    bad = np.flatnonzero(np.diff(times) <= 0)
    if bad.size:
        raise ReferenceValuesError("reference times must increase strictly", where(int(bad[0]) + 1),
                                   hint="one row per time, in increasing order")
    rv.times = times
    for name, values in cols.items():
        ok = np.isfinite(values)
        if not ok.any():
            raise ReferenceValuesError(f"`{name}` has no reference value", rv.locations.get(name),
                                       hint="give values, or drop the column")
        rv.series[name] = (times[ok], values[ok])


def check(rv: ReferenceValues, outputs, t0: float, t1: float) -> None:
    """Every column is one of `outputs`, every time within ``[t0, t1]``."""
    for name in rv.series:
        if name not in outputs:
            close = difflib.get_close_matches(name, list(outputs), n=1)
            raise ReferenceValuesError(
                f"reference values for `{name}`, which is not a requested output", rv.locations.get(name),
                hint=(f"did you mean `{close[0]}`? " if close else "") + f"outputs: {', '.join(outputs) or 'none'}")
    slack = 1e-9 * max(abs(t0), abs(t1), t1 - t0)
    for i, t in enumerate(rv.times):
        if not t0 - slack <= t <= t1 + slack:
            raise ReferenceValuesError(f"reference time {t:g} lies outside the run ({t0:g} to {t1:g})",
                                       rv.time_locations[i] if i < len(rv.time_locations) else None,
                                       hint="give values within t_start … t_end, or extend the run (`t_end`)")


def for_scene(scene, files, outputs, t0: float, t1: float) -> ReferenceValues:
    """The scene's reference values, read (a file through `files`, a
    :class:`phc.frontend.files.FileAccess`) and checked against `outputs` and the run ``[t0, t1]``."""
    from phc.frontend.files import FileRefused

    spec = scene.spec.reference_values
    if spec.file is None:
        rv = from_spec(spec, scene.smap)
    else:
        try:
            shown, real = files.resolve(scene.path, spec.file, "table")
            data = files.read_bytes(real, spec.file, "table")
        except FileRefused as err:
            raise ReferenceValuesError(err.message.replace("table", "reference values", 1),
                                       scene.smap.locate(("reference_values", "file")), hint=err.hint) from None
        rv = parse_csv(data, spec.file, str(shown), spec.time_column)
    rv.source = spec.source or ""
    check(rv, outputs, t0, t1)
    return rv


def from_file(path, time_column: str = "t") -> ReferenceValues:
    """Reference values from a CSV file named on the command line (``phc bench --reference``):
    the user's own file, read as a regular file within the table size limit."""
    from phc.frontend.files import FileAccess, FileRefused

    path = Path(path)
    try:
        data = FileAccess().read_bytes(Path(os.path.realpath(path)), str(path), "table")
    except FileRefused as err:
        raise ReferenceValuesError(err.message.replace("table", "reference values", 1), hint=err.hint) from None
    return parse_csv(data, str(path), str(path), time_column)


def diagnostic(err: ReferenceValuesError) -> Diagnostic:
    return Diagnostic(CODE, err.message, span=err.span, hint=err.hint)


def _split(line: str) -> tuple[list[str], list[int]]:
    """Cells of a CSV line and their offsets (a quoted cell may hold a comma)."""
    cells = csv_rows([line])[0]  # cells of any length: a long one is "not a number", located
    offsets, pos = [], 0
    for cell in cells:
        offsets.append(pos)
        # advance past this cell (quoted or not) and its comma
        if pos < len(line) and line[pos] == '"':
            end = pos + 1
            while end < len(line):
                if line[end] == '"':
                    if end + 1 < len(line) and line[end + 1] == '"':
                        end += 2
                        continue
                    break
                end += 1
            nxt = line.find(",", end)
        else:
            nxt = line.find(",", pos)
        pos = len(line) if nxt < 0 else nxt + 1
    return cells, offsets


def offsets_of(text: str, lineno: int, k: int) -> int:
    return _split(text.splitlines()[lineno - 1])[1][k]


__all__ = ["ReferenceValues", "ReferenceValuesError", "parse_csv", "from_spec", "check", "for_scene", "from_file",
           "diagnostic", "CODE"]
