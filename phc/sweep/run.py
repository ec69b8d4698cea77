"""The sweep itself (:func:`run_sweep`): compile each group once, open the results files
(new or resumed), run the points on an executor and record their rows as they arrive."""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, Optional, Sequence, Union

from phc.errors import ModelError, SweepSetupError
from phc.io import atomic_write
from phc.sweep.design import MESH_PREFIX, Design, compile_group, group_label, make_design, sweep_axes
from phc.sweep.executors import _executor, _failed
from phc.sweep.results import (INSTALL_PARQUET, MACHINE_COLUMNS, RUN_COLUMNS, STATS, AppendLog, RowTable, SweepReport,
                               _kinds, _parse, check_series_path, parquet_available, results_paths, write_parquet)


def run_sweep(path: Union[str, os.PathLike], out: Union[str, os.PathLike], *,
              params: Sequence[tuple[str, str]] = (), samples: Optional[int] = None, seed: Optional[int] = None,
              sampling: Optional[str] = None, executor: Union[str, Any] = "local", scheduler: Optional[str] = None,
              workers: Optional[int] = None, series: Union[None, str, os.PathLike] = None, resume: bool = False,
              retry_failed: bool = False, overwrite: bool = False, t_end: Optional[float] = None,
              n_out: Optional[int] = None, solver: Optional[str] = None, certify: bool = True,
              progress: bool = True, stream=None, compiled=None) -> SweepReport:
    """Run a parameter study of a model or scene file; see the module docstring.

    Parameters
    ----------
    path
        Model or scene file (a scene's ``sweep:`` section gives the swept values).
    out
        Results file, ``.csv`` (also ``.parquet`` when pyarrow is installed) or
        ``.parquet`` (needs pyarrow; the CSV file is written too, as the append log).
    params
        ``(NAME, SPEC)`` pairs (:func:`phc.spec.sweep.parse_spec`), over the scene's.
    samples, seed, sampling
        Number of samples of the distributions, the sampler's seed (default 0) and
        ``"lhs"`` (default) or ``"random"``; over the scene's.
    executor
        ``"local"`` (a process pool of `workers`), ``"dask"`` (the scheduler at
        `scheduler`, else a LocalCluster of `workers`), or an executor object.
    series
        A CSV file for the time series of every run (long format: point, t, outputs).
    resume, overwrite
        Continue the results in `out` (its rows are kept and their points skipped; points
        without a row run), or replace them. Without either, an existing results file is an
        error. Resuming needs results of the same model (its generated code), swept values,
        run options and phc version (their description ``RESULTS.sweep.json`` says).
    retry_failed
        With `resume`: the failed rows are dropped and their points run again.
    t_end, n_out, solver
        Run options of every point (default: the model's or scene's).
    compiled
        The compiled model of `path` when the caller has it (it is compiled otherwise).

    Raises
    ------
    ModelError
        The model does not compile, or a located problem in the scene's sweep section.
    SweepSetupError
        A wrong name, SPEC or option; results that do not belong to this sweep.
    """
    from phc.codegen.load import source_hash
    from phc.pipeline import compile_model

    started = time.perf_counter()
    stream = stream or sys.stderr
    paths = results_paths(out)
    check_series_path(out, series)
    if retry_failed and not resume:
        raise SweepSetupError("--retry-failed needs --resume (it runs the failed points of existing results again)")
    want_parquet = Path(out).suffix.lower() == ".parquet"
    if want_parquet and not parquet_available():
        raise SweepSetupError(f"writing Parquet needs pyarrow: {INSTALL_PARQUET} (or give a .csv file)")
    if compiled is None:
        compiled = compile_model(path, certify=certify)
    axes, spec, locate = sweep_axes(compiled, params)
    if samples is None and spec is not None and any(a.sampled for a in axes):
        samples = spec.samples  # the scene's, when a distribution is left to sample
    design = make_design(compiled, axes, samples,
                         seed if seed is not None else (spec.seed if spec else 0),
                         sampling or (spec.sampling if spec else "lhs"), locate)
    run = {k: v for k, v in (("t_end", t_end), ("n_out", n_out), ("solver", solver)) if v is not None}
    outputs = list(compiled.module.OUTPUTS)
    names = [a.name for a in design.axes]
    columns = ["point", *names, *RUN_COLUMNS, *(f"{o}.{s}" for o in outputs for s in STATS), *MACHINE_COLUMNS]
    twice = sorted({c for c in columns if columns.count(c) > 1})
    if twice:  # make_design refuses a swept name that is a result column; outputs are unique
        raise SweepSetupError(f"the results would have two columns named `{twice[0]}`; rename the output or parameter")
    units = _units(compiled, design, outputs)
    report = SweepReport(compiled.name, str(path), design, columns, units, rows=RowTable(columns))
    runner = _executor(executor, scheduler, workers)  # a wrong --scheduler before any work
    series_path = Path(series) if series else None

    # -- compile each group once ----------------------------------------------------------
    models, failed_groups = {}, {}
    for group, count in design.group_counts().items():
        t = time.perf_counter()
        entry = {"label": group_label(group), "points": count,
                 "compile_time_s": compiled.compile_time if not group else math.nan, "error": ""}
        try:
            models[group] = compile_group(compiled, path, group, certify)
            if models[group] is not compiled:
                entry["compile_time_s"] = time.perf_counter() - t
                report.n_compilations += 1
            else:
                entry["compile_time_s"] = compiled.compile_time
        except ModelError as err:
            report.n_compilations += 1
            first = next((d.render() for d in err.diagnostics if d.severity == "error"), str(err))
            failed_groups[group] = entry["error"] = f"compilation failed: {first}"
        report.compilations.append(entry)
    fingerprint = _fingerprint(design, run, series_path, outputs)
    hashes = {group_label(g): source_hash(m.source) for g, m in models.items()}

    # -- the results files: new, or resumed --------------------------------------------------
    log = AppendLog(paths["csv"], columns)
    series_log = AppendLog(series_path, ["point", "t", *outputs]) if series_path else None
    meta = {"phc_version": _version(), "model": compiled.name, "file": str(path), "design": design.digest,
            "fingerprint": fingerprint,
            "models": hashes,
            "points": len(design.points), "axes": [{"name": a.name, "spec": a.text} for a in design.axes],
            "samples": design.samples, "seed": design.seed, "sampling": design.sampling, "run": run,
            "series": str(series_path) if series_path else None,
            "columns": {c: {"unit": units[c]} if c in units else {} for c in columns}}
    existing = paths["csv"].exists()
    if existing and not (resume or overwrite):
        raise SweepSetupError(f"`{paths['csv']}` exists; pass --resume to continue it (finished points are "
                              "skipped) or --overwrite to start over")
    if existing and resume:
        report.retried = _resume(log, paths["meta"], meta, series_log, report.rows, retry_failed)
        report.resumed = len(report.rows)
    else:
        log.create()
        if series_log is not None:
            series_log.create()
    with atomic_write(paths["meta"], "w") as fh:
        json.dump(meta, fh, indent=1)
    report.paths.update(csv=paths["csv"], meta=paths["meta"])
    if series_log is not None:
        report.paths["series"] = series_path

    # -- run ----------------------------------------------------------------------------
    bar = None
    if progress:
        from phc.progress import CountProgress

        bar = CountProgress(len(design.points), label=compiled.name, done=len(report.rows), stream=stream)

    sent: dict[int, dict] = {}  # the swept values of the points being run (not made again for their rows)

    def record(out_: dict) -> None:
        index = out_["index"]
        values = sent.pop(index, None)
        point = design.points[index] if values is None else None
        row = {"point": index, **(values if point is None else point.values), **out_["row"]}
        if series_log is not None and out_["series"] is not None:
            t, outs = out_["series"]
            series_log.append([[index, float(ti), *(float(outs[o][k]) for o in outputs)]
                               for k, ti in enumerate(t)])
        log.append([[row.get(c, "") for c in columns]])  # the row last: a row means its series is complete
        report.rows[index] = row
        if bar is not None:
            bar.advance(failed=not row["success"])

    def tasks():
        """The points still to run, made and checked one at a time as the executor takes
        them; a point the model file refuses (or of a group that did not compile) is
        recorded here as a failed row and not sent. The check's verdict travels with the
        task (``checked``): the workers' copies of the model were made before it."""
        for p in design.points:
            if p.index in report.rows:
                continue
            task = {"index": p.index, "group": p.group, "params": p.params, "options": p.options, "run": run,
                    "series": series_log is not None}
            refused = failed_groups.get(p.group)
            if not refused:
                refused, task["checked"] = _refused(models[p.group], p.params)
            if refused:
                record(_failed(task, refused, outputs))
            else:
                sent[p.index] = p.values
                yield task

    t_run = time.perf_counter()
    try:
        pending = tasks()
        first = next(pending, None)  # nothing to run (all done, all refused): no executor is started
        if first is not None:
            if bar is not None:
                bar.draw(force=True)
            results = runner.run(models, itertools.chain([first], pending), outputs)
            try:
                for result in results:
                    record(result)
            finally:
                results.close()  # stops the workers when interrupted
    except KeyboardInterrupt:
        report.interrupted = True
    finally:
        if bar is not None:
            bar.close()
    report.run_elapsed_s = time.perf_counter() - t_run
    report.workers_startup_s = runner.startup_s
    report.executor = runner.describe()
    if report.complete:
        log.rewrite([r.get(c, "") for c in columns] for r in report.rows.ordered())
    if parquet_available():
        write_parquet(report, paths["parquet"])
        report.paths["parquet"] = paths["parquet"]
    else:
        report.parquet_skipped = f"pyarrow is not installed ({INSTALL_PARQUET})"
    report.elapsed_s = time.perf_counter() - started
    return report


