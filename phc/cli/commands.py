"""The `phc` subcommands: one ``cmd_NAME(args) -> exit code`` each.

validate, compile, simulate, sweep, animate, bench, check, linearize, export, graph, schema
and cache, with the parsing of their ``NAME=VALUE`` options. What they print and write comes
from :mod:`phc.cli.report`, the set-up of a run from :mod:`phc.cli.run`. Part of
:mod:`phc.cli`.
"""

from __future__ import annotations

import json
import math
import sys
from contextlib import nullcontext, redirect_stdout
from pathlib import Path
from typing import Sequence

from phc.cli.report import (EXIT_INTERRUPTED, EXIT_MODEL, EXIT_OK, _backend_line, _certificate_line, _compiled_json,
                            _Files, _left_out_lines, _part_line, _plot, _print_diagnostics, _size_text, _summary_text,
                            _write_results)
from phc.cli.run import (_compile_or_exit, _ignored_in_file_lines, _progress_for, _recompile_for_params,
                         _simulation_errors, _terminate_as_interrupt, _written_options)
from phc.errors import UsageError
from phc.inert import inert
from phc.io import finish_before_interrupt


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


def cmd_validate(args) -> int:
    from phc.codegen import fastpath

    files = _Files(args, "validate")
    report = []
    for path in args.files:
        kept = fastpath.lookup_validate(args, path) if args.format in ("text", "json") else None
        if kept is not None:  # an unchanged file: its result as stored (phc.codegen.fastpath)
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


MAX_FILE_STEM = 120
"""`phc compile` names the module after the model, shortened beyond this many characters
(with a hash of its source, so that two long names stay apart): file systems allow 255 bytes."""


def cmd_compile(args) -> int:
    from phc.codegen import fastpath
    from phc import ModelError, SimulationSetupError
    from phc.io import write_text

    files = _Files(args, "compile")
    out_dir = Path(args.output)
    cached = args.format == "text"  # the GitHub and SARIF formats need the diagnostics themselves
    for path in args.files:
        # an unchanged model: the texts and lines its last compilation gave (phc.codegen.fastpath)
        hit = fastpath.lookup_compile(args, path) if cached else None
        if hit is not None:
            compiled, kept = hit.compiled, hit.backend_line
        else:
            from phc import compile_model

            kept = None
            try:
                with fastpath.recording(args, path, command="compile") as recorder:
                    compiled = compile_model(path, certify=not args.no_certify, backend=args.backend)
            except SimulationSetupError as err:  # --backend numba without numba
                raise UsageError(str(err)) from None
            except ModelError as err:
                files.report(path, err.diagnostics, False)
                continue
            if cached and all(d.severity in ("error", "warning") for d in compiled.diagnostics):
                recorder.store(compiled)  # a record keeps the warnings' lines (no notes)
        files.report(path, [d for d in compiled.diagnostics if d.severity != "error"], True)
        out_dir.mkdir(parents=True, exist_ok=True)
        name = compiled.name
        if len(name) > MAX_FILE_STEM:
            import hashlib

            name = f"{name[:MAX_FILE_STEM - 17]}_{hashlib.sha256(name.encode()).hexdigest()[:16]}"
        target = write_text(out_dir / f"{name}.py", compiled.source)
        c_text = getattr(compiled.module, "C_SOURCE", None)  # --backend c: its C99 text too
        if c_text is not None:
            write_text(out_dir / f"{name}.c", c_text)
        files.status(f"{path}: wrote {target} ({compiled.n_states} states, {compiled.n_equations} equations, "
                     f"{compiled.jacobian_nnz} Jacobian nonzeros, compiled in {compiled.compile_time:.2f} s)")
        for line in [_certificate_line(compiled), _backend_line(compiled, args.backend, kept),
                     *_left_out_lines(compiled)]:
            files.status(line)
    return files.finish()


