"""The `phc` command line: validate, check, graph, compile, simulate, sweep, schema.

Exit codes: 0 success, 1 model errors (or a failed simulation), 2 usage errors.
A user mistake never produces a traceback: it is printed as one located line per
problem. Set ``PHC_DEBUG=1`` to see tracebacks of internal errors.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import warnings
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Optional, Sequence

from phc import __version__
from phc import PhcError
from phc.errors import UsageError
from phc.names import RUN_LIMITS, option_problem

EXIT_OK, EXIT_MODEL, EXIT_USAGE = 0, 1, 2
EXIT_INTERRUPTED = 130
_python_showwarning = warnings.showwarning


def _print_diagnostics(diags, fmt: str = "text", stream=None) -> None:
    stream = stream or sys.stderr
    if fmt == "json":
        return
    for d in diags:
        print(d.render(), file=stream)


def _parse_params(items: Sequence[str]) -> dict[str, float]:
    out = {}
    for item in items or []:
        if "=" not in item:
            raise UsageError(f"--param expects NAME=VALUE, got `{item}`")
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise UsageError(f"--param {name}: `{value}` is not a number") from None
        if not math.isfinite(out[name.strip()]):
            raise UsageError(f"--param {name}: the value must be a finite number, got {value}")
    return out


# Numeric options, checked in one place before any work: (command, dest) -> (option, kind,
# low, high). Kinds: "positive" (finite, > 0, <= high), "fraction" (0 < x < 1), "count"
# (a whole number in [low, high]) (phc.names.option_problem). The run options' ranges are
# the model language's (phc.names.RUN_LIMITS, which phc.options.RunOptions checks too).
NUMERIC_OPTIONS = {
    ("simulate", "t_end"): ("--t-end", *RUN_LIMITS["t_end"]),
    ("simulate", "n_out"): ("--n-out", *RUN_LIMITS["n_out"]),
    ("simulate", "step"): ("--step", *RUN_LIMITS["step"]),
    ("simulate", "rtol"): ("--rtol", *RUN_LIMITS["rtol"]),
    ("simulate", "atol"): ("--atol", *RUN_LIMITS["atol"]),
    ("animate", "t_end"): ("--t-end", *RUN_LIMITS["t_end"]),
    ("animate", "magnify"): ("--magnify", "positive", 0, 1e6),
    ("animate", "frames"): ("--frames", "count", 1, 10_000),
    ("animate", "fps"): ("--fps", "count", 1, 100),
    ("bench", "tolerances"): ("--tol", *RUN_LIMITS["rtol"]),
    ("bench", "steps"): ("--step", *RUN_LIMITS["step"]),
    ("bench", "repeats"): ("--repeats", "count", 1, 1000),
    ("bench", "reference_rtol"): ("--reference-rtol", *RUN_LIMITS["rtol"]),
    ("check", "samples"): ("--samples", "count", 0, 1000),
    ("sweep", "samples"): ("--samples", "count", 1, 100_000),
    ("sweep", "workers"): ("--workers", "count", 1, 4096),
    ("sweep", "t_end"): ("--t-end", *RUN_LIMITS["t_end"]),
    ("sweep", "n_out"): ("--n-out", *RUN_LIMITS["n_out"]),
    ("linearize", "modes"): ("--modes", "count", 1, 1_000_000),
}

# Output paths, checked before any work: (command, dest) -> accepted extensions, or None
# for a folder (created if missing). "-" (stdout) is always accepted where it makes sense.
OUTPUT_OPTIONS = {
    ("simulate", "out"): ("--out", (".csv", ".npz")),
    ("simulate", "plot"): ("--plot", (".png", ".pdf", ".svg")),
    ("animate", "output"): ("-o", (".gif",)),
    ("graph", "output"): ("-o", (".dot", ".png")),
    ("compile", "output"): ("-o", None),
    ("bench", "out_dir"): ("--out-dir", None),
    ("sweep", "out"): ("--out", (".csv", ".parquet")),
    ("sweep", "series"): ("--series", (".csv",)),
    ("sweep", "plot"): ("--plot", (".png", ".pdf", ".svg")),
    ("linearize", "output"): ("-o", (".txt", ".json", ".npz")),
}


def _check_number(option: str, kind: str, low: float, high: float, value) -> None:
    problem = option_problem(kind, low, high, value)
    if problem:
        raise UsageError(f"{option} {problem}")


def _check_arguments(args) -> None:
    """Numeric options and output paths of the command, before any work (usage errors)."""
    from phc.io import OutputPathError, check_output_dir, check_output_file

    for (command, dest), (option, kind, low, high) in NUMERIC_OPTIONS.items():
        value = getattr(args, dest, None) if args.command == command else None
        for item in (value if isinstance(value, list) else [value] if value is not None else []):
            _check_number(option, kind, low, high, item)
    for (command, dest), (option, suffixes) in OUTPUT_OPTIONS.items():
        path = getattr(args, dest, None) if args.command == command else None
        if not path or path == "-" and command == "graph":
            continue
        try:
            if suffixes is None:
                check_output_dir(path, option)
            else:
                check_output_file(path, option, suffixes)
        except OutputPathError as err:
            raise UsageError(str(err)) from None


class _Files:
    """Several files of one command: each file's diagnostics, printed as they come in the
    text and GitHub formats (one located line, or one annotation, per problem) or at the
    end as one SARIF log or JSON list, and a summary line when there are several files."""

    def __init__(self, args, command: str) -> None:
        self.fmt, self.command = args.format, command
        self.diagnostics: dict[str, list] = {}
        self.failed: list[str] = []
        self.n = len(args.files)

    def report(self, path: str, diags, ok: bool) -> None:
        diags = list(diags)
        self.diagnostics.setdefault(path, []).extend(diags)
        if not ok:
            self.failed.append(path)
        if self.fmt == "text":
            _print_diagnostics(diags)
        elif self.fmt == "github":
            from phc.report_formats import github_annotations

            for line in github_annotations(diags, path):
                print(line)

    def status(self, line: str) -> None:
        """A file's own line (`x.yaml: ok (...)`): stdout, except beside a SARIF log."""
        if self.fmt in ("text", "github"):
            print(line)
        elif self.fmt == "sarif":
            print(line, file=sys.stderr)

    def finish(self) -> int:
        if self.fmt == "sarif":
            from phc.report_formats import sarif_log

            print(json.dumps(sarif_log(self.diagnostics, __version__, self.command), indent=2))
        if self.n > 1 and self.fmt != "json":
            counts = [sum(d.severity == s for ds in self.diagnostics.values() for d in ds)
                      for s in ("error", "warning")]
            text = (f"phc {self.command}: {self.n} files, {self.n - len(self.failed)} ok, {len(self.failed)} "
                    f"failed; {counts[0]} error(s), {counts[1]} warning(s)")
            if self.failed:
                text += " in " + ", ".join(self.failed[:5]) + (", …" if len(self.failed) > 5 else "")
            print(text, file=sys.stderr)  # stdout keeps one line per file (or the log alone)
        return EXIT_MODEL if self.failed else EXIT_OK


