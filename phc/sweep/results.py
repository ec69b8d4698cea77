"""What a sweep writes: the columns of a row, the CSV append log, the report and the
Parquet copy.

Rows are appended to the CSV file as they arrive, each by one ``write`` of one complete
line to a file opened for appending, then flushed to disk (:class:`AppendLog`);
:func:`read_results` reads them back typed.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Sequence, Union

import numpy as np

from phc.inert import inert
from phc.io import atomic_write, csv_rows

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
        return int(value) if value else 0
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
        data = self.path.read_bytes()
        if not data.endswith(b"\n"):
            data = data[: data.rfind(b"\n") + 1]
        lines = csv_rows(io.StringIO(data.decode("utf-8", errors="replace")))  # messages of any length
        if not lines:
            return [], []
        header = lines[0]
        return header, [line for line in lines[1:] if len(line) == len(header)]

    def rewrite(self, rows: Sequence[Sequence]) -> None:
        with atomic_write(self.path) as fh:
            fh.write(_csv_line(self.columns))
            for row in rows:
                fh.write(_csv_line([_cell(v) for v in row]))


def _kinds(columns: Sequence[str]) -> dict[str, str]:
    kinds = {c: "float" for c in columns}
    kinds.update(point="int", steps="int", n_residual_evals="int", n_jacobian_evals="int", attempts="int",
                 success="bool", message="str", worker="str")
    return kinds


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
    rows: dict[int, dict] = field(default_factory=dict)
    """Point index -> row (typed values), the earlier rows of a resumed sweep included."""
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
        return [r for _, r in sorted(self.rows.items()) if not r["success"]]

    @property
    def complete(self) -> bool:
        return len(self.rows) == self.planned

    @property
    def success(self) -> bool:
        return self.complete and not self.failed and not self.interrupted

    def ordered(self) -> list[dict]:
        return [self.rows[i] for i in sorted(self.rows)]

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
        cpu = [r["cpu_time_s"] for r in self.rows.values() if not math.isnan(r["cpu_time_s"])]
        lines.append(f"  ran       {ran} run{'s' if ran != 1 else ''} on {self.executor} in {self.run_elapsed_s:.1f} s"
                     + (f" ({self.resumed} earlier rows kept)" if self.resumed else "")
                     + (f" ({self.retried} failed rows run again)" if self.retried else "")
                     + (f"; median {np.median(cpu):.3g} s CPU per run" if cpu else ""))
        ok = sum(1 for r in self.rows.values() if r["success"])
        lines.append(f"  results   {ok} succeeded, {len(self.rows) - ok} failed"
                     + (f", {self.planned - len(self.rows)} not run" if not self.complete else ""))
        for r in self.failed[:10]:
            values = ", ".join(f"{a.name} = {r[a.name]:.6g}" for a in d.axes)
            lines.append(f"  FAILED    point {r['point']} ({values}): {_short(r['message'])}")
        if len(self.failed) > 10:
            lines.append(f"  FAILED    ... and {len(self.failed) - 10} more (success = false in the results)")
        for key in ("csv", "parquet", "series", "meta", "plot"):
            if key in self.paths:
                lines.append(f"  wrote     {self.paths[key]}")
        if self.parquet_skipped:
            lines.append(f"  parquet   skipped: {self.parquet_skipped}")
        return "\n".join(inert(line) for line in lines)  # names, messages and paths (phc.inert)

    def summary(self) -> dict:
        return {"model": self.name, "file": self.file, "planned": self.planned, "rows": len(self.rows),
                "resumed": self.resumed, "retried": self.retried,
                "succeeded": sum(1 for r in self.rows.values() if r["success"]),
                "failed": len(self.failed), "interrupted": self.interrupted, "executor": self.executor,
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
    rows = report.ordered()
    fields, arrays = [], []
    for c in report.columns:
        meta = {"unit": report.units[c]} if c in report.units else None
        fields.append(pa.field(c, types[kinds[c]], metadata=meta))
        arrays.append(pa.array([r.get(c) for r in rows], type=types[kinds[c]]))
    table = pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata={
        "phc": json.dumps({"model": report.name, "file": report.file,
                           "axes": [{"name": a.name, "spec": a.text} for a in report.design.axes]})}))
    with atomic_write(path) as fh:
        pq.write_table(table, fh)


def read_results(path: Union[str, os.PathLike]) -> list[dict]:
    """The rows of a sweep's CSV file, typed (ints, bools, floats, strings)."""
    log = AppendLog(Path(path), [])
    header, lines = log.read()
    kinds = _kinds(header)
    return [{c: _parse(v, kinds[c]) for c, v in zip(header, line)} for line in lines]


def _short(text: str, n: int = 140) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 1] + "…"


__all__ = ["AppendLog", "INSTALL_PARQUET", "MACHINE_COLUMNS", "RUN_COLUMNS", "STATS", "SweepReport",
           "check_series_path", "parquet_available", "read_results", "result_columns", "results_paths",
           "write_parquet"]