def cmd_simulate(args) -> int:
    from phc.codegen import fastpath
    from phc.frontend.budget import format_bytes, peak_memory
    from phc.study.profile import profiled
    from phc import SimulationInterrupted, simulate

    params = _parse_params(args.param)
    hit = fastpath.lookup(args, params)  # an unchanged model: its cached front end (phc.codegen.fastpath)
    if hit is not None:
        compiled, written, backend_line = hit.compiled, hit.written_options, hit.backend_line
        recorder = first = None
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
        print(inert(line), file=sys.stderr)  # settings of the file this run's solver ignores (PHC-W250)
    progress = _progress_for(compiled, args.t_end, args.quiet)
    run_kwargs = dict(t_end=args.t_end, params=params, rtol=args.rtol, atol=args.atol, n_out=args.n_out,
                      solver=args.solver, step=args.step)
    estimates, prof, interrupted = [], None, False
    with _simulation_errors(args.file, progress, compiled):
        try:  # Ctrl-C: keep what was computed (written below), exit 130
            from phc.simulation import check_parameters

            check_parameters(compiled, params, label=lambda name, value: f"--param {name}={value:g}", path=args.file)
            # scikit-SUNDAE prints SUNDIALS' failure lines ("[IDAHandleFailure, Error: -4] ...") with
            # print(): in this command they go to stderr beside phc's own message, so that stdout
            # holds only the report (`--format json` stays one JSON document). The library leaves
            # sys.stdout alone: redirecting it there would not be safe for a caller's threads.
            with (profiled(compiled) if args.profile else nullcontext()) as prof, redirect_stdout(sys.stderr):
                result = simulate(compiled, progress=progress, **run_kwargs)
        except SimulationInterrupted as stop:
            result, interrupted = stop.result, True
        if hit is None and compiled is first and compiled.cache.run_modules:
            recorder.store(compiled, written)  # with the module the run built (phc.codegen.backends.for_run)
        if prof is not None:
            prof.run_cpu = result.cpu_time_s
        if args.estimate_error and not interrupted:
            progress.close()
            if not args.quiet:
                print(inert(f"{args.file}: estimating errors (a rerun with a finer step or tolerance, and one on "
                            "refined meshes)..."), file=sys.stderr)
            from phc import estimate_errors

            try:
                with redirect_stdout(sys.stderr):  # SUNDIALS' own lines, as for the run above
                    estimates = estimate_errors(compiled, result, run_kwargs)
            except KeyboardInterrupt:
                interrupted = True
                print(inert(f"{args.file}: error estimation interrupted; the run itself is complete"), file=sys.stderr)
    # Ctrl-C while the files are written: they are finished first (phc.io.finish_before_interrupt)
    written_anyway = False
    for target, write in ((args.out, lambda: _write_results(result, args.out)),
                          (args.plot, lambda: _plot(result, args.plot, compiled.name))):
        if not target:
            continue
        try:
            with finish_before_interrupt():
                write()
        except KeyboardInterrupt:
            interrupted = written_anyway = True
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
        print(_backend_line(compiled, args.backend, backend_line, result))
        for line in _left_out_lines(compiled):
            print(line)
        for e in estimates:
            if not e.ok and not e.per_output:  # no rerun to compare with (e.g. per-dof initial values)
                print(inert(f"  error    {e.kind}: {e.method}: {e.message}"))
                continue
            worst = max(e.per_output, key=e.per_output.get) if e.per_output else "-"
            status = "" if e.ok else f" (the rerun failed: {e.message})"
            print(inert(f"  error    {e.kind} ≈ {e.max:.3e} (largest in `{worst}`): {e.method}{status}"))
        if prof is not None:
            print(prof.render_text())
        if args.out:
            print(inert(f"  wrote    {args.out}"))
        if args.plot:
            print(inert(f"  plotted  {args.plot}"))
    if interrupted:
        kept = [f for f in (args.out, args.plot) if f]
        where = f"; the results so far are in {' and '.join(kept)}" if kept else " (no --out given: nothing written)"
        reached = f"t = {result.t[-1]:.6g}" if len(result.t) else "the start"
        if written_anyway:
            print(inert(f"phc simulate: interrupted while writing the results (run reached {reached}); the files "
                        f"were finished first: {' and '.join(kept)}"), file=sys.stderr)
            return EXIT_INTERRUPTED
        print(inert(f"phc simulate: interrupted at {reached}{where}"), file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_OK if result.success else EXIT_MODEL


def cmd_sweep(args) -> int:
    from phc import ModelError, SimulationSetupError
    from phc.sweep import plot_sweep, run_sweep
    from phc.sweep.results import check_series_path

    pairs = []
    for item in args.param or []:
        name, sep, spec = item.partition("=")
        if not sep or not name.strip():
            raise UsageError(f"--param expects NAME=SPEC, got `{item}`")
        pairs.append((name.strip(), spec))
    if args.retry_failed and not args.resume:
        raise UsageError("--retry-failed needs --resume (it runs the failed points of existing results again)")
    if args.scheduler is not None and not args.scheduler.strip():
        raise UsageError("--scheduler is empty; give an address (tcp://host:8786) or a scheduler file")
    for option, value in (("--plot-output", args.plot_output), ("--plot-against", args.plot_against)):
        if value is not None and not args.plot:
            raise UsageError(f"{option} needs --plot (it chooses what the plot draws)")
        if value is not None and not value.strip():
            raise UsageError(f"{option} is empty; give a column name" if option == "--plot-output" else
                             f"{option} is empty; give one or two swept parameters, e.g. k or k,c")
    try:
        check_series_path(args.out, args.series)  # before the compilation
    except SimulationSetupError as err:
        raise UsageError(str(err)) from None
    compiled = _compile_or_exit(args.file, certify=not args.no_certify, backend=args.backend)
    with _terminate_as_interrupt() as signals:
        try:
            report = run_sweep(args.file, args.out, params=pairs, samples=args.samples, seed=args.seed,
                               sampling=args.sampling, executor=args.executor, scheduler=args.scheduler,
                               workers=args.workers, series=args.series, resume=args.resume,
                               retry_failed=args.retry_failed, overwrite=args.overwrite, t_end=args.t_end,
                               n_out=args.n_out, solver=args.solver, certify=not args.no_certify,
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
        why = "stopped (SIGTERM)" if signals else "interrupted"
        print(inert(f"phc sweep: {why}; {len(report.rows)} of {report.planned} rows are in "
                    f"{report.paths['csv']}: rerun the same command with --resume to finish"), file=sys.stderr)
        return 128 + int(signals[0]) if signals else EXIT_INTERRUPTED
    return EXIT_OK if report.success else EXIT_MODEL


def cmd_animate(args) -> int:
    from phc.study import viz
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
        print(inert(f"{args.file}: simulation stopped: {result.message}; animating the results so far"),
              file=sys.stderr)
    try:
        viz.animate(compiled, result, args.output, magnify=args.magnify, fps=args.fps, max_frames=args.frames)
    except viz.PlotUnavailable as err:
        raise UsageError(str(err)) from err
    print(inert(f"{args.file}: wrote {args.output}"))
    if interrupted:
        return EXIT_INTERRUPTED
    return EXIT_OK if result.success else EXIT_MODEL


def cmd_bench(args) -> int:
    from phc.study.bench import parse_meshes, run_bench
    from phc import ModelError, SimulationSetupError

    try:
        report = run_bench(args.scene, solvers=args.solvers, tolerances=args.tolerances, steps=args.steps,
                           meshes=parse_meshes(args.mesh), repeats=args.repeats, out_dir=args.out_dir,
                           reference_cache=False if args.no_cache else None, progress=not args.quiet,
                           plot=not args.no_plot, outputs=args.outputs, reference_rtol=args.reference_rtol,
                           reference=args.reference, target_error=args.target_error)
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
        print(inert(f"{lin.model}: {len(lin.eigenvalues)} finite eigenvalues; wrote {args.output}"))
        return EXIT_OK
    text = json.dumps(lin.to_dict(), indent=2) if fmt == "json" else lin.render_text(args.modes)
    if args.output:
        Path(args.output).write_text(text + "\n", encoding="utf-8")
        print(inert(f"{lin.model}: {len(lin.eigenvalues)} finite eigenvalues; wrote {args.output}"))
    else:
        print(text)
    return EXIT_OK


def cmd_export(args) -> int:
    from phc import ModelError
    from phc.export import ExportError, export_fmu

    try:
        report = export_fmu(args.file, args.fmu, step=args.step, solver=args.solver, fmi=args.fmi,
                            params=_parse_params(args.param), certify=not args.no_certify)
    except ModelError as err:
        _print_diagnostics(err.diagnostics)
        return EXIT_MODEL
    except ExportError as err:  # one line naming the file: what cannot be exported, and what to do
        print(inert(str(err)), file=sys.stderr)
        return EXIT_MODEL
    print(inert(report.describe()))
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
    print(inert(f"{args.file}: wrote {args.output}"))
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
    from phc.io import OutputPathError, check_output_dir
    from phc.spec.export import SCHEMAS, schema_text, stale_schemas, write_schemas

    if (args.check or args.write) and not args.dir:
        raise UsageError("--dir is empty; give a folder")
    if args.check:
        try:
            stale = stale_schemas(args.dir)
        except OSError as err:  # a name too long, a loop of symbolic links, a file that cannot be read
            raise UsageError(f"--dir `{args.dir}` cannot be read ({(err.strerror or type(err).__name__).lower()})"
                             ) from None
        if stale:
            for path in stale:
                print(inert(f"{path}: stale or missing; regenerate with `phc schema --write --dir {args.dir}`"),
                      file=sys.stderr)
            return EXIT_MODEL
        print(inert(f"{args.dir}: schemas up to date ({', '.join(SCHEMAS)})"))
        return EXIT_OK
    if args.write:
        try:
            check_output_dir(args.dir, "--dir")
        except OutputPathError as err:
            raise UsageError(str(err)) from None
        for path in write_schemas(args.dir):
            print(inert(f"wrote {path}"))
        return EXIT_OK
    name = args.name if args.name.endswith(".schema.json") else f"{args.name}.schema.json"
    sys.stdout.write(schema_text(name))
    return EXIT_OK


def cmd_cache(args) -> int:
    from phc.codegen import load

    if args.action == "clean":
        files, size = load.clean()
        print(inert(f"{load.cache_dir()}: removed {files} files ({size / 2**20:.1f} MiB)"))
        return EXIT_OK
    info = load.info()
    print(inert(f"{info.path}: {info.files} files, {info.bytes / 2**20:.1f} MiB "
                f"(cap {info.cap_bytes / 2**20:.0f} MiB, PHC_CACHE_MAX_MB; least recently used evicted first)"))
    return EXIT_OK