def _refused(compiled, params: dict) -> tuple[str, Optional[tuple]]:
    """Why the model file refuses a point's parameter values ("" when it does not), and the
    key under which :func:`phc.simulation.check_parameters` filed its verdict (None when the
    values needed no check): checked here, where the model's files are, by elaborating the
    model with them. Workers never read the model's files, so they may run anywhere (another
    directory, another machine); their copies of the model were made before this check, so
    the key travels with the point's task and the worker records the verdict
    (:func:`phc.sweep.executors.run_point`). The key is read off the verdicts the check
    files (set aside around it), so it is the check's own. The answer is not kept here: a
    million points would be a million entries."""
    from phc.errors import SimulationSetupError
    from phc.simulation import check_parameters

    cache = compiled.cache.parameter_checks
    kept = dict(cache)
    cache.clear()
    try:
        check_parameters(compiled, params)
    except SimulationSetupError as err:
        return str(err), None
    finally:
        filed = list(cache)
        cache.clear()
        cache.update(kept)
    return "", (filed[0] if filed else None)


def _version() -> str:
    from phc import __version__

    return __version__


def _fingerprint(design: Design, run: dict, series: Optional[Path], outputs) -> str:
    """The sweep's identity: its design's digest (a hash of its definition, equal digests
    mean equal points: :class:`~phc.sweep.design.Points`), run options, outputs."""
    h = hashlib.sha256()
    h.update(json.dumps({"design": design.digest, "points": len(design.points), "run": run,
                         "series": series is not None, "outputs": outputs}, sort_keys=True).encode())
    return h.hexdigest()[:32]