def _part_line(path: str, dae) -> str:
    names = ", ".join(dae.external_ports)
    n_components = len(dae.topology.components) if dae.topology is not None else 0
    return (f"{path}: part ok ({n_components} component(s); exposes {names}; its balance is checked in the "
            "model that uses it)")


def cmd_validate(args) -> int:
    from phc import fastpath

    files = _Files(args, "validate")
    report = []
    for path in args.files:
        kept = fastpath.lookup_validate(args, path) if args.format in ("text", "json") else None
        if kept is not None:  # an unchanged file: its result as stored (phc.fastpath)
            files.report(path, [fastpath.StoredDiagnostic(*d) for d in kept["diagnostics"]], kept["valid"])
            report.append({"file": path, "valid": kept["valid"], "kind": kept["kind"], "diagnostics": kept["json"]})
            if kept["status"] is not None:
                files.status(kept["status"])
            continue
        from phc import validate_file

        with fastpath.recording(args, path, "validate") as recorder:
            dae, diags, kind = validate_file(path)
        ok = dae is not None and not diags.has_errors
        files.report(path, diags, ok)
        report.append({"file": path, "valid": ok, "kind": kind, "diagnostics": diags.to_json()})
        status = None
        if ok and kind == "part":
            status = _part_line(path, dae)
        elif ok:
            status = (f"{path}: ok ({dae.n_states - 1} states, {len(dae.equations)} equations, "
                      f"{len(dae.variables)} unknowns)")
        if status is not None:
            files.status(status)
        recorder.store_validate({"valid": ok, "kind": kind, "json": report[-1]["diagnostics"], "status": status,
                                 "diagnostics": [[d.severity, d.render()] for d in diags]})
    if args.format == "json":
        print(json.dumps(report, indent=2))
    return files.finish()


def _certificate_line(compiled) -> str:
    cert = compiled.description.certificate  # the verdict (phc.description.Verdict)
    return f"  {cert.summary}" if cert is not None else "  not certified (--no-certify)"


def _backend_line(compiled, requested=None, kept: Optional[str] = None) -> str:
    """What runs the generated functions (phc.codegen.backends); `kept` is the line a
    cached front end printed before (phc.fastpath)."""
    if kept is not None:
        return kept
    from phc.codegen.backends import describe

    return f"  backend  {describe(compiled.module, requested)}"


MAX_FILE_STEM = 120
"""`phc compile` names the module after the model, shortened beyond this many characters
(with a hash of its source, so that two long names stay apart): file systems allow 255 bytes."""


def cmd_compile(args) -> int:
    from phc import ModelError, SimulationSetupError, compile_model
    from phc.io import write_text

    files = _Files(args, "compile")
    out_dir = Path(args.output)
    for path in args.files:
        try:
            compiled = compile_model(path, certify=not args.no_certify, backend=args.backend)
        except SimulationSetupError as err:  # --backend numba without numba
            raise UsageError(str(err)) from None
        except ModelError as err:
            files.report(path, err.diagnostics, False)
            continue
        files.report(path, [d for d in compiled.diagnostics if d.severity != "error"], True)
        out_dir.mkdir(parents=True, exist_ok=True)
        name = compiled.name
        if len(name) > MAX_FILE_STEM:
            import hashlib

            name = f"{name[:MAX_FILE_STEM - 17]}_{hashlib.sha256(name.encode()).hexdigest()[:16]}"
        target = write_text(out_dir / f"{name}.py", compiled.source)
        files.status(f"{path}: wrote {target} ({compiled.n_states} states, {compiled.n_equations} equations, "
                     f"{compiled.jacobian_nnz} Jacobian nonzeros, compiled in {compiled.compile_time:.2f} s)")
        for line in [_certificate_line(compiled), _backend_line(compiled, args.backend),
                     *_left_out_lines(compiled)]:
            files.status(line)
    return files.finish()


def _size_text(size: dict) -> str:
    return f"{size['states']} states, {size['equations']} equations, {size['jacobian_nnz']} Jacobian nonzeros"


def _left_out_lines(compiled) -> list[str]:
    """What a scene left out, and the compiled size against the full model."""
    lines = [f"  left out {comp}: {what} — {why}" for comp, what, why in compiled.left_out]
    full = compiled.full_size()
    if full is not None:
        lines.append(f"  full     model {compiled.description.scene.model}: {_size_text(full)}")
    return lines


def _compiled_json(compiled) -> dict:
    return {"compiled": {**compiled.size(), "compile_time_s": compiled.compile_time, "backend": compiled.backend},
            "full_model": compiled.full_size(),
            "left_out": [{"component": c, "what": w, "why": y} for c, w, y in compiled.left_out],
            **({"scene": compiled.description.scene.name} if compiled.description.scene is not None else {})}


def _csv_header(result, columns) -> list[str]:
    """Column names with their units where known: `t [s]`, `output.x [m]` (docs/units.md)."""
    units = dict(getattr(result, "units", None) or {})
    if units:
        units.setdefault("t", "s")
        if "H" in units:
            units.setdefault("P_ports", "W" if units["H"] == "J" else None)
            units.setdefault("P_diss", units["P_ports"])
            units.setdefault("energy_balance", units["H"])
    header = []
    for name in columns:
        unit = units.get(name.removeprefix("output.") if name.startswith("output.") else name)
        header.append(f"{name} [{unit}]" if unit else name)
    return header


