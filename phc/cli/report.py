"""How the `phc` commands report: exit codes, diagnostics, summaries, result files.

The exit codes and :class:`_Exit` (leave a command with an exit code, the problem already
printed); :class:`_Files`, the diagnostics and status lines of a command over several
files (text, JSON, GitHub annotations, SARIF); the lines `phc compile` and `phc simulate`
print about a compiled model (certificate, backend, what a scene left out); the summary
of a run; its result file (CSV or NPZ) and its plot. Part of :mod:`phc.cli`.
"""

from __future__ import annotations

import json
import sys
from typing import Optional

from phc import __version__
from phc.errors import UsageError
from phc.inert import inert

EXIT_OK, EXIT_MODEL, EXIT_USAGE = 0, 1, 2
EXIT_INTERRUPTED = 130


def _print_diagnostics(diags, fmt: str = "text", stream=None) -> None:
    stream = stream or sys.stderr
    if fmt == "json":
        return
    for d in diags:
        print(d.render(), file=stream)


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
            from phc.cli.report_formats import github_annotations

            for line in github_annotations(diags, path):
                print(line)

    def status(self, line: str) -> None:
        """A file's own line (`x.yaml: ok (...)`): stdout, except beside a SARIF log."""
        line = inert(line)  # it starts with the file name (phc.inert)
        if self.fmt in ("text", "github"):
            print(line)
        elif self.fmt == "sarif":
            print(line, file=sys.stderr)

    def finish(self) -> int:
        if self.fmt == "sarif":
            from phc.cli.report_formats import sarif_log

            print(json.dumps(sarif_log(self.diagnostics, __version__, self.command), indent=2))
        if self.n > 1 and self.fmt != "json":
            counts = [sum(d.severity == s for ds in self.diagnostics.values() for d in ds)
                      for s in ("error", "warning")]
            text = (f"phc {self.command}: {self.n} files, {self.n - len(self.failed)} ok, {len(self.failed)} "
                    f"failed; {counts[0]} error(s), {counts[1]} warning(s)")
            if self.failed:
                shown = ", ".join(inert(f) for f in self.failed[:5])
                text += " in " + shown + (", …" if len(self.failed) > 5 else "")
            print(text, file=sys.stderr)  # stdout keeps one line per file (or the log alone)
        return EXIT_MODEL if self.failed else EXIT_OK


def _part_line(path: str, dae) -> str:
    names = ", ".join(dae.external_ports)
    n_components = len(dae.topology.components) if dae.topology is not None else 0
    return (f"{path}: part ok ({n_components} component(s); exposes {names}; its balance is checked in the "
            "model that uses it)")


def _certificate_line(compiled) -> str:
    cert = compiled.description.certificate  # the verdict (phc.codegen.description.Verdict)
    return f"  {cert.summary}" if cert is not None else "  not certified (--no-certify)"


def _backend_line(compiled, requested=None, kept: Optional[str] = None, result=None) -> str:
    """What runs the generated functions (phc.codegen.backends); `kept` is the line a
    cached front end printed before (phc.codegen.fastpath). A run that chose a backend of its own
    (`result.backend_note`: ``auto`` on a long fixed-step run) says which and why instead."""
    if result is not None and getattr(result, "backend_note", ""):
        return f"  backend  {result.backend_note}"
    if kept is not None:
        return kept
    from phc.codegen.backends import describe

    return f"  backend  {describe(compiled.module, requested)}"


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
    return "\n".join(inert(line) for line in lines)  # the model's name and the message (phc.inert)


def _event_text(e: dict) -> str:
    what = {"stick": "sticks", "slip": "slips " + ("+" if e["direction"] > 0 else "−"),
            "impact": "impact", "close": "closes", "open": "opens",
            "passage": "passed (IDA bridged by the midpoint rule)"}.get(e["kind"])
    if what is None:
        what = (("turns true" if e["direction"] > 0 else "turns false") if e.get("comparison")
                else "rising" if e["direction"] > 0 else "falling")
    return f"t = {e['t']:.10g} `{e['condition']}` {what}" + (" (in t)" if e["kind"] == "time" else "")


class _Exit(Exception):
    """Leave a command with this exit code (the problem was already printed)."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


def _plot(result, path: str, title: str) -> None:
    from phc.study import viz

    try:
        viz.plot_outputs(result, path, title=title)
    except viz.PlotUnavailable as err:
        raise UsageError(str(err)) from err
