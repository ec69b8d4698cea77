"""Setting up and guarding the runs of `phc simulate`, `animate`, `sweep` and `linearize`.

Compiling a model or scene (its diagnostics printed, exit 1 on errors); the progress bar;
a `--param` that needs a recompilation; the accuracy settings the file writes, and a
located warning at each one this run's solver ignores (PHC-W250); setup mistakes turned
into usage errors and inconsistent initial values into located lines (PHC-E218). Part
of :mod:`phc.cli`.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from typing import Sequence

from phc.cli.report import EXIT_MODEL, _Exit, _print_diagnostics
from phc.errors import UsageError
from phc.inert import inert, printable


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
    from phc.spec.load import load_spec
    from phc.frontend.scene import is_scene_file, load_scene

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
    from phc.spec.load import load_spec
    from phc.frontend.scene import is_scene_file, load_scene

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
    names = ignored_in_file(backend, written, given)
    own = BACKENDS.get(compiled.options.get("solver"))
    kept = []
    if args.solver and own is not None and own is not backend:
        # settings the file's own solver uses are for it, not mistakes: said at most once, in
        # one line, and not when `--step` sets this run's accuracy (then ignored_in_file is empty)
        kept = [name for name in names if name in own.honours]
        names = [name for name in names if name not in own.honours]
    lines = []
    for name in names:
        where, entry = written[name]
        if backend.fixed_step:
            hint = (f"remove `{name}`, or write `step:` beside it (default: the output interval) to keep "
                    f"`{name}` for `--solver ida`")
        else:
            hint = ("`step` is for the fixed-step solvers: remove it, or write `rtol:` beside it to keep "
                    "`step` for `--solver midpoint`")
        lines.append(f"{where}: warning: {entry}: {ignored_option_message(backend, [name])}. hint: {hint} "
                     "[PHC-W250]")
    if kept and backend.fixed_step:
        one = len(kept) == 1
        entries = ", ".join(f"`{written[name][1]}`" for name in kept)
        lines.append(f"{written[kept[0]][0]}: warning: {entries} {'is' if one else 'are'} for the file's solver "
                     f"`{own.name}`: `--solver {backend.name}` ignores {'it' if one else 'them'} and steps at the "
                     "output interval. hint: give `--step` to set this run's accuracy [PHC-W250]")
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
            print(inert(line), file=sys.stderr)
        raise _Exit(EXIT_MODEL) from None
    except SimulationSetupError as err:
        progress.close()
        raise UsageError(str(err)) from err
    except ModelEvaluationError as err:  # the model cannot be evaluated at the start
        progress.close()
        print(printable(f"{path}: {err}", quoted=False), file=sys.stderr)
        raise _Exit(EXIT_MODEL) from None
    except KeyboardInterrupt:
        progress.close()
        raise
    progress.close()


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
        print(printable(f"{path}: note: {note}", quoted=False), file=sys.stderr)
    return compiled


@contextmanager
def _terminate_as_interrupt():
    """Within the block, SIGTERM (`kill`, a batch system's stop) ends the command as Ctrl-C
    does: the sweep's workers are stopped and the finished rows kept. Yields a list that
    holds the signal's number once it came. A second SIGTERM during the clean-up is ignored
    (SIGKILL still ends the process; the workers end with it on Linux)."""
    import signal
    import threading

    got: list = []
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "SIGTERM"):
        yield got
        return

    def handler(signum, frame):
        got.append(signum)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield got
    finally:
        signal.signal(signal.SIGTERM, previous)