def _write_results(result, path: str) -> None:
    columns = {"t": result.t}
    for j, name in enumerate(result.variables):
        columns[name] = result.y[:, j]
    for name, values in result.outputs.items():
        columns[f"output.{name}"] = values
    columns["H"] = result.H
    columns["P_ports"] = result.port_power
    columns["P_diss"] = result.dissipation
    columns["energy_balance"] = result.H - result.H[0] + result.energy_supplied
    import numpy as np

    from phc.io import atomic_write

    if path.endswith(".npz"):
        with atomic_write(path) as fh:
            np.savez(fh, **columns)
    elif path.endswith(".csv"):
        data = np.column_stack(list(columns.values())) if len(result.t) else np.zeros((0, len(columns)))
        with atomic_write(path) as fh:
            np.savetxt(fh, data, delimiter=",", header=",".join(_csv_header(result, columns)), comments="",
                       fmt="%.17g")
    else:
        raise UsageError(f"--out must end in .csv or .npz, got `{path}`")


def _summary_text(name: str, result) -> str:
    s = result.summary()
    lines = [
        f"{name}: {'success' if s['success'] else 'INTERRUPTED' if s.get('interrupted') else 'FAILED'} "
        f"— {s['message']}",
        f"  size     {s['n_states']} states, {s['n_equations']} equations; solver {s['solver']} "
        + (f"(fixed step {s['step']:.3g})" if s.get("step") else f"(rtol {s['rtol']:.1e}, atol {s['atol']:.1e})"),
        f"  work     {s['steps']} steps, {s['n_residual_evals']} residual and {s['n_jacobian_evals']} "
        f"Jacobian evaluations, {s['cpu_time_s']:.3f} s CPU, t_final {s['t_final']:.6g}",
        f"  energy   balance error {s['energy_balance_error']:.3e} (relative {s['energy_balance_relative']:.3e})",
        f"  drift    position constraints {s['constraint_drift']:.3e}, velocity constraints "
        f"{s['velocity_drift']:.3e}",
    ]
    if s["initial_choices"]:
        chosen = ", ".join(f"{k} = {v:.6g}" for k, v in s["initial_choices"].items())
        lines.append(f"  initial  chosen by consistent initialization: {chosen}")
    if s.get("reference_errors"):  # against the scene's closed forms (`reference:`)
        shown = ", ".join(f"{k} {v['max']:.3e} (relative {v['relative']:.3e})"
                          for k, v in s["reference_errors"].items())
        lines.append(f"  reference max |y − y_ref| over the output times: {shown}")
    events = s.get("events") or []
    if events:  # switches of non-smooth laws (docs/events.md)
        shown = "; ".join(_event_text(e) for e in events[:5])
        more = f"; … {len(events) - 5} more (--format json lists all)" if len(events) > 5 else ""
        lines.append(f"  events   {len(events)}: {shown}{more}")
    return "\n".join(lines)


def _event_text(e: dict) -> str:
    what = {"stick": "sticks", "slip": "slips " + ("+" if e["direction"] > 0 else "−")}.get(e["kind"])
    if what is None:
        what = (("turns true" if e["direction"] > 0 else "turns false") if e.get("comparison")
                else "rising" if e["direction"] > 0 else "falling")
    return f"t = {e['t']:.10g} `{e['condition']}` {what}" + (" (in t)" if e["kind"] == "time" else "")


class _Exit(Exception):
    """Leave a command with this exit code (the problem was already printed)."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


def _compile_or_exit(path: str, certify: bool = True, backend=None):
    """Compile a model or scene file; print its diagnostics and exit 1 on errors (a failed
    certificate of the compiled equations included, unless `certify` is off)."""
    from phc import ModelError, SimulationSetupError
    from phc import compile_model

    try:
        return compile_model(path, certify=certify, backend=backend)
    except SimulationSetupError as err:  # --backend numba without numba
        raise UsageError(str(err)) from None
    except ModelError as err:
        _print_diagnostics(err.diagnostics)
        raise _Exit(EXIT_MODEL) from None


def _progress_for(compiled, t_end, quiet: bool):
    from phc.progress import Progress

    opts = compiled.options
    end = t_end if t_end is not None else opts["t_end"]
    return Progress(opts["t_start"], end, label=compiled.name, enabled=not quiet)


_INCONSISTENT_HINT = "change the fixed initial values or mark one as a guess (`name: {value: ..., guess: true}`)"


def _initial_spans(compiled) -> dict:
    """Initial value name -> where the model (or scene) file gives it, in file order."""
    out = {}
    for item in compiled.description.initial if compiled is not None else ():
        if item.span is not None:
            out[item.name] = item.span
    return dict(sorted(out.items(), key=lambda kv: (str(kv[1].file), kv[1].line, kv[1].col)))


def _initial_spans_from_files(path: str) -> dict:
    """:func:`_initial_spans` read from the files themselves (when no compiled model is at
    hand): the scene's `initial:` entries, then its model's."""
    from phc.elaborate import load_spec
    from phc.scene import is_scene_file, load_scene

    out = {}
    model = path
    try:
        if is_scene_file(path):
            scene, _ = load_scene(path)
            if scene is None:
                return {}
            for name in scene.spec.initial:
                out[name] = scene.locate("initial", name)
            model = scene.model_path
        spec, smap, _ = load_spec(model)
        if spec is not None:
            for name in spec.simulation.initial:
                out.setdefault(name, smap.locate(("simulation", "initial", name)))
    except (OSError, ValueError, AttributeError):
        return out
    return out


_ACCURACY_KEYS = ("rtol", "atol", "step", "max_order")
"""Settings of a model's `simulation:` (a scene's `accuracy:`) that only some solvers use."""


def _written_options(path: str) -> dict[str, list[str]]:
    """The accuracy settings the model (or scene) file writes: name -> [where its key is,
    its entry], the scene's `accuracy:` over its model's `simulation:` (defaults the user
    did not write are not listed)."""
    from phc.elaborate import load_spec
    from phc.scene import is_scene_file, load_scene

    out: dict[str, list[str]] = {}
    model = path
    try:
        if is_scene_file(path):
            scene, _ = load_scene(path)
            if scene is None:
                return {}
            for key in _ACCURACY_KEYS:
                if getattr(scene.spec.accuracy, key) is not None:
                    out[key] = [str(scene.smap.locate_key(("accuracy", key))), f"accuracy.{key}"]
            model = scene.model_path
        spec, smap, _ = load_spec(model)
        if spec is not None:
            for key in _ACCURACY_KEYS:
                if key in spec.simulation.model_fields_set and getattr(spec.simulation, key) is not None:
                    out.setdefault(key, [str(smap.locate_key(("simulation", key))), f"simulation.{key}"])
    except (OSError, ValueError, AttributeError):
        return out
    return out


def _ignored_in_file_lines(compiled, written: dict, args) -> list[str]:
    """A located warning (PHC-W250) at each accuracy setting of the file that the solver of
    this run ignores (:func:`phc.simulation.backend.ignored_in_file`)."""
    from phc.simulation import BACKENDS
    from phc.simulation.backend import ignored_in_file, ignored_option_message

    backend = BACKENDS.get(args.solver or compiled.options.get("solver"))
    if backend is None or not written:
        return []
    given = {"rtol": args.rtol, "atol": args.atol, "step": args.step}
    lines = []
    for name in ignored_in_file(backend, written, given):
        where, entry = written[name]
        if backend.fixed_step:
            hint = (f"remove `{name}`, or write `step:` beside it (default: the output interval) to keep "
                    f"`{name}` for `--solver ida`")
        else:
            hint = ("`step` is for the fixed-step solvers: remove it, or write `rtol:` beside it to keep "
                    "`step` for `--solver midpoint`")
        lines.append(f"{where}: warning: {entry}: {ignored_option_message(backend, [name])}. hint: {hint} "
                     "[PHC-W250]")
    return lines


def _inconsistent_lines(path: str, problems: Sequence[str], compiled=None) -> list[str]:
    """One located line per violated equation (PHC-E218): at the first fixed initial value it
    involves, in the file's order, or at the file when none is located."""
    import re

    from phc.diagnostics import Diagnostic

    spans = _initial_spans(compiled) or _initial_spans_from_files(path)
    lines = []
    for k, problem in enumerate(problems):
        named = set(re.findall(r"`([^`]+)`", problem.split("fixed values involved:", 1)[-1])) \
            if "fixed values involved:" in problem else set()
        where = next((name for name in spans if name in named), None)
        hint = _INCONSISTENT_HINT if k == len(problems) - 1 else None
        if where is None:
            lines.append(f"{path}: inconsistent initial values: {problem}" + (f". hint: {hint}" if hint else "")
                         + " [PHC-E218]")
            continue
        d = Diagnostic("PHC-E218", f"inconsistent initial values: {problem}", span=spans[where], hint=hint,
                       path=f"simulation.initial.{where}")
        lines.append(d.render())
    return lines


