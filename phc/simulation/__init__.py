"""Simulation (pipeline stage 9): consistent initialization, integration, energy figures.

``simulate(compiled, ...)`` returns a :class:`SimResult`. A numerical failure is data
(``success=False`` with a message saying when, why and what to try), never an
exception; invalid options raise :class:`~phc.errors.SimulationSetupError` at once.
"""

from __future__ import annotations

import importlib
import math
import os
import time
import warnings
from functools import partial
from typing import Callable, Optional

import numpy as np

from phc.codegen.compiled import CompiledModel
from phc.errors import InconsistentInitialError, SimulationSetupError
from phc.simulation.guard import CATCH as GUARD_CATCH
from phc.simulation.guard import ModelEvaluationError, guard, quiet_floating_point
from phc.simulation.events import breakpoints_within, has_switches, integrate_switched, piece_grid, piece_outputs
from phc.simulation.impacts import has_contacts
from phc.simulation.ida import MAX_ORDER, applied_atol, integrate_ida
from phc.simulation import ida_native
from phc.simulation.initial import InitialResult, consistent_initial_conditions
from phc.simulation.monitor import describe_equations, many_steps_hint
from phc.simulation.order import carry as carry_order
from phc.simulation.step_logic import substeps
from phc.names import RUN_LIMITS
from phc.options import RunOptions
from phc.simulation.backend import Backend, BackendRun, IgnoredOptionWarning, ignored_option_message
from phc.simulation.result import SimResult, SimulationInterrupted
from phc.simulation.scaling import cached_nominal_scales, nominal_indices, nominal_scales, tested_fraction


def _deferred(module: str, name: str) -> Callable:
    """``module.name``, imported at its first call: a run with IDA does not load the
    fixed-step integrators' drivers (the midpoint rule's stage solver, which the nominal
    scales' probe uses, is loaded by that probe)."""
    def integrate(*args, **kwargs):
        return getattr(importlib.import_module(module), name)(*args, **kwargs)
    integrate.__name__ = integrate.__qualname__ = name
    integrate.__doc__ = f"``{module}.{name}``, imported at its first call."
    return integrate


integrate_midpoint = _deferred("phc.simulation.midpoint", "integrate_midpoint")
integrate_discrete_gradient = _deferred("phc.simulation.discrete_gradient", "integrate_discrete_gradient")
integrate_midpoint4 = _deferred("phc.simulation.midpoint4", "integrate_midpoint4")
_VARIABLE = frozenset({"rtol", "atol", "max_steps", "max_order"})
_FIXED = frozenset({"step", "max_steps"})
BACKENDS: dict[str, Backend] = {b.name: b for b in (
    # on the C back end, the native driver where it can (phc.simulation.ida_native), else scikit-sundae
    Backend("ida", ida_native.integrate, _VARIABLE, False, "SUNDIALS IDA: variable-order, variable-step BDF"),
    Backend("midpoint", integrate_midpoint, _FIXED, True, "implicit midpoint: order 2, energy-exact for quadratic H"),
    Backend("discrete_gradient", integrate_discrete_gradient, _FIXED, True,
            "discrete gradient: order 2, energy-exact for any H"),
    Backend("midpoint4", integrate_midpoint4, _FIXED, True,
            "composition of three midpoint substeps: order 4, energy-exact for quadratic H"),
)}
"""Integrators by name (:class:`~phc.simulation.backend.Backend`): `ida` (variable-order
BDF), and the fixed-step structure-preserving `midpoint`, `discrete_gradient`, `midpoint4`."""
FIXED_STEP = tuple(name for name, b in BACKENDS.items() if b.fixed_step)
N_OUT_LIMITS = tuple(RUN_LIMITS["n_out"][1:])
"""Smallest and largest number of output points (the model language's `simulation.n_out`)."""
MAX_STEPS_LIMIT = RUN_LIMITS["max_steps"][2]
"""Largest `max_steps`: IDA stores it in a C long (32 bits on some platforms)."""


