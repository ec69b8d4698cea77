"""What a sweep writes: the columns of a row, the CSV append log, the report and the
Parquet copy.

Rows are appended to the CSV file as they arrive, each by one ``write`` of one complete
line to a file opened for appending, then flushed to disk (:class:`AppendLog`);
:func:`read_results` reads them back typed.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Iterator, Optional, Sequence, Union

import numpy as np

from phc.inert import inert
from phc.io import _CSV_FIELD_LIMIT, _CSV_LOCK, atomic_write

if TYPE_CHECKING:
    from phc.sweep.design import Design

STATS = ("final", "min", "max", "rms")
RUN_COLUMNS = ("success", "message", "t_final", "steps", "n_residual_evals", "n_jacobian_evals",
               "energy_balance_error", "energy_balance_relative", "constraint_drift", "velocity_drift")
MACHINE_COLUMNS = ("cpu_time_s", "wall_time_s", "attempts", "worker")
"""Columns that differ between two runs of the same point (timing, where it ran)."""
INSTALL_PARQUET = 'pip install "port-hamiltonian-compiler[parquet]"'
_MEANING = {"point": "the index of the point", "success": "whether the run succeeded", "message": "the run's message",
            "t_final": "the time the run reached", "steps": "the solver's step count",
            "n_residual_evals": "the residual evaluations", "n_jacobian_evals": "the Jacobian evaluations",
            "energy_balance_error": "the energy-balance residual",
            "energy_balance_relative": "the relative energy-balance residual",
            "constraint_drift": "the position-constraint drift", "velocity_drift": "the velocity-constraint drift",
            "cpu_time_s": "the run's CPU time", "wall_time_s": "the run's wall time",
            "attempts": "the runs of the point", "worker": "where it ran"}


def result_columns(outputs: Sequence[str]) -> dict[str, str]:
    """Every column of a row besides the swept names -> what it holds (a swept name must be
    none of them: :func:`phc.sweep.design.make_design` refuses it)."""
    columns = {c: _MEANING[c] for c in ("point", *RUN_COLUMNS, *MACHINE_COLUMNS)}
    columns.update({f"{o}.{s}": f"the {s} of output `{o}`" for o in outputs for s in STATS})
    return columns


# ---------------------------------------------------------------------------------------
# result files


def _cell(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if value is None:
        return ""
    return str(value)


def _csv_line(cells: Sequence[str]) -> bytes:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue().encode()


def _parse(value: str, kind: str):
    if kind == "bool":
        return value.strip().lower() == "true"
    if kind == "int":
        if not value:
            return 0
        try:
            return int(value)
        except ValueError:  # "4.0"
            number = float(value)
            if number != int(number):
                raise
            return int(number)
    if kind == "str":
        return value
    return float(value) if value else math.nan


class AppendLog:
    """A CSV file written one complete line per ``write`` to a file opened for appending,
    flushed to disk after each: a killed process leaves whole rows (at most a torn last
    line, dropped by :meth:`load`)."""

    def __init__(self, path: Path, columns: Sequence[str]) -> None:
        self.path, self.columns = Path(path), list(columns)

    def create(self) -> None:
        with atomic_write(self.path) as fh:
            fh.write(_csv_line(self.columns))

    def append(self, rows: Sequence[Sequence]) -> None:
        data = b"".join(_csv_line([_cell(v) for v in row]) for row in rows)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)

    def read(self) -> tuple[list[str], list[list[str]]]:
        """(header, complete rows); a torn last line (no newline) is left out."""
        header, lines = self.iter_rows()
        return header, list(lines)

    def iter_rows(self) -> tuple[list[str], Iterator[list[str]]]:
        """(header, its complete rows one at a time): the file is read a line at a time (a
        torn last line, without its newline, is left out; rows of another length too)."""
        rows = iter_csv(self.path)
        header = next(rows, [])
        return header, (line for line in rows if len(line) == len(header))

    def rewrite(self, rows: Iterable[Sequence]) -> None:
        """The file replaced (atomically) by the header and `rows`, written as they come
        (`rows` may be read from this very file: the old one is replaced at the end)."""
        with atomic_write(self.path) as fh:
            fh.write(_csv_line(self.columns))
            for row in rows:
                fh.write(_csv_line([_cell(v) for v in row]))


def _kinds(columns: Sequence[str]) -> dict[str, str]:
    kinds = {c: "float" for c in columns}
    kinds.update(point="int", steps="int", n_residual_evals="int", n_jacobian_evals="int", attempts="int",
                 success="bool", message="str", worker="str")
    kinds.update({c: "int" for c in columns if c.startswith("accuracy.mesh.")})  # element counts
    return kinds


def iter_csv(path: Path) -> Iterator[list[str]]:
    """The rows of a CSV file one at a time, fields of any length (the csv module's limit
    is raised while a row is parsed and restored after: the process keeps its setting); a
    torn last line (no newline at the end of the file) is left out."""
    with open(path, encoding="utf-8", errors="replace", newline="") as fh:
        def lines():
            for line in fh:
                if line.endswith(("\n", "\r")):
                    yield line

        reader = csv.reader(lines())
        while True:
            with _CSV_LOCK:
                previous = csv.field_size_limit()
                csv.field_size_limit(max(previous, _CSV_FIELD_LIMIT))
                try:
                    row = next(reader, None)
                finally:
                    csv.field_size_limit(previous)
            if row is None:
                return
            yield row


class RowTable:
    """The rows of a sweep, point index -> row, held as typed columns (float, int and bool
    arrays, a list of strings) that grow by doubling: a million rows of a few dozen columns
    are tens of megabytes, not the gigabytes of a million dicts. Reading a row makes its
    dict; the mapping keeps the order rows were set in."""

    def __init__(self, columns: Sequence[str], kinds: Optional[dict] = None, capacity: int = 64) -> None:
        self.columns = list(columns)
        self.kinds = kinds or _kinds(self.columns)
        self._n = 0  # slots used (deleted rows included)
        self._live = 0
        self._cap = max(1, capacity)
        self._index = np.full(self._cap, -1, dtype=np.int64)  # slot -> point (-1: deleted)
        self._pos = np.full(0, -1, dtype=np.int64)  # point -> slot (-1: none), grown to the largest point
        dtypes = {"float": np.float64, "int": np.int64, "bool": np.bool_}
        self._data = {c: np.zeros(self._cap, dtype=dtypes[self.kinds.get(c, "float")])
                      if self.kinds.get(c, "float") in dtypes else [] for c in self.columns}
        self._strings: dict[str, dict] = {c: {} for c, col in self._data.items() if isinstance(col, list)}
        """Per text column, its values seen so far: one string object per value for the
        workers' names and the messages that repeat (a few thousand kept)."""

    def __len__(self) -> int:
        return self._live

    def __contains__(self, index) -> bool:
        try:
            return self._slot(int(index)) >= 0
        except (TypeError, ValueError):
            return False

    def _slot(self, index: int) -> int:
        return int(self._pos[index]) if 0 <= index < len(self._pos) else -1

    def _grow(self, index: int) -> None:
        if self._n == self._cap:
            self._cap *= 2
            self._index = np.concatenate([self._index, np.full(self._cap - len(self._index), -1, dtype=np.int64)])
            for c, col in self._data.items():
                if isinstance(col, np.ndarray):
                    self._data[c] = np.concatenate([col, np.zeros(self._cap - len(col), dtype=col.dtype)])
        if index >= len(self._pos):
            size = max(index + 1, 2 * len(self._pos), 64)
            self._pos = np.concatenate([self._pos, np.full(size - len(self._pos), -1, dtype=np.int64)])

    def __setitem__(self, index: int, row: dict) -> None:
        index = int(index)
        if index < 0:
            raise KeyError(index)
        slot = self._slot(index)
        if slot < 0:
            self._grow(index)
            slot = self._n
            self._n += 1
            self._live += 1
            self._index[slot] = index
            self._pos[index] = slot
            for col in self._data.values():
                if isinstance(col, list):
                    col.append("")
        for c, col in self._data.items():
            value = row.get(c, "")
            kind = self.kinds.get(c, "float")
            if kind == "str":
                text = "" if value is None else str(value)
                seen = self._strings[c]
                col[slot] = seen.get(text) or (seen.setdefault(text, text) if len(seen) < 4096 else text)
            elif kind == "bool":
                col[slot] = bool(value) if not isinstance(value, str) else value.strip().lower() == "true"
            elif kind == "int":
                col[slot] = int(value) if value not in ("", None) else 0
            else:
                col[slot] = float(value) if value not in ("", None) else math.nan

    def __getitem__(self, index: int) -> dict:
        slot = self._slot(int(index))
        if slot < 0:
            raise KeyError(index)
        return self._row(slot)

    def get(self, index: int, default=None):
        return self[index] if index in self else default

    def __delitem__(self, index: int) -> None:
        slot = self._slot(int(index))
        if slot < 0:
            raise KeyError(index)
        self._pos[index] = -1
        self._index[slot] = -1
        self._live -= 1

    def _row(self, slot: int) -> dict:
        row = {}
        for c, col in self._data.items():
            value = col[slot]
            kind = self.kinds.get(c, "float")
            row[c] = value if kind == "str" else bool(value) if kind == "bool" else \
                int(value) if kind == "int" else float(value)
        return row

    def _slots(self) -> np.ndarray:
        return np.flatnonzero(self._index[: self._n] >= 0)

    def __iter__(self) -> Iterator[int]:
        for slot in self._slots():
            yield int(self._index[slot])

    def keys(self) -> Iterator[int]:
        return iter(self)

    def values(self) -> Iterator[dict]:
        for slot in self._slots():
            yield self._row(int(slot))

    def items(self) -> Iterator[tuple[int, dict]]:
        for slot in self._slots():
            yield int(self._index[slot]), self._row(int(slot))

    def _ordered_slots(self) -> np.ndarray:
        slots = self._slots()
        return slots[np.argsort(self._index[slots], kind="stable")]

    def ordered(self) -> Iterator[dict]:
        """The rows in point order, one at a time."""
        for slot in self._ordered_slots():
            yield self._row(int(slot))

    def column(self, name: str) -> Union[np.ndarray, list]:
        """A column's values in point order."""
        slots = self._ordered_slots()
        col = self._data[name]
        return col[slots] if isinstance(col, np.ndarray) else [col[int(s)] for s in slots]

    def count(self, column: str, value) -> int:
        """Rows whose `column` equals `value` (``count("success", False)``: the failed rows)."""
        col = self._data[column]
        slots = self._slots()
        if isinstance(col, np.ndarray):
            return int(np.count_nonzero(col[slots] == value))
        return sum(1 for s in slots if col[int(s)] == value)

    @property
    def nbytes(self) -> int:
        """The bytes of its arrays (strings not counted)."""
        return int(self._index.nbytes + self._pos.nbytes +
                   sum(col.nbytes for col in self._data.values() if isinstance(col, np.ndarray)))