@contextmanager
def _simulation_errors(path: str, progress, compiled=None):
    """Turn setup mistakes into usage errors and inconsistent initial values into located
    lines (PHC-E218, at the fixed initial value involved); the progress bar is closed
    either way."""
    from phc import InconsistentInitialError, SimulationSetupError
    from phc import ModelEvaluationError

    try:
        yield
    except InconsistentInitialError as err:
        progress.close()
        for line in _inconsistent_lines(path, err.problems, compiled):
            print(line, file=sys.stderr)
        raise _Exit(EXIT_MODEL) from None
    except SimulationSetupError as err:
        progress.close()
        raise UsageError(str(err)) from err
    except ModelEvaluationError as err:  # the model cannot be evaluated at the start
        progress.close()
        print(f"{path}: {err}", file=sys.stderr)
        raise _Exit(EXIT_MODEL) from None
    except KeyboardInterrupt:
        progress.close()
        raise
    progress.close()


def cmd_simulate(args) -> int:
    from phc import fastpath
    from phc.budget import format_bytes, peak_memory
    from phc.profile import profiled
    from phc import SimulationInterrupted, simulate

    params = _parse_params(args.param)
    hit = fastpath.lookup(args, params)  # an unchanged model: its cached front end (phc.fastpath)
    if hit is not None:
        compiled, written, backend_line = hit.compiled, hit.written_options, hit.backend_line
    else:
        backend_line = None
        with fastpath.recording(args) as recorder:
            compiled = _compile_or_exit(args.file, certify=not args.no_certify, backend=args.backend)
            first = compiled
            compiled = _recompile_for_params(compiled, args.file, params, certify=not args.no_certify)
        written = _written_options(args.file)
        if compiled is first:
            recorder.store(compiled, written)  # kept in the cached front end
    if args.format != "json":  # the model's warnings, as `phc validate` prints them (also from the cache)
        _print_diagnostics([d for d in compiled.diagnostics if d.severity == "warning"])
    for line in _ignored_in_file_lines(compiled, written, args):
        print(line, file=sys.stderr)  # settings of the file this run's solver ignores (PHC-W250)
    progress = _progress_for(compiled, args.t_end, args.quiet)
    run_kwargs = dict(t_end=args.t_end, params=params, rtol=args.rtol, atol=args.atol, n_out=args.n_out,
                      solver=args.solver, step=args.step)
    estimates, prof, interrupted = [], None, False
    with _simulation_errors(args.file, progress, compiled):
        try:  # Ctrl-C: keep what was computed (written below), exit 130
            from phc.simulation import check_parameters

            check_parameters(compiled, params, label=lambda name, value: f"--param {name}={value:g}", path=args.file)
            with (profiled(compiled) if args.profile else nullcontext()) as prof:
                result = simulate(compiled, progress=progress, **run_kwargs)
        except SimulationInterrupted as stop:
            result, interrupted = stop.result, True
        if prof is not None:
            prof.run_cpu = result.cpu_time_s
        if args.estimate_error and not interrupted:
            progress.close()
            if not args.quiet:
                print(f"{args.file}: estimating errors (a rerun with a finer step or tolerance, and one on "
                      "refined meshes)...", file=sys.stderr)
            from phc import estimate_errors

            try:
                estimates = estimate_errors(compiled, result, run_kwargs)
            except KeyboardInterrupt:
                interrupted = True
                print(f"{args.file}: error estimation interrupted; the run itself is complete", file=sys.stderr)
    if args.out:
        _write_results(result, args.out)
    if args.plot:
        _plot(result, args.plot, compiled.name)
    if args.format == "json":
        summary = result.summary()
        summary["peak_memory_bytes"] = peak_memory()
        summary["model"] = compiled.description.model
        summary["compile_time_s"] = compiled.compile_time
        summary.update(_compiled_json(compiled))
        verdict = compiled.description.certificate
        summary["certificate"] = verdict.to_dict() if verdict is not None else None
        if args.estimate_error:
            summary["error_estimates"] = [e.to_dict() for e in estimates]
        if prof is not None:
            summary["profile"] = prof.to_dict()
        if args.out:
            summary["output_file"] = args.out
        if args.plot:
            summary["plot_file"] = args.plot
        print(json.dumps(summary, indent=2))
    else:
        label = (f"{compiled.name} (scene of {compiled.description.model})" if compiled.description.scene
                 else compiled.name)
        print(_summary_text(label, result))
        print(f"  memory   peak {format_bytes(peak_memory())} resident")
        print(f"  compiled {_size_text(compiled.size())} in {compiled.compile_time:.2f} s")
        print(_certificate_line(compiled))
        print(_backend_line(compiled, args.backend, backend_line))
        for line in _left_out_lines(compiled):
            print(line)
        for e in estimates:
            if not e.ok and not e.per_output:  # no rerun to compare with (e.g. per-dof initial values)
                print(f"  error    {e.kind}: {e.method}: {e.message}")
                continue
            worst = max(e.per_output, key=e.per_output.get) if e.per_output else "-"
            status = "" if e.ok else f" (the rerun failed: {e.message})"
            print(f"  error    {e.kind} ≈ {e.max:.3e} (largest in `{worst}`): {e.method}{status}")
        if prof is not None:
            print(prof.render_text())
        if args.out:
            print(f"  wrote    {args.out}")
        if args.plot:
            print(f"  plotted  {args.plot}")
    if interrupted:
        kept = [f for f in (args.out, args.plot) if f]
        where = f"; the results so far are in {' and '.join(kept)}" if kept else " (no --out given: nothing written)"
        reached = f"t = {result.t[-1]:.6g}" if len(result.t) else "the start"
        print(f"phc simulate: interrupted at {reached}{where}", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_OK if result.success else EXIT_MODEL


def _recompile_for_params(compiled, path: str, params: dict, certify: bool = True):
    """A `--param` of a compile-time parameter (a mesh length, a coefficient varying along
    a distributed component): the model recompiled with it, and a note saying so."""
    from phc import ModelError, SimulationSetupError
    from phc.sweep import recompile_for

    try:
        compiled, note = recompile_for(compiled, path, params, certify=certify)
    except SimulationSetupError as err:
        raise UsageError(str(err)) from None
    except ModelError as err:
        _print_diagnostics(err.diagnostics)
        raise _Exit(EXIT_MODEL) from None
    if note:
        print(f"{path}: note: {note}", file=sys.stderr)
    return compiled


def cmd_sweep(args) -> int:
    from phc import ModelError, SimulationSetupError
    from phc.sweep import plot_sweep, run_sweep

    pairs = []
    for item in args.param or []:
        name, sep, spec = item.partition("=")
        if not sep or not name.strip():
            raise UsageError(f"--param expects NAME=SPEC, got `{item}`")
        pairs.append((name.strip(), spec))
    compiled = _compile_or_exit(args.file, certify=not args.no_certify, backend=args.backend)
    try:
        report = run_sweep(args.file, args.out, params=pairs, samples=args.samples, seed=args.seed,
                           sampling=args.sampling, executor=args.executor, scheduler=args.scheduler,
                           workers=args.workers, series=args.series, resume=args.resume, overwrite=args.overwrite,
                           t_end=args.t_end, n_out=args.n_out, solver=args.solver, certify=not args.no_certify,
                           progress=not args.quiet, compiled=compiled)
        if args.plot and report.rows:
            plot_sweep(report, args.plot, args.plot_output,
                       [a.strip() for a in args.plot_against.split(",")] if args.plot_against else None)
            report.paths["plot"] = Path(args.plot)
    except ModelError as err:
        _print_diagnostics(err.diagnostics)
        return EXIT_MODEL
    except SimulationSetupError as err:
        raise UsageError(str(err)) from None
    print(report.render_text() if args.format == "text" else json.dumps(report.summary(), indent=2))
    if report.interrupted:
        print(f"phc sweep: interrupted; {len(report.rows)} of {report.planned} rows are in {report.paths['csv']}: "
              "rerun the same command with --resume to finish", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_OK if report.success else EXIT_MODEL


def _plot(result, path: str, title: str) -> None:
    from phc import viz

    try:
        viz.plot_outputs(result, path, title=title)
    except viz.PlotUnavailable as err:
        raise UsageError(str(err)) from err


def _solver_names() -> tuple[str, ...]:
    from phc.names import SOLVER_NAMES

    return SOLVER_NAMES


def cmd_animate(args) -> int:
    from phc import viz
    from phc import SimulationInterrupted, simulate

    compiled = _compile_or_exit(args.file, certify=not args.no_certify)
    progress = _progress_for(compiled, args.t_end, args.quiet)
    interrupted = False
    with _simulation_errors(args.file, progress, compiled):
        try:
            result = simulate(compiled, t_end=args.t_end, progress=progress)
        except SimulationInterrupted as stop:  # Ctrl-C: animate what was computed, exit 130
            result, interrupted = stop.result, True
    if not result.success:
        print(f"{args.file}: simulation stopped: {result.message}; animating the results so far", file=sys.stderr)
    try:
        viz.animate(compiled, result, args.output, magnify=args.magnify, fps=args.fps, max_frames=args.frames)
    except viz.PlotUnavailable as err:
        raise UsageError(str(err)) from err
    print(f"{args.file}: wrote {args.output}")
    if interrupted:
        return EXIT_INTERRUPTED
    return EXIT_OK if result.success else EXIT_MODEL


def cmd_bench(args) -> int:
    from phc.bench import parse_meshes, run_bench
    from phc import ModelError, SimulationSetupError

    try:
        report = run_bench(args.scene, solvers=args.solvers, tolerances=args.tolerances, steps=args.steps,
                           meshes=parse_meshes(args.mesh), repeats=args.repeats, out_dir=args.out_dir,
                           reference_cache=False if args.no_cache else None, progress=not args.quiet,
                           plot=not args.no_plot, outputs=args.outputs, reference_rtol=args.reference_rtol,
                           reference=args.reference)
    except ModelError as err:
        _print_diagnostics(err.diagnostics)
        return EXIT_MODEL
    except SimulationSetupError as err:
        raise UsageError(str(err)) from err
    print(report.render_text() if args.format == "text" else json.dumps(report.summary(), indent=2))
    if report.interrupted:
        return 130
    return EXIT_OK if report.success else EXIT_MODEL


def cmd_check(args) -> int:
    import phc
    from phc import validate_file

    files = _Files(args, "check")
    reports = []
    for path in args.files:
        report = phc.certify_model(path, samples=args.samples)
        if report.structure is None and any(d.code == "PHC-E216" for d in report.diagnostics):
            # a part (`kind: part`): validated as a part, certified in the model that uses it
            dae, diags, _ = validate_file(path)
            ok = dae is not None and not diags.has_errors
            files.report(path, diags, ok)
            reports.append({"model": path, "kind": "part", "valid": ok, "certified": None,
                            "diagnostics": diags.to_json()})
            if ok:
                files.status(_part_line(path, dae) + "; certified there too")
            continue
        reports.append(report.to_dict())
        if report.structure is None:
            files.report(path, report.diagnostics, False)
            continue
        if args.format == "text":
            print(report.render_text())  # the certificate, its diagnostics at the end
            files.diagnostics[path] = list(report.diagnostics)
            if not report.certified:
                files.failed.append(path)
        else:
            files.report(path, report.diagnostics, report.certified)
            files.status(f"{path}: {'certified' if report.certified else 'NOT certified'}")
    if args.format == "json":
        print(json.dumps(reports[0] if len(reports) == 1 else reports, indent=2))
    return files.finish()


def _parse_assignments(items: Sequence[str], option: str) -> dict[str, float]:
    """NAME=VALUE pairs of a repeatable option (numbers only: nothing is evaluated)."""
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise UsageError(f"{option} expects NAME=VALUE, got `{item}`")
        try:
            number = float(value)
        except ValueError:
            raise UsageError(f"{option} {name.strip()}: `{value}` is not a number") from None
        if not math.isfinite(number):
            raise UsageError(f"{option} {name.strip()}: the value must be a finite number, got {value}")
        out[name.strip()] = number
    return out


def cmd_linearize(args) -> int:
    from types import SimpleNamespace

    from phc import ModelError, linearize_model

    fmt = args.format or {".json": "json", ".npz": "npz"}.get(Path(args.output or "").suffix.lower(), "text")
    if fmt == "npz" and not args.output:
        raise UsageError("--format npz needs -o OUT.npz")
    if args.at is not None and not math.isfinite(args.at):
        raise UsageError(f"--at must be a finite time, got {args.at:g}")
    mesh = {}
    for name, count in _parse_assignments(args.mesh, "--mesh").items():
        if count != int(count) or count < 1:
            raise UsageError(f"--mesh {name}: the element count must be a whole number from 1 on, got {count:g}")
        mesh[name] = int(count)
    with _simulation_errors(args.file, SimpleNamespace(close=lambda: None)):
        try:
            lin = linearize_model(args.file, at=args.at, state=_parse_assignments(args.state, "--state"),
                                  params=_parse_params(args.param), mesh=mesh, certify=not args.no_certify)
        except ModelError as err:
            _print_diagnostics(err.diagnostics)
            return EXIT_MODEL
    if fmt == "npz":
        lin.save_npz(args.output)
        print(f"{lin.model}: {len(lin.eigenvalues)} finite eigenvalues; wrote {args.output}")
        return EXIT_OK
    text = json.dumps(lin.to_dict(), indent=2) if fmt == "json" else lin.render_text(args.modes)
    if args.output:
        Path(args.output).write_text(text + "\n", encoding="utf-8")
        print(f"{lin.model}: {len(lin.eigenvalues)} finite eigenvalues; wrote {args.output}")
    else:
        print(text)
    return EXIT_OK


def cmd_graph(args) -> int:
    from phc.checks.graph import to_dot
    from phc import build_dae

    dae, diags = build_dae(args.file)
    if dae is None:
        _print_diagnostics(diags)
        return EXIT_MODEL
    dot = to_dot(dae.topology, dae.name)
    if not args.output or args.output == "-":
        sys.stdout.write(dot)
        return EXIT_OK
    if args.output.endswith(".dot"):
        from phc.io import write_text

        write_text(args.output, dot)
    elif args.output.endswith(".png"):
        _draw_png(dae, args.output)
    else:
        raise UsageError(f"-o must end in .dot or .png, got `{args.output}`")
    print(f"{args.file}: wrote {args.output}")
    return EXIT_OK


def _draw_png(dae, path: str) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise UsageError("drawing PNG needs matplotlib: pip install 'port-hamiltonian-compiler[plot]' (or write DOT with -o file.dot)")
    import networkx as nx

    from phc.checks.graph import component_graph

    graph = component_graph(dae.topology)
    fig, ax = plt.subplots(figsize=(8, 6))
    pos = nx.spring_layout(graph, seed=1)
    nx.draw_networkx(graph, pos, ax=ax, node_color="#cfe2f3", node_size=1600, font_size=9)
    labels = {(u, v): d["label"] for u, v, d in graph.edges(data=True)}
    nx.draw_networkx_edge_labels(graph, pos, edge_labels=labels, ax=ax, font_size=7)
    ax.set_title(f"{dae.name}: interconnection graph")
    ax.axis("off")
    from phc.io import atomic_write

    with atomic_write(path) as fh:
        fig.savefig(fh, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)


def cmd_schema(args) -> int:
    from phc.spec.export import SCHEMAS, schema_text, stale_schemas, write_schemas

    if args.check:
        stale = stale_schemas(args.dir)
        if stale:
            for path in stale:
                print(f"{path}: stale or missing; regenerate with `phc schema --write --dir {args.dir}`",
                      file=sys.stderr)
            return EXIT_MODEL
        print(f"{args.dir}: schemas up to date ({', '.join(SCHEMAS)})")
        return EXIT_OK
    if args.write:
        for path in write_schemas(args.dir):
            print(f"wrote {path}")
        return EXIT_OK
    name = args.name if args.name.endswith(".schema.json") else f"{args.name}.schema.json"
    sys.stdout.write(schema_text(name))
    return EXIT_OK


def cmd_cache(args) -> int:
    from phc.codegen import load

    if args.action == "clean":
        files, size = load.clean()
        print(f"{load.cache_dir()}: removed {files} files ({size / 2**20:.1f} MiB)")
        return EXIT_OK
    info = load.info()
    print(f"{info.path}: {info.files} files, {info.bytes / 2**20:.1f} MiB "
          f"(cap {info.cap_bytes / 2**20:.0f} MiB, PHC_CACHE_MAX_MB; least recently used evicted first)")
    return EXIT_OK


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """phc's own warnings as one line `phc: warning: ...`; others as Python prints them."""
    from phc import PhcWarning

    if issubclass(category, PhcWarning):
        print(f"phc: warning: {message}", file=sys.stderr)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


def _allowed_paths(args):
    """Files under each `--allow-path DIR` may be referenced too (see phc.files)."""
    from phc.files import allow_paths

    dirs = getattr(args, "allow_path", None) or []
    for d in dirs:
        if not Path(d).is_dir():
            raise UsageError(f"--allow-path `{d}` is not a directory")
    return allow_paths(dirs)


def _memory_size(text: str) -> int:
    from phc.budget import parse_size

    try:
        return parse_size(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _with_budget(func):
    """Run a command under its `--max-memory` budget (see phc.budget)."""

    def run(args) -> int:
        from phc import budget

        with budget.override(args.max_memory):
            try:
                budget.max_memory()
            except ValueError as err:  # a malformed PHC_MAX_MEMORY
                raise UsageError(str(err)) from None
            return func(args)

    return run


FORMAT_HELP = ("text: one located line per problem; json; github: GitHub Actions annotations "
               "(::error file=...,line=...,col=...::message); sarif: one SARIF 2.1.0 log on stdout for code "
               "scanning (github/codeql-action/upload-sarif)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="phc", description="Compiler for port-Hamiltonian models.")
    parser.add_argument("--version", action="version", version=f"phc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("validate", help="check model files (schema, names, expressions, structure); a part "
                       "(`kind: part`) without closing its exposed ports")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--format", choices=("text", "json", "github", "sarif"), default="text", help=FORMAT_HELP)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("compile", help="generate the residual module of each model")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--format", choices=("text", "github", "sarif"), default="text", help=FORMAT_HELP)
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("-o", "--output", default=".", metavar="DIR", help="directory for the generated module")
    p.add_argument("--backend", choices=("auto", "numpy", "numba"),
                   help="what runs the generated functions: numba (machine code, cached; pip install "
                   "'port-hamiltonian-compiler[fast]'), numpy, or auto (numba for models of 16 unknowns or "
                   "more when installed; the default, or $PHC_BACKEND)")
    p.set_defaults(func=cmd_compile)

    p = sub.add_parser("simulate", help="compile and simulate a model or a scene")
    p.add_argument("file", metavar="FILE", help="a model file, or a scene file (models/scenes/*.yaml)")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("--t-end", type=float, help="end time (default: the model's simulation.t_end)")
    p.add_argument("--n-out", type=int, help="number of output points")
    p.add_argument("--solver", choices=_solver_names(), help="integrator (default: the model's)")
    p.add_argument("--step", type=float, help="step size of the midpoint solver")
    p.add_argument("--backend", choices=("auto", "numpy", "numba"),
                   help="what runs the generated functions: numba (machine code, cached; pip install "
                   "'port-hamiltonian-compiler[fast]'), numpy, or auto (numba for models of 16 unknowns or "
                   "more when installed; the default, or $PHC_BACKEND)")
    p.add_argument("--rtol", type=float)
    p.add_argument("--atol", type=float)
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="override a parameter (repeatable)")
    p.add_argument("--out", metavar="FILE", help="write results to FILE (.csv or .npz)")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--plot", metavar="OUT.png", help="draw the requested outputs over time (needs the `plot` extra: pip install 'port-hamiltonian-compiler[plot]')")
    p.add_argument("--estimate-error", action="store_true",
                   help="estimate the temporal (finer step/tolerance) and spatial (refined meshes) errors of the "
                   "outputs by Richardson extrapolation from reruns")
    p.add_argument("--profile", action="store_true",
                   help="break the CPU time into compile stages, residual and Jacobian evaluations and solver work")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("animate", help="simulate and draw the planar mechanism frame by frame (GIF)")
    p.add_argument("file", metavar="FILE", help="a scene or model file")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("-o", "--output", metavar="OUT.gif", required=True)
    p.add_argument("--magnify", type=float, default=1.0, help="magnify the beam deflection in the picture")
    p.add_argument("--frames", type=int, default=100, help="at most this many frames")
    p.add_argument("--fps", type=int, default=20)
    p.add_argument("--t-end", type=float)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_animate)

    p = sub.add_parser("bench", help="work-precision study of a scene: error vs CPU time across solvers, "
                       "tolerances and meshes (CSV, Markdown, PNG)")
    p.add_argument("scene", metavar="SCENE")
    p.add_argument("--solver", action="append", dest="solvers", choices=_solver_names(),
                   help="solver to sweep (repeatable; default: the scene's bench.solvers, else all)")
    p.add_argument("--tol", action="append", type=float, dest="tolerances", help="rtol of IDA (repeatable)")
    p.add_argument("--step", action="append", type=float, dest="steps", help="step of fixed-step solvers (repeatable)")
    p.add_argument("--mesh", action="append", metavar="COMP=N1,N2,...", help="element counts to sweep (repeatable)")
    p.add_argument("--repeats", type=int, help="runs per point; the minimum CPU time is reported")
    p.add_argument("--output", action="append", dest="outputs", help="outputs whose error is measured (repeatable)")
    p.add_argument("--reference", metavar="FILE.csv",
                   help="reference values (a `t` column and one column per output, e.g. a published reference "
                   "solution): errors of those outputs at those times; replaces the scene's reference_values")
    p.add_argument("--reference-rtol", type=float, help="rtol of the reference run (no closed form)")
    p.add_argument("--out-dir", default=".", help="where bench.csv, bench.md and bench.png go")
    p.add_argument("--no-cache", action="store_true", help="recompute the reference run")
    p.add_argument("--no-plot", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("sweep", help="parameter study: grids, Latin-hypercube or random samples, on a local "
                       "process pool or a Dask cluster (one compilation per sweep)")
    p.add_argument("file", metavar="FILE", help="a model file, or a scene file (its `sweep:` section is used)")
    p.add_argument("--param", action="append", metavar="NAME=SPEC",
                   help="swept values (repeatable): a number, a list 1,2,5, a grid A:B:N or log:A:B:N, or a "
                   "distribution uniform:A:B, normal:MEAN:STD, loguniform:A:B; NAME is a parameter, "
                   "accuracy.rtol/atol/step or accuracy.mesh.COMPONENT")
    p.add_argument("--samples", type=int, help="number of samples of the distributions")
    p.add_argument("--seed", type=int, help="seed of the sampler (default 0)")
    p.add_argument("--sampling", choices=("lhs", "random"), help="Latin hypercube (default) or random")
    p.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="local process pool (default) or Dask distributed (needs the `cluster` extra: pip install 'port-hamiltonian-compiler[cluster]')")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:8786) or scheduler file; default: a LocalCluster")
    p.add_argument("--workers", type=int, help="worker processes of the local pool or LocalCluster (default: "
                   "the CPUs available)")
    p.add_argument("--out", required=True, metavar="RESULTS",
                   help="results, .csv (also .parquet with pyarrow) or .parquet: one row per run")
    p.add_argument("--series", metavar="FILE.csv", help="also write every run's output time series (long format)")
    p.add_argument("--resume", action="store_true", help="continue the results in --out, skipping finished points")
    p.add_argument("--overwrite", action="store_true", help="replace existing results in --out")
    p.add_argument("--t-end", type=float, help="end time of every run (default: the model's)")
    p.add_argument("--n-out", type=int, help="output points of every run")
    p.add_argument("--solver", choices=_solver_names(), help="integrator (default: the model's)")
    p.add_argument("--backend", choices=("auto", "numpy", "numba"),
                   help="what runs the generated functions on every worker (and in every recompiled group): "
                   "numba, numpy, or auto (the default, or $PHC_BACKEND)")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.add_argument("--plot", metavar="OUT.png", help="draw an output against one or two parameters (needs the `plot` extra: pip install 'port-hamiltonian-compiler[plot]')")
    p.add_argument("--plot-output", metavar="COLUMN", help="column to draw (default: the first output's max)")
    p.add_argument("--plot-against", metavar="P1[,P2]", help="swept parameter(s) on the axes (default: the first "
                   "one or two that vary)")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("check", help="certify Dirac structures and couplings and the compiled equations (Berger, Hochdahl, Reis, Seifried, \"Port-Hamiltonian modelling of coupled rigid/flexible multibody systems\", Section 2)")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--format", choices=("text", "json", "github", "sarif"), default="text", help=FORMAT_HELP)
    p.add_argument("--samples", type=int, default=2, help="random states sampled besides the initial one")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("linearize", help="linearize about a consistent point: the descriptor system (E, A, B, C, "
                       "D), finite eigenvalues with natural frequencies and damping ratios, mode shapes")
    p.add_argument("file", metavar="FILE", help="a model file, or a scene file")
    p.add_argument("--at", type=float, metavar="T", help="linearize at time T of the simulated motion (default: at "
                   "the start, about the initial state)")
    p.add_argument("--state", action="append", metavar="NAME=VALUE",
                   help="initial value of a state (repeatable); the rest by consistent initialization")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="override a parameter (repeatable)")
    p.add_argument("--mesh", action="append", metavar="COMPONENT=N", help="elements of a distributed component "
                   "(repeatable)")
    p.add_argument("--format", choices=("text", "json", "npz"),
                   help="report format (default: from the -o suffix, else text)")
    p.add_argument("-o", "--output", metavar="OUT", help="write the report to OUT (.txt, .json or .npz)")
    p.add_argument("--modes", type=int, default=20, help="modes listed in the text report (default 20)")
    p.add_argument("--no-certify", action="store_true",
                   help="skip the certificate of the compiled equations (power balance, passivity)")
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("graph", help="draw the interconnection graph (DOT, or PNG with matplotlib)")
    p.add_argument("file", metavar="FILE")
    p.add_argument("-o", "--output", metavar="OUT", help="out.dot or out.png (default: DOT on stdout)")
    p.set_defaults(func=cmd_graph)

    for name in ("validate", "compile", "simulate", "animate", "bench", "check", "graph", "sweep", "linearize"):
        p = sub.choices[name]
        p.add_argument("--max-memory", type=_memory_size, metavar="SIZE",
                       help="memory budget, e.g. 8G or 512M: a model whose estimated compile and output memory is "
                       "larger is refused before the work (default 2G; env PHC_MAX_MEMORY)")
        p.set_defaults(func=_with_budget(p.get_default("func")))

    p = sub.add_parser("schema", help="print, write or check the JSON Schemas of the model language")
    p.add_argument("--name", default="model", choices=("model", "scene", "model.schema.json", "scene.schema.json"),
                   help="which schema to print: the model language or scenes (default: model)")
    p.add_argument("--write", action="store_true", help="write the schemas into --dir")
    p.add_argument("--check", action="store_true", help="fail if the schemas in --dir are stale")
    p.add_argument("--dir", default="schemas")
    p.set_defaults(func=cmd_schema)

    p = sub.add_parser("cache", help="show or empty the cache of generated modules and bench references")
    p.add_argument("action", choices=("info", "clean"), nargs="?", default="info")
    p.set_defaults(func=cmd_cache)
    for name in ("validate", "compile", "simulate", "animate", "bench", "check", "graph", "sweep", "linearize"):
        sub.choices[name].add_argument(
            "--allow-path", action="append", default=[], metavar="DIR",
            help="also allow files under DIR to be referenced (nested models, tables, matrices); by default "
            "they must lie in the directory of the model or scene file (repeatable; env PHC_ALLOW_PATH)")
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.showwarning = _show_warning
    try:
        _check_arguments(args)
        with _allowed_paths(args):
            return args.func(args)
    except _Exit as done:
        return done.code
    except UsageError as err:
        print(f"phc {args.command}: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("phc: interrupted", file=sys.stderr)
        return 130
    except PhcError as err:  # phc's own exceptions are about the input or the run, not internal
        print(f"phc {args.command}: error: {err}", file=sys.stderr)
        return EXIT_MODEL
    except BrokenPipeError:  # the reader went away (`phc ... | head`): not an error of ours
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except Exception as err:  # an internal error, not a user mistake
        if os.environ.get("PHC_DEBUG"):
            raise
        print(f"phc {args.command}: internal error: {type(err).__name__}: {err} "
              "(please report it; rerun with PHC_DEBUG=1 for a traceback)", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