def parameter_vector(mod, overrides: Optional[dict] = None) -> np.ndarray:
    """Full parameter vector from defaults and base-parameter overrides by name."""
    base_idx = list(mod.BASE_PARAMETERS)
    base = np.array(mod.PARAMETER_DEFAULTS, dtype=float)[base_idx]
    names = [mod.PARAMETERS[i] for i in base_idx]
    fixed = set(getattr(mod, "COMPILE_TIME_PARAMETERS", ()))
    for key, value in (overrides or {}).items():
        if key in fixed and float(value) != float(base[names.index(key)]):
            raise SimulationSetupError(f"parameter `{key}` was used at compile time (a mesh length or a "
                                       "coefficient varying along a distributed component); change it in the "
                                       "model and recompile (`phc simulate --param` and `phc sweep` recompile "
                                       "for it)")
        if key not in names:
            if key in mod.PARAMETERS:
                raise SimulationSetupError(f"parameter `{key}` is derived from other parameters; override those")
            raise SimulationSetupError(f"unknown parameter `{key}`; known: {', '.join(names)}")
        if not math.isfinite(float(value)):
            raise SimulationSetupError(f"parameter `{key}` must be a finite number, got {value}")
        base[names.index(key)] = float(value)
    with quiet_floating_point():
        full = mod.full_parameters(base)
    bad = [name for name, value in zip(mod.PARAMETERS, np.asarray(full, dtype=float)) if not math.isfinite(value)]
    if bad:
        given = ", ".join(f"{k} = {v:g}" for k, v in (overrides or {}).items())
        raise SimulationSetupError(f"derived parameter `{bad[0]}` is not finite"
                                   + (f" with {given}" if given else "") + "; check the parameter values")
    return full


def check_parameters(compiled, params: Optional[dict], label: Optional[Callable[[str, float], str]] = None,
                     path: Optional[str] = None) -> None:
    """Check parameter overrides the way values written in the model file are checked: the
    model is elaborated again with them (a few milliseconds, no code generated), and what it
    refuses there — a storage coefficient that is not positive (PHC-E405), a mass matrix
    that is not positive definite (PHC-E122), ... — is refused here.

    `label(name, value)` names where an override comes from in messages (``--param m=-2``);
    by default ``parameter `m` = -2``. `path` is the model or scene file, for a compiled
    model that does not name it (the command line's cached front end). Results are
    remembered per compiled model (``compiled.cache.parameter_checks``) and travel with its
    pickle: a model rebuilt from one (a sweep's worker) never reads the model's files, and
    refuses values that were not checked where it was compiled.

    Raises
    ------
    SimulationSetupError
        An override the model file would refuse: the message names the override, what is
        wrong (with the code) and where in the model file the value is used.
    """
    if not params:
        return
    mod = compiled.module
    defaults = dict(zip(mod.PARAMETERS, np.asarray(mod.PARAMETER_DEFAULTS, dtype=float)))
    changed = {}
    for key, value in params.items():
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise SimulationSetupError(f"parameter `{key}` must be a number, got {value!r}") from None
        if "." not in key and key in defaults and number != float(defaults[key]):
            changed[key] = number
    if not changed:
        return
    cache = compiled.cache.parameter_checks
    key = tuple(sorted(changed.items()))
    label = label or (lambda name, value: f"parameter `{name}` = {value:g}")
    given = ", ".join(label(k, v) for k, v in changed.items())
    if key not in cache:
        if compiled.cache.rebuilt:
            raise SimulationSetupError(f"{given}: this compiled model was rebuilt from its pickle and does not read "
                                       "the model's files; check parameter values where it was compiled "
                                       "(phc.simulation.check_parameters) before sending it")
        cache[key] = _parameter_problems(compiled, changed, path)
    problems = cache[key]
    if problems:
        raise SimulationSetupError(f"{given}: " + "; ".join(problems)
                                   + " (a value the model file would refuse; choose another)")


def _parameter_problems(compiled, changed: dict, path: Optional[str] = None) -> list[str]:
    """The errors of elaborating `compiled`'s model with `changed` over its parameters."""
    from phc.frontend.elaborate import elaborate
    from phc.frontend.scene import is_scene_file, load_scene

    scene = compiled.scene
    sources = compiled.description.sources
    try:
        if scene is not None:
            model = scene.model_path
        elif compiled.description.scene is None and sources:
            model = sources[0]
        elif path is not None and is_scene_file(path):
            scene, _ = load_scene(path)
            if scene is None:
                return []
            model = scene.model_path
        else:
            model = path
        if model is None:
            return []
        _, diags = elaborate(model, scene, params=changed)
    except (OSError, ValueError):  # the file went away or changed: nothing to compare with
        return []
    out = []
    for d in diags:
        if getattr(d, "severity", "error") != "error":
            continue
        where = ""
        if d.span is not None:
            where = f" ({d.span.file}:{d.span.line}:{d.span.col})" if hasattr(d.span, "line") else ""
        message = d.message.replace(" at the default parameters", "")
        out.append(f"{message}{where} [{d.code}]")
    return out


