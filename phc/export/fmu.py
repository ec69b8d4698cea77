"""FMI 2.0 co-simulation export: ``phc export MODEL_OR_SCENE.yaml --fmu OUT.fmu``.

Input: a model or scene file (and the export's options). Output: an ``.fmu`` (a zip) with

* ``modelDescription.xml`` (:mod:`phc.export.fmu_xml`): the base parameters (causality
  ``parameter``, taken by the compiled code at run time: ``tunable`` — settable between steps —
  unless the initial state depends on them, then ``fixed``; parameters fixed at compile time — a
  mesh length — are ``local`` constants), the
  inputs (an additive input on every top-level effort or flow source and exposed port, as
  ``phc linearize`` defines them: :func:`phc.study.linearize.compile_with_inputs`), the model's
  outputs, the stored energy ``energy.H`` and the energy-balance error
  ``energy.balance_error`` (outputs), every DAE variable (``local``), with units and
  descriptions;
* ``sources/model.c`` (the C back end's functions, :func:`phc.codegen.c_printer.c_source`),
  ``sources/fmu.c`` (the constants below, :mod:`phc.export.fmu_c`), which includes
  ``sources/steps.c`` (the implicit midpoint rule's step loop that ``phc simulate`` runs on the
  C back end) and ``sources/fmi2_cs.c`` (the FMI functions, the same for every FMU);
* ``binaries/linux64/<model>.so``, those sources compiled by the system C compiler with the
  flags of the C step loop (no fused multiply-adds, no ``-ffast-math``) and only the FMI
  functions visible.

What phc computes here and embeds: the consistent initial state at the exported parameter
values (phc's initialization, :func:`phc.simulation.start_state`), the nominal scales the
Newton test weighs the variables by (as ``phc simulate`` finds them for the model's own run),
the step logic's constants, and which parameters the initial state depends on: the FMU refuses
a change of those with a logged ``fmi2Error`` (export again with ``--param``) and takes any
other at ``fmi2ExitInitializationMode``. Only the differential variables' start matters to
the midpoint rule (the algebraic ones enter only through the step's midpoint, which the step
solves for), so a parameter that moves only algebraic start values is not refused.

Refused, one line each naming the file (:class:`ExportError`): another solver than the
implicit midpoint rule, FMI 3, no C compiler, a platform other than x86-64 Linux, switching
conditions (events), inputs with breakpoints (pieces or CSV tables), invariants that are not
rows of the equations (the Python loop projects them), more unknowns than the dense step loop
serves.
"""

from __future__ import annotations

import hashlib
import math
import os
import platform
import re
import shutil
import sys
import tempfile
import time
import uuid
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from phc.errors import CodegenError, ExportError, PhcError

RELATIVE_CHANGE = 1e-3
"""How much each parameter is moved to see whether the initial state depends on it (when phc
chose some initial values: guesses)."""

BUILD_TIMEOUT = 900.0
"""Seconds the C compiler may take on the FMU's sources before it is abandoned."""

START_TOLERANCE = 1e-10
"""A differential start value moved by more than this (relative to its nominal scale) depends on the parameter."""


@dataclass
class FmuReport:
    """What :func:`export_fmu` wrote."""

    path: str
    model: str
    identifier: str
    guid: str
    unknowns: int
    parameters: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    fixes_start: tuple[str, ...]
    """Parameters the FMU refuses to change (the initial state depends on them)."""
    step: float
    """Longest step (0: one step per communication interval)."""
    compiler: str
    seconds: float
    notes: list[str] = field(default_factory=list)

    def describe(self) -> str:
        step = f"steps of at most {self.step:g}" if self.step else "one step per communication interval"

        def count(k: int, what: str) -> str:
            return f"{k} {what}{'' if k == 1 else 's'}"

        return (f"{self.path}: FMI 2.0 co-simulation FMU of `{self.model}` for linux64 (implicit midpoint rule, "
                f"{step}; {count(len(self.parameters), 'parameter')}, {count(len(self.inputs), 'input')}, "
                f"{count(len(self.outputs), 'output')}; written in {self.seconds:.1f} s wall)")