def _resume(log: AppendLog, meta_path: Path, meta: dict, series_log: Optional[AppendLog], rows: RowTable,
            retry_failed: bool = False) -> int:
    """The rows already in the results file put in `rows`, after checking they belong to
    this sweep (its description records the same model, design, run options and phc
    version), and how many failed rows were dropped to run again (`retry_failed`). The
    files are read and rewritten a row at a time."""
    try:
        old = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        raise SweepSetupError(f"cannot resume `{log.path}`: its description `{meta_path}` is missing or damaged; "
                              "pass --overwrite to start over") from None
    if not isinstance(old, dict) or not isinstance(old.get("models", {}), dict):
        raise SweepSetupError(f"cannot resume `{log.path}`: its description `{meta_path}` is not the description "
                              "of a sweep (a JSON object written by phc sweep); pass --overwrite to start over")
    why = _mismatch(old, meta)
    if why:
        raise SweepSetupError(f"cannot resume `{log.path}`: {why}; use another --out, or --overwrite to start over")
    try:
        header, lines = log.iter_rows()
    except OSError as err:
        raise SweepSetupError(f"cannot resume `{log.path}`: cannot read it ({err.strerror or err}); "
                              "pass --overwrite to start over") from None
    if header != log.columns:
        raise SweepSetupError(f"cannot resume `{log.path}`: its columns are not this sweep's; use --overwrite")
    kinds = _kinds(log.columns)
    try:
        for line in lines:
            try:
                row = {c: _parse(v, kinds[c]) for c, v in zip(header, line)}
            except ValueError:
                continue
            if 0 <= row["point"] < meta["points"]:
                rows[row["point"]] = row
    except csv.Error as err:
        raise SweepSetupError(f"cannot resume `{log.path}`: it is not a CSV file phc can read ({err}); "
                              "pass --overwrite to start over") from None
    retried = 0
    if retry_failed:
        failed = [i for i, r in rows.items() if not r["success"]]
        for i in failed:
            del rows[i]
        retried = len(failed)
    log.rewrite([r.get(c, "") for c in log.columns] for r in rows.values())  # drops a torn line
    if series_log is not None:
        if series_log.path.exists():
            _, kept = series_log.iter_rows()
            try:
                series_log.rewrite(s for s in kept if s and s[0].isascii() and s[0].isdigit() and int(s[0]) in rows)
            except csv.Error as err:
                raise SweepSetupError(f"cannot resume the time series `{series_log.path}`: it is not a CSV file phc "
                                      f"can read ({err}); pass --overwrite to start over") from None
        else:
            series_log.create()
    return retried