def simulate(compiled, t_end: Optional[float] = None, *, params: Optional[dict] = None,
             rtol: Optional[float] = None, atol: Optional[float] = None, n_out: Optional[int] = None,
             t_eval=None, initial: Optional[dict] = None, solver: Optional[str] = None,
             max_steps: Optional[int] = None, progress: Optional[Callable[[float], None]] = None,
             step: Optional[float] = None, backend: Optional[str] = None,
             nominal: Optional[dict] = None, max_order: Optional[int] = None) -> SimResult:
    """Simulate a compiled model.

    Parameters
    ----------
    compiled : CompiledModel or path
        From :func:`phc.compile_model`; a model or scene file's path is compiled first
        (``phc.compile_model(path)``: compile once and pass the result to run it often).
    t_end, rtol, atol, n_out, solver, max_steps, max_order : optional
        Override the model's `simulation` defaults (checked as the model file's are:
        :class:`phc.options.RunOptions`).
    t_eval : array_like, optional
        Output times (overrides `n_out`).
    step : float, optional
        Step size of the fixed-step `midpoint`, `discrete_gradient` and `midpoint4` solvers (default:
        the model's `simulation.step`, else the output interval).
    backend : {"auto", "numpy", "numba", "c"}, optional
        What runs the generated functions (default: what `compiled` was compiled with;
        :mod:`phc.codegen.backends`).
    params : dict, optional
        Base-parameter overrides by name (one compilation serves a parameter study).
    initial : dict, optional
        Initial values by state name; a value may be ``(value, True)`` to mark a guess.
    nominal : dict, optional
        Nominal scales by state name, over the model's `simulation.nominal`: the size
        `atol` and the Newton tests measure each state against (phc finds one for
        every state; :mod:`phc.simulation.scaling`).

    Returns
    -------
    SimResult
        Check ``success``; a failed run keeps its partial results.

    Raises
    ------
    SimulationSetupError
        For invalid options (non-finite, out of range), unknown parameters or states, and
        parameter overrides that make the model impossible to evaluate at the start.
    InconsistentInitialError
        When fixed initial values violate the equations.
    ModelEvaluationError
        When the model cannot be evaluated at the start (an expression outside its domain).
        Later in the run this is data: ``success=False``, the message names the row or
        output, its place in the model file and the time, and the results so far are kept.
    SimulationInterrupted
        On Ctrl-C (a ``KeyboardInterrupt``); its ``.result`` holds the run up to there.
    """
    from phc.codegen.backends import for_run

    if isinstance(compiled, (str, os.PathLike)):
        from phc.pipeline import compile_model

        compiled = compile_model(compiled)
    elif not isinstance(compiled, CompiledModel):
        raise TypeError(f"simulate() expects a compiled model (phc.compile_model(path)) or a model file's path, "
                        f"got {type(compiled).__name__}")
    opts = compiled.description.options  # read-only (phc.codegen.description)
    # the one options object: the model's (or scene's) run options with this call's overrides
    options = RunOptions.of(opts).with_overrides(t_end=t_end, rtol=rtol, atol=atol, n_out=n_out, solver=solver,
                                                 max_steps=max_steps, step=step, max_order=max_order)
    requested, backend = backend, BACKENDS[options.solver]
    ignored = backend.ignored({"rtol": rtol, "atol": atol, "step": step, "max_order": max_order})
    if ignored:
        warnings.warn(ignored_option_message(backend, ignored), IgnoredOptionWarning, stacklevel=2)
    t0 = options.t_start
    if t_eval is not None:
        t_out = np.asarray(t_eval, dtype=float).ravel()
        if not len(t_out) or not np.isfinite(t_out).all() or np.any(np.diff(t_out) <= 0) or t_out[0] < t0:
            raise SimulationSetupError("`t_eval` must be finite, increasing output times from the start time on")
        if t_out[0] != t0:
            t_out = np.concatenate([[t0], t_out])
    else:
        t_out = np.linspace(t0, options.t_end, options.n_out)
    # the module that runs: under `auto`, a long fixed-step run goes to a compiled step loop
    # (phc.codegen.backends.for_run; the Python loop runs models with switching conditions)
    mod, backend_note = for_run(compiled, requested, *_loop_plan(compiled, options, t_out))
    mod = guard(mod, compiled.source, _locator(compiled))
    from phc.frontend.budget import check_output_arrays

    columns = 2 * mod.N + len(mod.OUTPUTS) + len(mod.INVARIANTS) + len(getattr(mod, "VELOCITY_INVARIANTS", ())) + 4
    too_large = check_output_arrays(len(t_out), columns, "t_eval" if t_eval is not None else "n_out")
    if too_large:  # the model's own n_out was checked at compile time; this catches overrides
        raise SimulationSetupError(too_large)
    if not backend.fixed_step:
        options = options.replace(step=None)  # IDA has none (a file's `step` is for --solver midpoint)
    elif options.step is not None and not math.isfinite((t_out[-1] - t0) / options.step):
        raise SimulationSetupError(f"`step` must be a finite positive number no smaller than the time span "
                                   f"over 1e300, got {options.step}")
    p = parameter_vector(mod, params)
    check_parameters(compiled, params)  # the checks of values in the file (PHC-E405, E122, ...)
    values, fixed = initial_values(compiled, p, initial)
    user_nominal = nominal_indices(mod, {**opts.get("nominal", {}), **(nominal or {})})
    marks = [("", time.process_time())]  # the phases' ends, for SimResult.timings
    with quiet_floating_point():
        try:
            init = start_state(compiled, p, t0, values, fixed, mod)
        except ModelEvaluationError as err:
            raise _setup_error(err, params) from None
        if hasattr(progress, "restart"):
            progress.restart()
        marks.append(("start", time.process_time()))
        # every tolerance measures the variables against their nominal scales (docs/tolerances.md)
        scales = cached_nominal_scales(mod, p, init.y0, init.yp0, user_nominal, t0=t0, span=float(t_out[-1] - t0),
                                       t_out=t_out, atol=options.atol * tested_fraction(options.solver, options.rtol))
        marks.append(("scales", time.process_time()))
        run = partial(backend, mod, p, options=options, progress=progress, names=describe_equations(compiled),
                      nominal=scales)
        if has_switches(mod):  # switching conditions: breakpoints in t, state events (docs/events.md)
            out = integrate_switched(backend, mod, p, t_out, init, fixed, run.keywords)
        else:
            out = _integrate_with_breakpoints(run, mod, p, t_out, init)
        marks.append(("integrate", time.process_time()))
        # the algebraic variables at the output times, from the states (simulation/polish.py): IDA
        # leaves the index-2 ones out of its error test, the fixed-step solvers extrapolate them
        from phc.simulation.polish import polish_outputs

        out = polish_outputs(mod, p, out, scales)
        marks.append(("polish", time.process_time()))
        result = _finish(compiled, mod, p, out, init, 0.0, options, params)
        marks.append(("finish", time.process_time()))
    result.timings = {name: end - begin for (_, begin), (name, end) in zip(marks, marks[1:])}
    result.cpu_time_s = marks[-2][1] - marks[0][1]  # the run itself, without `finish` (as always)
    if backend.fixed_step:  # the step actually taken: no longer than `step` nor an output interval
        intervals = np.diff(t_out)
        h = options.step
        result.step = float(max(d / substeps(d, h or 0.0) for d in intervals))
    result.backend = getattr(getattr(mod, "module", mod), "BACKEND", "numpy")
    result.backend_note = backend_note
    if result.interrupted:
        raise SimulationInterrupted(result)
    return result