def _identifier(name: str) -> str:
    """The model's name as a file stem and C-style identifier."""
    ident = re.sub(r"[^A-Za-z0-9_]", "_", str(name))[:64] or "model"
    return ident if not ident[0].isdigit() else f"m_{ident}"


def _derived_statements(ir) -> tuple[str, ...]:
    """C statements ``p[i] = ...;`` for the derived parameters, in dependency order, printed as
    the C back end prints expressions (the NumPy module's evaluation order)."""
    from phc.codegen.c_printer import CPrinter, _Expressions, comment, unsupported

    printer = CPrinter(ir)
    names = dict(printer.names)
    names.update({s: f"p[{k}]" for k, s in enumerate(ir.p_symbols)})
    text = _Expressions(names, printer.order)
    out = []
    for i, expr in ir.derived:
        what = unsupported(expr, printer.known)
        if what:
            raise ExportError(f"the derived parameter `{ir.parameters[i]}` uses {what}, which the FMU's C code "
                              "cannot compute")
        out.append(f"p[{i}] = {text.text(expr)};  /* {comment(ir.parameters[i])} */")
    return tuple(out)


def _fixes_start(compiled, raw, p, t0, y0, scales, names) -> set[str]:
    """The base parameters whose change moves a differential variable's consistent start: those
    a start value is written in, and those whose change (by :data:`RELATIVE_CHANGE`) moves the
    start phc's initialization finds or makes the given values inconsistent."""
    from phc.simulation import initial_values, parameter_vector
    from phc.simulation.guard import quiet_floating_point
    from phc.simulation.initial import consistent_initial_conditions

    diff = np.flatnonzero(np.asarray(raw.DIFFERENTIAL, dtype=bool))
    out: set[str] = set()
    for iv in compiled.description.initial:  # the parameters the start values are written in
        out |= set(names) if iv.depends is None else set(iv.depends).intersection(names)
    for name in sorted(set(names) - out):  # the values phc chose, and the consistency of the given ones
        value = float(p[list(raw.PARAMETERS).index(name)])
        moved = value * (1.0 + RELATIVE_CHANGE) if value != 0.0 else RELATIVE_CHANGE
        try:
            with quiet_floating_point():
                q = parameter_vector(raw, {name: moved})
                values, fixed_q = initial_values(compiled, q)
                y = consistent_initial_conditions(raw, q, t0, values, fixed_q).y0
        except (PhcError, ArithmeticError, ValueError):
            out.add(name)
            continue
        if np.any(np.abs(y[diff] - y0[diff]) > START_TOLERANCE * np.asarray(scales)[diff]):
            out.add(name)
    return out