# ---------------------------------------------------------------------------------------
# the report


@dataclass
class SweepReport:
    """What :func:`run_sweep` did."""

    name: str
    file: str
    design: Design
    columns: list[str]
    units: dict[str, str]
    rows: Union[dict, RowTable] = field(default_factory=dict)
    """Point index -> row (typed values), the earlier rows of a resumed sweep included
    (:func:`~phc.sweep.run_sweep` holds them as a :class:`RowTable`)."""
    resumed: int = 0
    """Rows found in the results file and skipped."""
    retried: int = 0
    """Failed rows found in the results file and dropped to run their points again
    (``--retry-failed``)."""
    executor: str = ""
    workers_startup_s: float = math.nan
    compilations: list[dict] = field(default_factory=list)
    """Per compilation group: label, points, compile_time_s, error."""
    n_compilations: int = 1
    """Compilations made (the base model's, and one per group compiled with other values)."""
    paths: dict[str, Path] = field(default_factory=dict)
    parquet_skipped: str = ""
    interrupted: bool = False
    elapsed_s: float = 0.0
    run_elapsed_s: float = 0.0
    """Wall time from the first submission to the last row (workers' start included)."""

    @property
    def planned(self) -> int:
        return len(self.design.points)

    @property
    def failed(self) -> list[dict]:
        return list(self._failed())

    def _failed(self) -> Iterator[dict]:
        rows = self.rows.ordered() if isinstance(self.rows, RowTable) else (r for _, r in sorted(self.rows.items()))
        return (r for r in rows if not r["success"])

    @property
    def n_failed(self) -> int:
        if isinstance(self.rows, RowTable):
            return self.rows.count("success", False)
        return sum(1 for r in self.rows.values() if not r["success"])

    @property
    def complete(self) -> bool:
        return len(self.rows) == self.planned

    @property
    def success(self) -> bool:
        return self.complete and not self.n_failed and not self.interrupted

    def ordered(self) -> list[dict]:
        if isinstance(self.rows, RowTable):
            return list(self.rows.ordered())
        return [self.rows[i] for i in sorted(self.rows)]

    def _column(self, name: str) -> list:
        if isinstance(self.rows, RowTable):
            col = self.rows.column(name)
            return col.tolist() if isinstance(col, np.ndarray) else col
        return [r.get(name) for r in self.ordered()]

    def render_text(self) -> str:
        d = self.design
        what = ", ".join(f"{a.name} ({a.describe()})" for a in d.axes) or "no parameter (one run)"
        sampled = f"; {d.samples} {d.sampling} samples, seed {d.seed}" if d.samples else ""
        status = ("INTERRUPTED — finished rows kept, rerun with --resume" if self.interrupted else
                  "complete" if self.complete else "incomplete")
        lines = [f"{self.name}: sweep of {self.planned} runs over {what}{sampled} — {status}"]
        compile_s = sum({c["label"]: c["compile_time_s"] for c in self.compilations
                         if not math.isnan(c["compile_time_s"])}.values())
        n = self.n_compilations
        lines.append(f"  compiled  {n} compilation{'s' if n != 1 else ''} for {self.planned} runs ({compile_s:.2f} s)"
                     + "".join(f"; {c['label']}: FAILED" for c in self.compilations if c["error"]))
        ran = len(self.rows) - self.resumed
        cpu = [v for v in self._column("cpu_time_s") if not math.isnan(v)] if self.rows else []
        lines.append(f"  ran       {ran} run{'s' if ran != 1 else ''} on {self.executor} in {self.run_elapsed_s:.1f} s"
                     + (f" ({self.resumed} earlier rows kept)" if self.resumed else "")
                     + (f" ({self.retried} failed rows run again)" if self.retried else "")
                     + (f"; median {np.median(cpu):.3g} s CPU per run" if cpu else ""))
        n_failed = self.n_failed
        ok = len(self.rows) - n_failed
        lines.append(f"  results   {ok} succeeded, {n_failed} failed"
                     + (f", {self.planned - len(self.rows)} not run" if not self.complete else ""))
        for r in itertools.islice(self._failed(), 10):
            values = ", ".join(f"{a.name} = {r[a.name]:.6g}" for a in d.axes)
            lines.append(f"  FAILED    point {r['point']} ({values}): {_short(r['message'])}")
        if n_failed > 10:
            lines.append(f"  FAILED    ... and {n_failed - 10} more (success = false in the results)")
        for key in ("csv", "parquet", "series", "meta", "plot"):
            if key in self.paths:
                lines.append(f"  wrote     {self.paths[key]}")
        if self.parquet_skipped:
            lines.append(f"  parquet   skipped: {self.parquet_skipped}")
        return "\n".join(inert(line) for line in lines)  # names, messages and paths (phc.inert)

    def summary(self) -> dict:
        return {"model": self.name, "file": self.file, "planned": self.planned, "rows": len(self.rows),
                "resumed": self.resumed, "retried": self.retried,
                "succeeded": len(self.rows) - self.n_failed,
                "failed": self.n_failed, "interrupted": self.interrupted, "executor": self.executor,
                "elapsed_s": self.elapsed_s, "run_elapsed_s": self.run_elapsed_s,
                "compilations": [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in c.items()}
                                 for c in self.compilations], "n_compilations": self.n_compilations,
                "axes": [{"name": a.name, "spec": a.text} for a in self.design.axes],
                "samples": self.design.samples, "seed": self.design.seed, "sampling": self.design.sampling,
                "paths": {k: str(v) for k, v in self.paths.items()}, "parquet_skipped": self.parquet_skipped}