def fixed_step_plan(compiled, *, t_end: Optional[float] = None, n_out: Optional[int] = None,
                    solver: Optional[str] = None, step: Optional[float] = None) -> tuple[Optional[str], int]:
    """The fixed-step solver whose compiled step loop a run of `compiled` with these settings
    (as :func:`simulate` takes them, no `t_eval`) would use and its number of steps, as
    :func:`simulate` passes them to :func:`phc.codegen.backends.for_run`; ``(None, 0)`` for
    IDA and for a model with contacts (impacts: its runs keep the Python loop; switching conditions
    are watched in the compiled loops)."""
    options = RunOptions.of(compiled.description.options).with_overrides(t_end=t_end, n_out=n_out, solver=solver,
                                                                         step=step)
    return _loop_plan(compiled, options, np.linspace(options.t_start, options.t_end, options.n_out))


def _loop_plan(compiled, options: RunOptions, t_out: np.ndarray) -> tuple[Optional[str], int]:
    if not BACKENDS[options.solver].fixed_step or has_contacts(compiled.module):
        return None, 0
    return options.solver, _fixed_steps(t_out, options.step)


def _fixed_steps(t_out: np.ndarray, step: Optional[float]) -> int:
    """The number of steps a fixed-step solver takes over `t_out`: each output interval in
    equal steps no longer than `step` (one step each without it)."""
    return sum(substeps(d, step or 0.0) for d in np.diff(np.asarray(t_out, dtype=float)))