def _variables(compiled, raw, inputs, p, fixes_start) -> tuple:
    """The FMU's variables in value-reference order (:class:`~phc.export.fmu_c.FmuVariable`)."""
    from phc.export.fmu_c import FmuVariable

    units = dict(compiled.description.units)
    info = {par.name: par for par in compiled.dae.parameters}
    by_parameter = {inp.parameter: inp for inp in inputs}
    compile_time = set(getattr(raw, "COMPILE_TIME_PARAMETERS", ()))
    out = []
    for i in raw.BASE_PARAMETERS:
        name = raw.PARAMETERS[i]
        if name in by_parameter:
            continue
        par = info.get(name)
        unit, text = (par.unit, par.description or "") if par is not None else (None, "")
        if name in compile_time:
            out.append(FmuVariable(name, "CONSTANT", int(i), "local", "constant", "exact", float(p[i]), unit,
                                   (text + "; " if text else "") + "fixed when the model was compiled (a mesh "
                                   "length or a coefficient along a distributed component)"))
        else:
            fixes = name in fixes_start  # tunable between steps unless the start state depends on it
            out.append(FmuVariable(name, "PARAMETER", int(i), "parameter", "fixed" if fixes else "tunable", "exact",
                                   float(p[i]), unit, text, fixes_start=fixes))
    for inp in inputs:
        out.append(FmuVariable(inp.name, "INPUT", list(raw.PARAMETERS).index(inp.parameter), "input", "continuous",
                               None, 0.0, None, f"added to the {inp.kind} of {inp.origin} (the model's value; 0 "
                               "for a free port), held over each communication step"))
    for k, name in enumerate(raw.OUTPUTS):
        out.append(FmuVariable(name, "OUTPUT", k, "output", "continuous", "calculated", None, units.get(name),
                               "an output of the model"))
    energy_unit = units.get("H") or units.get("energy.supplied")
    out.append(FmuVariable("energy.H", "ENERGY", 0, "output", "continuous", "calculated", None, energy_unit,
                           "the stored energy H (the Hamiltonian)"))
    out.append(FmuVariable("energy.balance_error", "BALANCE", 0, "output", "continuous", "calculated", None,
                           energy_unit, "H(t) - H(t0) + E(t), E the energy supplied through the ports and "
                           "dissipated: zero per step up to the Newton tolerance for a quadratic H (the implicit "
                           "midpoint rule's discrete energy balance)"))
    for j, name in enumerate(raw.VARIABLES):
        what = ("a state (differential variable)" if raw.DIFFERENTIAL[j] else
                "an algebraic variable: the midpoint rule's value at the step end (the step solves for its midpoint)")
        out.append(FmuVariable(name, "VARIABLE", j, "local", "continuous", "calculated", None, units.get(name), what))
    seen: dict[str, str] = {}
    for v in out:
        if v.name in seen:
            raise ExportError(f"two FMU variables would be named `{v.name}` (a {seen[v.name].lower()} and a "
                              f"{v.kind.lower()}); rename one in the model")
        seen[v.name] = v.kind
    return tuple(out)


def _build(folder: Path, identifier: str, argv: list[str]) -> Path:
    """Compile the sources in `folder`/sources into `folder`/binaries/linux64/<identifier>.so."""
    from phc.codegen.cc import compile_library
    from phc.codegen.c_steps import FLAGS

    target = folder / "binaries" / "linux64" / f"{identifier}.so"
    target.parent.mkdir(parents=True)
    try:
        compile_library(argv, (*FLAGS, "-fvisibility=hidden"), ("model.c", "fmu.c"), target, cwd=folder / "sources",
                        timeout=BUILD_TIMEOUT, libs=("-lm",), what="the FMU's sources",
                        hint="a phc bug: please report it")
    except CodegenError as err:
        raise ExportError(str(err)) from None
    return target


def export_fmu(path, out, *, step: Optional[float] = None, solver: Optional[str] = None, fmi="2",
               params: Optional[dict] = None, certify: bool = True) -> FmuReport:
    """Write an FMI 2.0 co-simulation FMU of the model or scene file `path` to `out` (see the
    module docstring).

    Parameters
    ----------
    step : float, optional
        Longest step of the implicit midpoint rule (default: the model's ``simulation.step``;
        without one, one step per communication interval).
    solver : str, optional
        ``midpoint`` (the only one the FMU embeds).
    fmi : str
        ``"2"`` (FMI 2.0).
    params : dict, optional
        Parameter values to export with (the FMU's defaults and the start state's).

    Raises
    ------
    ExportError
        What cannot be exported, one line naming the file.
    ModelError
        The model has errors (its diagnostics).
    """
    started = time.perf_counter()
    where = str(path)
    try:
        return _export(path, out, step, solver, fmi, params, certify, started)
    except ExportError as err:
        text = str(err)
        raise ExportError(text if text.startswith(where + ":") else f"{where}: {text}") from None