def _mismatch(old: dict, new: dict) -> str:
    """Why results described by `old` are not those of the sweep described by `new` ("" when
    they are): another phc version, model, generated code, swept values, run options."""
    def spec(axes) -> str:
        if not isinstance(axes, list) or not all(isinstance(a, dict) for a in axes):
            return "?"
        return ", ".join(f"{a.get('name')} = `{a.get('spec')}`" for a in axes) or "no parameter"

    if old.get("phc_version") != new["phc_version"]:
        return (f"its rows were computed by phc {old.get('phc_version') or '(unknown version)'}, this is phc "
                f"{new['phc_version']}")
    if "model" not in old:
        return "its description does not record the model (an older phc wrote it)"
    if old.get("model") != new["model"]:
        return f"it holds a sweep of model `{old.get('model')}`, not `{new['model']}`"
    if spec(old.get("axes")) != spec(new["axes"]):
        return f"it holds a different sweep (over {spec(old.get('axes'))}; this one: {spec(new['axes'])})"
    for key, what in (("samples", "number of samples"), ("seed", "seed"), ("sampling", "sampling"),
                      ("run", "run options")):
        if old.get(key) != new[key]:
            return f"it holds a different sweep (its {what}: {old.get(key)}; this one's: {new[key]})"
    if "design" not in old:
        return ("its description does not record the design's digest (an older phc wrote it, which recorded every "
                "point)")
    if old.get("design") != new["design"]:
        return "it holds a different sweep (other points)"
    if old.get("fingerprint") != new["fingerprint"]:
        return "it holds a different sweep (other points, outputs, or time series)"
    changed = sorted(set(old.get("models", {})) | set(new["models"]))
    changed = [label for label in changed if old.get("models", {}).get(label) != new["models"].get(label)]
    if changed:
        return (f"the model changed since its rows were computed (the generated code of {', '.join(changed)} "
                "differs)")
    return ""


def _units(compiled, design: Design, outputs) -> dict[str, str]:
    units = {"t_final": "s", "cpu_time_s": "s", "wall_time_s": "s", "accuracy.step": "s", "accuracy.rtol": "1"}
    for par in compiled.dae.parameters:
        if par.unit:
            units[par.name] = par.unit
    for name in design.kinds:
        if name.startswith(MESH_PREFIX):
            units[name] = "elements"
    kept = {k: v for k, v in units.items() if k in {a.name for a in design.axes} or k in RUN_COLUMNS + MACHINE_COLUMNS}
    labels = getattr(compiled.dae, "units", None) or {}
    for name in outputs:  # an output's statistics are in its unit (the plot's axes, Parquet metadata)
        if labels.get(name):
            kept.update({f"{name}.{stat}": labels[name] for stat in STATS})
    return kept


__all__ = ["run_sweep"]