def initial_values(compiled, p: np.ndarray, initial: Optional[dict] = None) -> tuple[dict[int, float], set[int]]:
    """Initial values by variable index and the indices that are fixed (not guesses): the
    model's (:attr:`ModelDescription.initial <phc.codegen.description.ModelDescription.initial>`:
    a value written in parameters that `p` changes is evaluated again from the assembled
    system), then `initial` (by state name, a value or ``(value, True)`` for a guess); the
    energy accumulator starts fixed at 0.

    Raises
    ------
    SimulationSetupError
        For an unknown state or a value that is not finite, and when `p` changes a
        parameter an initial value is written in and `compiled` has no assembled system to
        evaluate it again (a model loaded from its description).
    """
    mod = compiled.module
    index = {name: j for j, name in enumerate(mod.VARIABLES)}
    values, fixed = {}, set()
    changed = _changed_parameters(mod, p)
    by_name: Optional[dict] = None  # sympy only for initial values written in overridden parameters
    memo: dict = {}  # the parameter factors of initial fields, evaluated once (phc.ir.initial_fields)
    for k, iv in enumerate(compiled.description.initial):
        affected = changed if iv.depends is None else changed.intersection(iv.depends)
        if not affected:
            values[index[iv.name]] = iv.value  # a number, or evaluated at these parameters when compiled
        elif compiled.dae is None:
            raise SimulationSetupError(f"the initial value of `{iv.name}` is written in parameters this run changes "
                                       f"({', '.join(sorted(affected))}); a model loaded from its description "
                                       "cannot evaluate it again: compile the model (phc.compile_model)")
        else:
            if by_name is None:
                import sympy as sp

                slot = {pname: i for i, pname in enumerate(mod.PARAMETERS)}  # not .index per parameter
                by_name = {par.symbol: sp.Float(float(p[slot[par.name]])) for par in compiled.dae.parameters}
            from phc.ir.initial_fields import evaluate

            values[index[iv.name]] = evaluate(compiled.dae.initial[k].expr, by_name, memo)
        if not iv.guess:
            fixed.add(index[iv.name])
    for name, spec in (initial or {}).items():
        if name not in index or not mod.DIFFERENTIAL[index[name]]:
            raise SimulationSetupError(f"`{name}` is not a state of the model; {_states_hint(name, mod)}")
        value, guess = spec if isinstance(spec, tuple) else (spec, False)
        if not math.isfinite(float(value)):
            raise SimulationSetupError(f"initial value of `{name}` must be a finite number, got {value}")
        values[index[name]] = float(value)
        (fixed.discard if guess else fixed.add)(index[name])
    bad = [mod.VARIABLES[j] for j, v in values.items() if not math.isfinite(v)]
    if bad:
        raise SimulationSetupError(f"the initial value of `{bad[0]}` is not finite with these parameter values")
    energy_idx = index["energy.supplied"]
    values[energy_idx] = 0.0
    fixed.add(energy_idx)
    return values, fixed