def results_paths(out: Union[str, os.PathLike]) -> dict[str, Path]:
    """The CSV file, the Parquet copy and the sidecar description of a results path
    (``x.csv`` or ``x.parquet`` → ``x.csv``, ``x.parquet``, ``x.sweep.json``)."""
    out = Path(out)
    stem = out.with_suffix("")
    return {"csv": stem.with_suffix(".csv"), "parquet": stem.with_suffix(".parquet"),
            "meta": stem.with_name(stem.name + ".sweep.json")}


def check_series_path(out: Union[str, os.PathLike], series: Union[None, str, os.PathLike]) -> None:
    """Refuse a time-series file that is one of the results' files (``--series r.csv`` with
    ``--out r.csv``, or with ``--out r.parquet``, whose CSV copy is ``r.csv``): one would
    overwrite the other."""
    from phc.errors import SweepSetupError

    if series is None or str(series) == "":
        return
    what = {"csv": "the results file", "parquet": "the Parquet copy of the results",
            "meta": "the description of the results"}
    for key, path in results_paths(out).items():
        if _same_file(Path(series), path):
            if key == "csv" and Path(out).suffix.lower() == ".parquet":
                where = f"`{path}`, the CSV copy of the results that --out `{out}` writes"
            else:
                where = f"{what[key]} (--out `{out}`)" if Path(out) == path else f"`{path}`, {what[key]}"
            raise SweepSetupError(f"--series `{series}` is {where}; give the time series a file of its own")