def _export(path, out, step, solver, fmi, params, certify, started) -> FmuReport:
    from phc.codegen import c_backend
    from phc.codegen.c_printer import c_source
    from phc.codegen.lower import lower_residual
    from phc.errors import BackendUnsupported, InconsistentInitialError, ModelEvaluationError, SimulationSetupError
    from phc.export.fmu_c import FMI2_CS, FmuData, fmu_source
    from phc.export.fmu_xml import model_description
    from phc.study.linearize import compile_with_inputs
    from phc.options import RunOptions
    from phc.simulation import initial_values, parameter_vector, start_state
    from phc.simulation import midpoint as mp
    from phc.codegen.c_steps import source as steps_source
    from phc.simulation.compiled_steps import MAX_UNKNOWNS, algebraic_mask, step_constants
    from phc.simulation.events import has_switches
    from phc.simulation.guard import quiet_floating_point
    from phc.simulation.scaling import nominal_indices, nominal_scales, tested_fraction

    if str(fmi) not in ("2", "2.0"):
        raise ExportError(f"FMI {fmi} is not offered yet; phc writes FMI 2.0 co-simulation FMUs (--fmi 2)")
    if solver not in (None, "midpoint"):
        raise ExportError(f"the FMU embeds the implicit midpoint rule (its step loop in C, with the energy balance "
                          f"exact per step); `{solver}` cannot be exported: use --solver midpoint")
    if step is not None and not (math.isfinite(float(step)) and float(step) > 0):
        raise ExportError(f"the step must be a positive finite number, got {step}")
    if not (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "amd64", "AMD64")):
        raise ExportError(f"phc builds the FMU's binary for x86-64 Linux (linux64) only; this machine is "
                          f"{sys.platform} on {platform.machine()}")
    argv, identity = c_backend.find_compiler()
    if argv is None:
        raise ExportError(f"cannot build the FMU's binary: {identity.split(', or run with')[0]}")
    if not str(out).endswith(".fmu"):
        raise ExportError(f"the FMU's file name must end in .fmu, got `{out}`")

    compiled, inputs = compile_with_inputs(path, params or None, None, certify, "numpy")
    raw = compiled.module
    if has_switches(raw):
        raise ExportError("the model has switching conditions (events: ifelse, abs, sign, min or max of the state, "
                          "stops) or contacts (impacts); the FMU carries no event handling yet: export a model without "
                          "them")
    if len(getattr(raw, "BREAKPOINTS", ())):
        raise ExportError("the model's inputs have breakpoints (pieces or tables, first at t = "
                          f"{float(raw.BREAKPOINTS[0]):g}), where phc restarts the run; the FMU does not: drive "
                          "that port from the importer instead (each port is an input of the FMU)")
    if raw.N > MAX_UNKNOWNS:
        raise ExportError(f"the model has {raw.N} unknowns, more than the {MAX_UNKNOWNS} the C step loop's dense LU "
                          "serves")
    ir = lower_residual(compiled.dae)
    try:
        model_c = c_source(ir)
    except BackendUnsupported as err:
        raise ExportError(f"the FMU cannot carry this model: {err}") from None
    derived = _derived_statements(ir)

    try:
        options = RunOptions.of(compiled.description.options).with_overrides(solver="midpoint", step=step)
        t0 = float(options.t_start)
        p = parameter_vector(raw)
        values, fixed = initial_values(compiled, p)
        init = start_state(compiled, p, t0, values, fixed)
        y0, yp0 = np.asarray(init.y0, dtype=float), np.asarray(init.yp0, dtype=float)
        t_out = np.linspace(t0, options.t_end, options.n_out)
        opts = compiled.description.options
        with quiet_floating_point():
            scales = nominal_scales(raw, p, y0, yp0, nominal_indices(raw, dict(opts.get("nominal", {}))), t0=t0,
                                    span=float(t_out[-1] - t0), t_out=t_out,
                                    atol=options.atol * tested_fraction("midpoint", options.rtol))
    except (InconsistentInitialError, ModelEvaluationError, SimulationSetupError) as err:
        raise ExportError(f"no consistent start at the exported parameters: {err}") from None
    if mp.make_projector(raw, p, y0, t0) is not None:
        raise ExportError("the model's invariants are not rows of its equations (phc projects them at the step "
                          "ends in Python); the FMU's step loop cannot")
    input_parameters = {inp.parameter for inp in inputs}
    base_names = [raw.PARAMETERS[i] for i in raw.BASE_PARAMETERS
                  if raw.PARAMETERS[i] not in input_parameters
                  and raw.PARAMETERS[i] not in set(getattr(raw, "COMPILE_TIME_PARAMETERS", ()))]
    fixes = _fixes_start(compiled, raw, p, t0, y0, scales, base_names)
    variables = _variables(compiled, raw, inputs, p, fixes)

    weights = mp.newton_weights_of(scales, raw)
    end_rows = np.asarray(mp.constraint_rows(raw), dtype=np.int64)
    jrows = np.asarray(raw.JAC_ROWS, dtype=np.int64)
    data = dict(
        model=str(raw.MODEL), n=int(raw.N), njac=len(jrows), nend=len(end_rows), nout=len(raw.OUTPUTS),
        ninv=len(raw.INVARIANTS), nrows=len(raw.EQUATIONS), npred=mp.MAX_PREDICTOR_ORDER + 1, t0=t0,
        step=float(options.step or 0.0), energy_index=list(raw.VARIABLES).index("energy.supplied"),
        p=np.asarray(p, dtype=float), derived=derived, y0=y0,
        yp0=yp0, weights=None if weights is None else np.asarray(weights, dtype=float),
        colscale=np.asarray(scales, dtype=float), constants=step_constants(), jrows=jrows,
        jcols=np.asarray(raw.JAC_COLS, dtype=np.int64), end_rows=end_rows,
        emask=np.isin(jrows, end_rows).astype(np.int8), algmask=algebraic_mask(raw), variables=variables)
    digest = hashlib.sha256(model_c.encode() + fmu_source(FmuData(guid="", **data)).encode()).hexdigest()
    guid = "{" + str(uuid.UUID(hex=digest[:32])) + "}"
    d = FmuData(guid=guid, **data)
    identifier = _identifier(raw.MODEL)
    interval = (options.t_end - t0) / (options.n_out - 1) if options.n_out > 1 else None
    xml = model_description(d, identifier=identifier, description=_description(compiled), stop_time=options.t_end,
                            output_interval=interval)

    work = Path(tempfile.mkdtemp(prefix="phc-fmu-"))
    try:
        sources = work / "sources"
        sources.mkdir()
        (sources / "model.c").write_text(model_c, encoding="utf-8")
        (sources / "fmu.c").write_text(fmu_source(d), encoding="utf-8")
        (sources / "steps.c").write_text(steps_source(), encoding="utf-8")
        shutil.copyfile(FMI2_CS, sources / "fmi2_cs.c")
        (work / "modelDescription.xml").write_text(xml, encoding="utf-8")
        binary = _build(work, identifier, argv)
        _zip(work, [work / "modelDescription.xml", binary, sources / "model.c", sources / "fmu.c",
                    sources / "steps.c", sources / "fmi2_cs.c"], Path(out))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return FmuReport(path=str(out), model=str(raw.MODEL), identifier=identifier, guid=guid, unknowns=int(raw.N),
                     parameters=tuple(v.name for v in variables if v.kind == "PARAMETER"),
                     inputs=tuple(v.name for v in variables if v.kind == "INPUT"),
                     outputs=tuple(v.name for v in variables if v.causality == "output"),
                     fixes_start=tuple(sorted(fixes)), step=float(options.step or 0.0), compiler=identity,
                     seconds=time.perf_counter() - started)


def _description(compiled) -> str:
    text = ""
    if compiled.dae is not None:
        text = str(getattr(compiled.dae, "description", "") or "")
    return text or f"port-Hamiltonian model {compiled.description.name}, exported by phc"


def _zip(root: Path, files: list[Path], out: Path) -> None:
    """The FMU: `files` (paths under `root`) in a zip written next to `out`, then moved onto it."""
    out = out.resolve()
    partial = out.with_name(out.name + f".{os.getpid()}.part")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zf:
            for f in files:
                info = zipfile.ZipInfo(f.relative_to(root).as_posix(), date_time=(1980, 1, 1, 0, 0, 0))
                info.external_attr = 0o644 << 16
                info.compress_type = zipfile.ZIP_DEFLATED
                zf.writestr(info, f.read_bytes())
        os.replace(partial, out)
    except OSError as err:
        try:
            partial.unlink(missing_ok=True)
        except OSError:
            pass
        raise ExportError(f"cannot write `{out}`: {err.strerror or err}") from None


__all__ = ["ExportError", "FmuReport", "export_fmu"]