def _states_hint(name: str, mod) -> str:
    """What to say after "`name` is not a state": the states it is close to, else the
    states of its component, else the first states of the model."""
    import difflib

    states = [v for v, diff in zip(mod.VARIABLES, mod.DIFFERENTIAL) if diff and v != "energy.supplied"]
    close = difflib.get_close_matches(name, states, n=3, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(f"`{s}`" for s in close) + "?"
    comp = name.rpartition(".")[0]
    own = [s for s in states if s.rpartition(".")[0] == comp] or states
    listed = ", ".join(f"`{s}`" for s in own[:8]) + (f" (and {len(own) - 8} more)" if len(own) > 8 else "")
    return f"the states{f' of `{comp}`' if own is not states else ''} are {listed}"


def _changed_parameters(mod, p: np.ndarray) -> set[str]:
    """The parameters (base and derived) whose values in `p` differ from the defaults'."""
    try:
        default = np.asarray(parameter_vector(mod), dtype=float)
    except SimulationSetupError:  # the defaults' derived parameters are not finite: everything differs
        return set(mod.PARAMETERS)
    given = np.asarray(p, dtype=float)
    if given.shape != default.shape:
        return set(mod.PARAMETERS)
    return {mod.PARAMETERS[i] for i in np.flatnonzero(given != default)}


def start_state(compiled, p: np.ndarray, t0: float, values: dict[int, float], fixed: set[int],
                mod=None) -> InitialResult:
    """The consistent state at the start of a run (:func:`consistent_initial_conditions` with
    the guarded module, as `simulate` runs it), kept in ``compiled.cache`` (a
    :class:`~phc.codegen.compiled.RunCache`) for the last parameters,
    initial values and t₀ it was asked for: the certificate of every compilation solves it
    for the model's own values, and `simulate` with those values starts from it instead of
    solving again (the same solve, so the same numbers). Raises what the solve raises."""
    if mod is None:
        mod = guard(compiled.module, compiled.source, _locator(compiled))
    # what evaluates the functions (numpy or numba: equal up to rounding) is part of the key
    key = (getattr(mod, "BACKEND", "numpy"), float(t0), np.asarray(p, dtype=float).tobytes(),
           np.array(sorted(values), dtype=np.int64).tobytes(),
           np.array([values[j] for j in sorted(values)], dtype=float).tobytes(), tuple(sorted(fixed)))
    kept = compiled.cache.start_state
    if kept is None or kept[0] != key:
        with quiet_floating_point():
            kept = (key, consistent_initial_conditions(mod, p, t0, values, fixed))
        compiled.cache.start_state = kept
    init = kept[1]
    return InitialResult(init.y0.copy(), init.yp0.copy(), dict(init.chosen), init.residual, init.iterations)


def _setup_error(err: ModelEvaluationError, params: Optional[dict]) -> Exception:
    """A model that cannot be evaluated at the start: blamed on an overridden parameter it
    uses (a setup mistake), else returned as it is (a model error)."""
    blamed = [name for name in err.parameters if name in (params or {})]
    if blamed:
        values = ", ".join(f"`{name}` = {err.parameters[name]:g}" for name in blamed)
        inside = f" in `{err.expression}`" if err.expression else ""
        return SimulationSetupError(f"parameter {values} makes the model impossible to evaluate: {err.reason}{inside} "
                                    f"({err.subject} at t = {err.t:.6g}); choose another value")
    return err


def _locator(compiled) -> Callable[[str, str], Optional[str]]:
    """``locate(kind, label) -> "file:line"`` for equations, invariants and outputs (best effort)."""
    desc = compiled.description
    spans: dict = {}  # made on the first call (a message about a failure): a mesh has 10⁵-odd rows

    def locate(kind: str, label: str) -> Optional[str]:
        if not spans:
            spans.update({("equation", eq.label): eq.span for eq in desc.equations if eq.span is not None})
            for inv in desc.invariants + desc.velocity_invariants:
                if inv.span is not None:
                    spans[("invariant", inv.label)] = inv.span
            spans[None] = None  # made (a model may have no located row)
        span = spans.get((kind, label))
        if span is None and kind == "output":
            span = desc.output_spans.get(label)
        return f"{span.file}:{span.line}" if span is not None else None

    return locate


def _integrate_with_breakpoints(run, mod, p, t_out, init) -> BackendRun:
    """Integrate over `t_out`, stopping at each input breakpoint (module BREAKPOINTS: ends of
    pieces, table rows) and restarting there from a consistent state: the differential
    variables are continuous, the algebraic ones and ẏ may jump. A step input is thus
    located exactly rather than found by step rejections."""
    t0, t1 = float(t_out[0]), float(t_out[-1])
    breaks = breakpoints_within(getattr(mod, "BREAKPOINTS", ()), t0, t1)
    if not breaks:
        return _run_safely(run, t_out, init.y0, init.yp0)
    ends = [*breaks, t1]
    y0, yp0, start = init.y0, init.yp0, t0
    pieces, total = [], dict(steps=0, nfev=0, njev=0)
    out, note = None, None
    for end in ends:
        out = _run_safely(run, piece_grid(t_out, start, end), y0, yp0)
        for key in total:
            total[key] += getattr(out, key)
        note = out.extra.get("order_note") or note  # IDA's maximum order phc chose (simulation/order.py)
        run = partial(run.func, *run.args, **carry_order(run.keywords, out))
        pieces.append(dict(zip(("t", "y", "yp"), piece_outputs(out, t_out, start, end))))
        if not out.success or end == t1:
            break
        y_end = out.y[-1]
        dif = set(np.flatnonzero(np.asarray(mod.DIFFERENTIAL)).tolist())
        try:
            restart = consistent_initial_conditions(mod, p, end, dict(enumerate(y_end)), dif,
                                                    initial_relations=False)
        except InconsistentInitialError as err:
            out = out.replace(success=False, message=f"cannot restart after the input breakpoint at t = {end:.6g}: "
                              + "; ".join(err.problems))
            break
        except ModelEvaluationError as err:
            out = out.replace(success=False, message=f"cannot restart after the input breakpoint at t = {end:.6g}: "
                              f"{err}")
            break
        except KeyboardInterrupt:
            out = out.replace(success=False, interrupted=True, message=f"interrupted at t = {end:.6g}")
            break
        y0, yp0, start = restart.y0, restart.yp0, end
    merged = {k: np.concatenate([pc[k] for pc in pieces]) for k in ("t", "y", "yp")}
    _, first = np.unique(merged["t"], return_index=True)  # a breakpoint on the grid appears twice
    merged = {k: v[np.sort(first)] for k, v in merged.items()}
    return out.replace(**merged, **total, order_note=note)


def _run_safely(run, t_out, y0, yp0) -> BackendRun:
    """Run a backend; if it raises on a model evaluation or Ctrl-C before it could return its
    partial results, keep the start point."""
    try:
        return run(t_out, y0, yp0)
    except (ModelEvaluationError, KeyboardInterrupt) as err:
        t0 = float(t_out[0])
        interrupted = isinstance(err, KeyboardInterrupt)
        message = f"interrupted at t = {t0:.6g}" if interrupted else f"{err}; only the start point is kept"
        return BackendRun(t=np.asarray(t_out[:1], dtype=float), y=np.atleast_2d(np.asarray(y0, dtype=float)),
                          yp=np.atleast_2d(np.asarray(yp0, dtype=float)), steps=0, success=False, message=message,
                          interrupted=interrupted)


def _evaluate_along(mod, p, out: BackendRun) -> tuple[dict, Optional[ModelEvaluationError]]:
    """H, powers, invariants and outputs at the output times; stops at the first time where
    one cannot be evaluated (the results are cut there). Evaluated unguarded first (fast);
    only when that fails is the run repeated point by point through the guards."""
    t, y, yp = out.t, out.y, out.yp
    raw = getattr(mod, "module", mod)
    try:
        if getattr(raw, "BACKEND", "") == "c" and len(t) > 1:  # one call over all points (phc.codegen.c_steps)
            from phc.codegen import c_steps

            rows = c_steps.along(raw, p, t, y, yp)
            if rows is not None and all(np.isfinite(v).all() for v in rows.values()):
                return rows, None
        rows = {"H": [raw.hamiltonian(ti, yi, p) for ti, yi in zip(t, y)],
                "powers": [raw.powers(ti, yi, ypi, p) for ti, yi, ypi in zip(t, y, yp)],
                "scale": [float(raw.energy_scale(ti, yi, p)) for ti, yi in zip(t, y)],
                "inv": [raw.invariants(ti, yi, p) for ti, yi in zip(t, y)],
                "vinv": [raw.velocity_invariants(ti, yi, p) for ti, yi in zip(t, y)],
                "outs": [raw.outputs(ti, yi, ypi, p) for ti, yi, ypi in zip(t, y, yp)]}
        if all(np.isfinite(np.asarray(v, dtype=float)).all() for v in rows.values()):
            return rows, None
    except GUARD_CATCH:
        pass
    rows = {"H": [], "powers": [], "scale": [], "inv": [], "vinv": [], "outs": []}
    failure = None
    for ti, yi, ypi in zip(t, y, yp):
        try:
            row = dict(H=mod.hamiltonian(ti, yi, p), powers=mod.powers(ti, yi, ypi, p),
                       scale=float(mod.energy_scale(ti, yi, p)), inv=mod.invariants(ti, yi, p),
                       vinv=mod.velocity_invariants(ti, yi, p), outs=mod.outputs(ti, yi, ypi, p))
        except ModelEvaluationError as err:
            failure = err
            break
        for key, value in row.items():
            rows[key].append(value)
    return rows, failure


MANY_STEPS = 100_000
"""A successful IDA run with more steps than this says what may cost them (`_finish`), and so
does an IDA run that used up `max_steps`."""


def _finish(compiled, mod, p, out: BackendRun, init, cpu: float, options: RunOptions, params=None) -> SimResult:
    rows, failure = _evaluate_along(mod, p, out)
    n = len(rows["H"])
    if n == 0:  # not even the start point can be evaluated: nothing to keep
        raise _setup_error(failure, params)
    t, y, yp = out.t[:n], out.y[:n], out.yp[:n]
    success, message = out.success, out.message
    steps = out.steps
    # where the steps went: a successful IDA run of very many steps, or one that used up max_steps
    # (at the time IDA reached, which may lie beyond the last output time kept)
    used_up = bool(out.extra.get("max_steps_reached")) and steps > 0
    if options.solver == "ida" and (success and steps > MANY_STEPS and len(out.t) > 1 or used_up):
        ends = sorted({0, len(out.t) - 1})  # the modes at the start and at the end
        reached = float(out.extra.get("t_reached", out.t[-1])) if used_up else float(out.t[-1])
        if reached > out.t[0]:
            hint = many_steps_hint(mod, p, out.t[ends], out.y[ends], out.yp[ends], steps=steps,
                                   span=reached - float(out.t[0]),
                                   max_order=int(out.extra.get("max_order") or options.max_order or MAX_ORDER),
                                   rtol=options.rtol, atol=applied_atol(options.rtol, options.atol), stopped=used_up)
            message = f"{message}; {hint}"
    if out.extra.get("order_note"):  # the maximum order phc chose for IDA, and why (simulation/order.py)
        message = f"{message}; {out.extra['order_note']}"
    if failure is not None:
        if out.success:
            message = f"{failure}; results up to t = {t[-1]:.6g} are kept"
        else:  # the solver stopped where the model cannot be evaluated: its last point goes too
            message = f"{out.message} (cut to t = {t[-1]:.6g}: the {failure.function} fail at t = {failure.t:.6g})"
        success = False
    if not success and len(out.t) and not out.interrupted:
        # "results up to t_fail": the rows kept are the output times before it
        message = f"{message} ({n} output time(s) kept, the last at t = {t[-1]:.6g})"
    H = np.array(rows["H"], dtype=float)
    powers = np.array(rows["powers"], dtype=float).reshape(-1, 2)
    energy = y[:, mod.VARIABLES.index("energy.supplied")]
    balance = H - H[0] + energy
    scale = max(rows["scale"], default=0.0)
    inv = np.array(rows["inv"], dtype=float).reshape(n, -1)
    vinv = np.array(rows["vinv"], dtype=float).reshape(n, -1)
    outs = np.array(rows["outs"], dtype=float).reshape(n, len(mod.OUTPUTS))
    desc = compiled.description
    return SimResult(
        success=success, message=message, t=t, y=y, yp=yp, variables=tuple(mod.VARIABLES),
        differential=np.asarray(mod.DIFFERENTIAL), H=H, port_power=powers[:, 0], dissipation=powers[:, 1],
        energy_supplied=energy, outputs={name: outs[:, i] for i, name in enumerate(mod.OUTPUTS)},
        invariants=inv, invariant_labels=tuple(mod.INVARIANTS), velocity_invariants=vinv,
        energy_balance_error=float(np.abs(balance).max(initial=0.0)),
        energy_balance_relative=float(np.abs(balance).max(initial=0.0) / scale) if scale > 0 else 0.0,
        constraint_drift=float(np.abs(inv).max(initial=0.0)), velocity_drift=float(np.abs(vinv).max(initial=0.0)),
        steps=out.steps, n_residual_evals=out.nfev, n_jacobian_evals=out.njev, cpu_time_s=cpu,
        n_states=desc.n_states, n_equations=len(desc.equations), solver=options.solver, rtol=options.rtol,
        atol=options.atol,
        initial_choices=init.chosen, interrupted=out.interrupted, events=list(out.events), units=dict(desc.units),
    )


__all__ = ["simulate", "SimResult", "SimulationInterrupted", "ModelEvaluationError", "BACKENDS", "Backend", "BackendRun",
           "fixed_step_plan",
           "IgnoredOptionWarning",
           "InconsistentInitialError", "initial_values", "parameter_vector", "start_state"]