def _same_file(a: Path, b: Path) -> bool:
    """The same file: the same path once resolved (symbolic links, `..`), or, when both
    exist, the same inode (a hard link)."""
    if os.path.normcase(os.path.realpath(a)) == os.path.normcase(os.path.realpath(b)):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def parquet_available() -> bool:
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        return False
    return True


def write_parquet(report: SweepReport, path: Path) -> None:
    """The rows as a Parquet table (atomically), units in the fields' metadata."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    kinds = _kinds(report.columns)
    types = {"int": pa.int64(), "bool": pa.bool_(), "str": pa.string(), "float": pa.float64()}
    fields, arrays = [], []
    for c in report.columns:
        meta = {"unit": report.units[c]} if c in report.units else None
        fields.append(pa.field(c, types[kinds[c]], metadata=meta))
        arrays.append(pa.array(report._column(c), type=types[kinds[c]]))
    table = pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata={
        "phc": json.dumps({"model": report.name, "file": report.file,
                           "axes": [{"name": a.name, "spec": a.text} for a in report.design.axes]})}))
    with atomic_write(path) as fh:
        pq.write_table(table, fh)


def read_results(path: Union[str, os.PathLike]) -> list[dict]:
    """The rows of a sweep's CSV file, typed (ints, bools, floats, strings)."""
    header, lines = AppendLog(Path(path), []).iter_rows()
    kinds = _kinds(header)
    return [{c: _parse(v, kinds[c]) for c, v in zip(header, line)} for line in lines]


def _short(text: str, n: int = 140) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 1] + "…"


__all__ = ["AppendLog", "INSTALL_PARQUET", "MACHINE_COLUMNS", "RUN_COLUMNS", "RowTable", "STATS", "SweepReport",
           "check_series_path", "iter_csv", "parquet_available", "read_results", "result_columns", "results_paths",
           "write_parquet"]
