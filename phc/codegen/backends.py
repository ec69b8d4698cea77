"""Choosing the backend that runs the generated functions.

Input: the NumPy module printed and loaded for a model (the reference backend) and the
:class:`~phc.codegen.lower.ResidualIR` it was printed from. Output: the module to run —
the reference itself (``numpy``), or the same functions compiled to machine code:
``numba`` (:mod:`phc.codegen.numba_backend`; needs the optional dependency,
``pip install "port-hamiltonian-compiler[fast]"``) or ``c`` (:mod:`phc.codegen.c_backend`:
C99 compiled by the system C compiler, loaded through ctypes).

``auto`` (the default, or ``$PHC_BACKEND``) runs a model on ``c`` when a C compiler is found
and the C back end prints and builds the model, up to :data:`AUTO_MAX_NONZEROS` Jacobian
nonzeros (above, a mesh whose arrays would be compiled into the code, on ``numpy``); else, for a model of
:data:`AUTO_MIN_UNKNOWNS` unknowns or more, on ``numba`` when numba can be imported; else on
``numpy``. C comes first because it costs least to build (a model's library compiles in a fraction of a
second and is cached by content, where numba's functions take seconds and its step loop
minutes once per machine) and its functions cost least to call from Python, on small models
too: IDA and the drivers call them through phc's call bridge (:mod:`phc.codegen.c_bridge`,
the buffer protocol in C), or through ctypes where Python's C headers
are missing (a few microseconds more a call; the backend line says so).
``benchmarks/bench_backends.py`` measures the three per call and per step. A compiled module
that disagrees with the reference at its check point is never used (a warning says so and the
next choice runs). Asking for ``numba`` explicitly where it cannot be imported is
an error that says how to install it; asking for ``c`` where no C compiler is found, or for
a model using something the C back end does not print yet (an input table), is an error
that says so in one line.

A run of a fixed-step solver (``midpoint``, ``discrete_gradient``, ``midpoint4``) is different:
its whole step loop runs compiled on the numba or C back end (:mod:`phc.simulation.compiled_steps`),
20–100 times faster a step than the Python loop on the NumPy module, however small the model.
So when ``auto`` ran the NumPy module (no C: below :data:`AUTO_MIN_UNKNOWNS` unknowns)
and a run takes at least :data:`AUTO_LOOP_STEPS` fixed steps, :func:`for_run` runs it on
numba's compiled step loop when numba can be imported (C is tried first, for a model the C
back end could not build at compile time and can now), else on NumPy with the reason in the
run's note. An explicit ``numpy`` never switches; IDA keeps the size rule.
"""

from __future__ import annotations

import os
import time
import warnings
from types import ModuleType
from typing import Optional

from phc.errors import SimulationSetupError

CHOICES = ("auto", "numpy", "numba", "c")
"""Accepted values of ``backend=`` and ``--backend``."""

AUTO_MIN_UNKNOWNS = 16
"""Where ``auto`` cannot run C, it compiles with numba models of at least this many unknowns.
Below, numba's compilation (seconds cold, its import about a second warm) costs more than its
calls save on a run: the model's functions are a handful of float operations."""

AUTO_MAX_NONZEROS = 1 << 20
"""Above this many Jacobian nonzeros (a mesh of about 2·10⁴ beam elements) ``auto`` runs the
NumPy module. The compiled back ends print a mesh's index and value arrays into their source
(the C text of a 2·10⁴-element Euler–Bernoulli beam, 1.08·10⁶ nonzeros, is 35 MB), and their
compilation's time and memory grow with it: that beam took 11 s and 270 MiB more to compile on C
than on NumPy, and the 10⁵-element beam's ``phc simulate`` peaked at 2.5 GiB on C against 1.9 on
NumPy. What a mesh's run computes is its sparse products (SciPy's, on NumPy), and its fixed-step
runs keep the Python step loop at that size anyway. ``--backend c`` or ``numba`` compiles it."""

AUTO_LOOP_STEPS = 2000
"""Where ``auto`` ran the NumPy module (no C), a fixed-step solver's run of at least this many
steps runs on numba's compiled step loop (:func:`for_run`), and a shorter one too once the
model has built that loop (its cost is then paid). The switch has a one-off cost per model
against the time each step saves. Measured on the pendulum (7 unknowns; 2-core x86-64 at load
average ~3, ``nice -n 19``): the NumPy module's Python loop takes 1.35 ms a midpoint step
(about 0.86 ms on a quiet machine), numba's loop 13 µs. Once per run: numba's model functions
cost 2.0 s when loaded from phc's cache (lowering, numba's import, the cache load) and 4.0 s
when compiled cold, its step loop 0.4 s from the cache (compiling it cold is a one-off per
machine: ~2 min). At about 1 ms a step saved, 2000 steps (2–2.7 s on NumPy) pay back a warm
numba load; a model's first, cold numba compilation pays back from about 3500 steps, and is
cached for every later run. Below the threshold a run takes at most a few seconds on NumPy
anyway."""


def default_choice() -> str:
    """``$PHC_BACKEND`` when set to one of :data:`CHOICES`, else ``auto``."""
    value = os.environ.get("PHC_BACKEND", "").strip().lower()
    return value if value in CHOICES else "auto"


def check_choice(backend: Optional[str]) -> str:
    """`backend` validated (None means :func:`default_choice`)."""
    if backend is None:
        return default_choice()
    value = str(backend).strip().lower()
    if value not in CHOICES:
        raise SimulationSetupError(f"unknown backend `{backend}`; choose one of {', '.join(CHOICES)}")
    return value


def name_of(module) -> str:
    """The backend a loaded module runs on (``numpy``, ``numba`` or ``c``)."""
    return getattr(module, "BACKEND", "numpy")


def reference_of(module):
    """The NumPy module behind `module` (itself for a NumPy module)."""
    return getattr(module, "REFERENCE", module)


def select(ir, reference: ModuleType, source: str, backend: Optional[str] = None) -> tuple[ModuleType, str]:
    """The module to run for `backend` and a note on the choice (empty when it is what was
    asked for). Raises :class:`~phc.errors.SimulationSetupError` when ``numba`` is asked
    for explicitly and cannot be imported, or ``c`` and there is no C compiler or the model
    uses something the C back end does not print."""
    choice = check_choice(backend)
    if choice == "numpy":
        return reference, ""
    if choice == "c":
        return _select_c(ir, reference, source)
    c_why = ""
    if choice == "auto" and len(ir.jac_rows) > AUTO_MAX_NONZEROS:
        reference.__auto_note__ = (f"auto: {len(ir.jac_rows):,} Jacobian nonzeros, above {AUTO_MAX_NONZEROS:,}, "
                                   "where compiling a mesh's arrays into C or numba costs more time and memory than "
                                   "its sparse products save; --backend c compiles it anyway")
        return reference, reference.__auto_note__
    if choice == "auto":
        module, c_why = _auto_c(ir, reference, source)
        if module is not None:
            return module, ""
        if reference.N < AUTO_MIN_UNKNOWNS:
            # kept for `describe`; a dunder name, so the compiled modules built from this one
            # later (which copy its other attributes) do not inherit it
            reference.__auto_note__ = auto_note(reference, c_why)
            return reference, reference.__auto_note__
    from phc.codegen import numba_backend

    ok, why = numba_backend.available()
    if not ok:
        if choice == "numba":
            raise SimulationSetupError(f"the numba backend is not available: {why}; or use --backend numpy")
        return reference, f"numpy (compiled backends unavailable: {c_why}; {why})"
    try:
        module, _ = numba_backend.load_compiled(ir, reference, source)
    except numba_backend.BackendMismatch as err:
        warnings.warn(f"{err}; running the NumPy module instead (please report this phc bug)",
                      numba_backend.CompiledBackendWarning, stacklevel=2)
        return reference, f"numpy ({err})"
    except Exception as err:  # numba or LLVM refused the code: a phc bug, never a failed run
        first = (str(err).strip().splitlines() or [""])[0][:200]
        warnings.warn(f"the compiled backend could not build this model's functions ({type(err).__name__}: "
                      f"{first}); running the NumPy module instead (please report this phc bug)",
                      numba_backend.CompiledBackendWarning, stacklevel=2)
        return reference, f"numpy (compilation failed: {type(err).__name__})"
    if c_why:
        module.AUTO_NOTE = f"auto: the C backend is not used ({c_why})"
    return module, ""


def _select_c(ir, reference: ModuleType, source: str) -> tuple[ModuleType, str]:
    from phc.codegen import c_backend
    from phc.errors import BackendUnsupported

    ok, why = c_backend.available()
    if not ok:
        raise SimulationSetupError(f"the C backend is not available: {why}")
    try:
        return _load_c(ir, reference, source)
    except BackendUnsupported as err:
        raise SimulationSetupError(f"{err}; run this model with --backend numpy (or numba)") from None


def _auto_c(ir, reference: ModuleType, source: str) -> tuple[Optional[ModuleType], str]:
    """``auto`` for a model of :data:`AUTO_MIN_UNKNOWNS` unknowns or more, first choice: (the C
    module, "") when a C compiler is found and the C back end prints the model and builds it,
    else (None, why not): numba is tried next."""
    from phc.codegen import cc
    from phc.errors import BackendUnsupported

    c_ok, c_why = cc.available()
    if not c_ok:
        return None, c_why
    try:
        module, note = _load_c(ir, reference, source)
    except BackendUnsupported as err:
        return None, f"the C backend: {err}"
    if name_of(module) != "c":  # a mismatch or a failed compilation: warned (a phc bug)
        return None, note[len("numpy ("):-1] if note.startswith("numpy (") else note
    return module, ""


def _load_c(ir, reference: ModuleType, source: str) -> tuple[ModuleType, str]:
    """The C module and an empty note; the reference and the reason after a warning when the
    library disagrees with the reference or the compiler refuses the code (a phc bug, never a
    failed run). ``BackendUnsupported`` (something the C back end does not print) is raised."""
    from phc.codegen import c_backend
    from phc.errors import BackendMismatch, BackendUnsupported, CompiledBackendWarning

    try:
        module, _ = c_backend.load_compiled(ir, reference, source)
    except BackendUnsupported:
        raise
    except BackendMismatch as err:
        warnings.warn(f"{err}; running the NumPy module instead (please report this phc bug)",
                      CompiledBackendWarning, stacklevel=4)
        return reference, f"numpy ({err})"
    except Exception as err:  # the compiler refused the code: a phc bug, never a failed run
        first = (str(err).strip().splitlines() or [""])[0][:300]
        warnings.warn(f"the C backend could not build this model's functions ({type(err).__name__}: {first}); "
                      "running the NumPy module instead (please report this phc bug)", CompiledBackendWarning,
                      stacklevel=4)
        return reference, f"numpy (C compilation failed: {type(err).__name__})"
    return module, ""


def auto_note(module, c_why: str) -> str:
    """Why ``auto`` runs the NumPy module for a model this small: C is not used (`c_why`), and
    numba's compilation costs more than it saves below :data:`AUTO_MIN_UNKNOWNS` unknowns."""
    return (f"auto: the C backend is not used ({c_why}); {module.N} unknowns, below {AUTO_MIN_UNKNOWNS}, where "
            f"numba's compilation (seconds) costs more than its calls save (a fixed-step run of {AUTO_LOOP_STEPS} "
            "steps or more runs on its compiled step loop); --backend numba compiles it anyway")


def describe(module, requested: Optional[str] = None) -> str:
    """One line on what runs `module`'s functions and, when ``auto`` did not run C, why."""
    auto = check_choice(requested) == "auto"
    if name_of(module) == "c":
        line = f"c: compiled functions ({module.C_REPORT.describe()})"
        from phc.codegen import c_bridge

        why = c_bridge.why_not()
        return line + (f"; called through ctypes: {why}" if why else "")
    report = getattr(module, "COMPILE_REPORT", None)
    if report is not None:
        line = f"numba: compiled functions ({report.describe()})"
        note = getattr(module, "AUTO_NOTE", "")
        return line + (f"; {note}" if auto and note else "")
    if check_choice(requested) == "numpy":
        return "numpy"
    if check_choice(requested) == "c":
        return "numpy (the C backend could not build this model's functions: see the warning)"
    if getattr(module, "__auto_note__", "") and (getattr(module, "N", AUTO_MIN_UNKNOWNS) < AUTO_MIN_UNKNOWNS
                                                 or len(getattr(module, "JAC_ROWS", ())) > AUTO_MAX_NONZEROS):
        return f"numpy ({module.__auto_note__})"
    from phc.codegen import cc
    from phc.codegen.numba_cache import why_unavailable

    why = why_unavailable()
    c_ok, c_why = cc.available()
    if c_ok:
        return "numpy (the compiled backends could not build this model's functions: see the warnings)" if not why \
            else f"numpy (the C backend could not build this model's functions; numba unavailable: {why})"
    return f"numpy (compiled backends unavailable: {c_why}; {why})" if why else \
        "numpy (the compiled backend could not build this model's functions: see the warning)"


def for_run(compiled, backend: Optional[str], method: Optional[str], steps: int) -> tuple[ModuleType, str]:
    """The module a run of `compiled` uses and a one-line note on the choice (empty when it
    is what :func:`for_compiled` gives with nothing to add).

    `method` is the fixed-step solver whose compiled step loop would run (None for IDA and
    for runs that keep the Python loop, e.g. with switching conditions), `steps` the number
    of steps it takes. `backend` None means what `compiled` was compiled with
    (``compiled.backend_request``). The rule is in the module docstring. The module built is
    kept in ``compiled.cache.run_modules``; a model loaded from its description (no
    ``compiled.dae``) uses the one its cached front end put there (:mod:`phc.codegen.fastpath`)."""
    module = for_compiled(compiled, backend)
    targets, why_numpy, note = _run_targets(compiled, module, backend, method, steps)
    if not targets and method is not None and steps < AUTO_LOOP_STEPS:
        # the threshold weighs the one-off cost of building the compiled loop; where this model
        # has built it already, a shorter run takes it too (else a finer step, over the
        # threshold, ran 10–40 times faster than a coarser one: the work check of `phc bench`)
        longer, why_numpy, _ = _run_targets(compiled, module, backend, method, AUTO_LOOP_STEPS)
        kept = [target for target in longer if target in compiled.cache.run_modules]
        if kept:
            built = compiled.cache.run_modules[kept[0]]
            return built, (f"{describe(built)}; auto: {steps} {method} steps, below {AUTO_LOOP_STEPS}, on the "
                           f"compiled step loop this model has built already ({why_numpy})")
    if not targets:
        return module, note
    what = f"{steps} {method} steps, at least {AUTO_LOOP_STEPS}"
    kept = [target for target in targets if target in compiled.cache.run_modules]  # built once per model
    if kept:
        built = compiled.cache.run_modules[kept[0]]
        return built, f"{describe(built)}; auto: {what}, run on the compiled step loop ({why_numpy})"
    if compiled.dae is None:
        return module, (f"numpy (auto: {why_numpy}; {what}, would run faster on a compiled step loop, but this model "
                        "was loaded from its description (CompiledModel.from_description), which cannot build one; "
                        "--backend numba or c compiles it)")
    refused = []
    for target in targets:
        try:
            built = for_compiled(compiled, target)
        except SimulationSetupError as err:  # the C back end does not print something the model uses
            refused.append(str(err))
            continue
        if name_of(built) == "numpy":  # a mismatch or a failed compilation: warned, the reference runs
            refused.append(f"{target} could not build the model's functions")
            continue
        compiled.cache.run_modules[target] = built
        return built, f"{describe(built)}; auto: {what}, run on the compiled step loop ({why_numpy})"
    return module, f"numpy (auto: {why_numpy}; no compiled step loop for {what}: {'; '.join(refused)})"


def run_targets(compiled, backend: Optional[str], method: Optional[str], steps: int) -> list[str]:
    """The compiled backends :func:`for_run` tries for this run instead of the module
    `compiled` was compiled with (``numba``, or none): it runs on the first it has built or
    can build. Empty when the run stays on that module."""
    return _run_targets(compiled, for_compiled(compiled, backend), backend, method, steps)[0]


def _run_targets(compiled, module, backend, method, steps) -> tuple[list[str], str, str]:
    """(the compiled backends to try, why auto ran NumPy, the note when there are none).
    Only numba: ``auto`` runs a model on NumPy when the C back end cannot (no compiler, or a
    model it does not print), and then it cannot run C's step loop either."""
    request = check_choice(backend) if backend is not None else getattr(compiled, "backend_request", None)
    if request != "auto" or name_of(module) != "numpy" or method is None or steps < AUTO_LOOP_STEPS:
        return [], "", ""
    if module.N >= AUTO_MIN_UNKNOWNS:  # auto tried C and numba and could use neither (the note says why)
        return [], "", ""
    from phc.codegen import numba_cache  # does not import sympy: a cached front end asks this too (phc.codegen.fastpath)

    numba_ok, numba_why = numba_cache.available()
    why_numpy = f"{module.N} unknowns, below {AUTO_MIN_UNKNOWNS}, without C"
    if not numba_ok:
        what = f"{steps} {method} steps, at least {AUTO_LOOP_STEPS}"
        return [], why_numpy, f"numpy (auto: {why_numpy}; no compiled step loop for {what}: {numba_why})"
    return ["numba"], why_numpy, ""


def kept_text(module) -> Optional[object]:
    """What loads a compiled module again without the model's system, JSON data: a numba
    module's ``KERNEL`` (:func:`phc.codegen.numba_cache.load_cached`), a C module's
    ``C_SOURCE`` (:func:`phc.codegen.c_backend.load_source`); None for another module."""
    attribute = {"numba": "KERNEL", "c": "C_SOURCE"}.get(name_of(module))
    return getattr(module, attribute, None) if attribute else None


def for_compiled(compiled, backend: Optional[str]) -> ModuleType:
    """The module of `compiled` (a :class:`~phc.pipeline.CompiledModel`) on `backend`; None
    keeps the one it was compiled with. A compiled backend not built at compile time is
    built here (lowering the DAE again)."""
    if backend is None:
        return compiled.module
    choice = check_choice(backend)
    current = name_of(compiled.module)
    reference = reference_of(compiled.module)
    if choice == "numpy" or choice == current or (choice == "auto" and current != "numpy"):
        return reference if choice == "numpy" else compiled.module
    if compiled.dae is None:
        raise SimulationSetupError(f"backend `{backend}`: this model was loaded from its description (phc.codegen.fastpath), "
                                   f"which runs on `{current}` only; compile it (phc.compile_model) for another")
    from phc.codegen.lower import lower_residual

    start = time.perf_counter()
    module, _ = select(lower_residual(compiled.dae), reference, compiled.source, choice)
    timings = compiled.cache.timings  # phc.codegen.compiled.RunCache
    timings["backend"] = timings.get("backend", 0.0) + time.perf_counter() - start
    return module


__all__ = ["AUTO_LOOP_STEPS", "AUTO_MAX_NONZEROS", "AUTO_MIN_UNKNOWNS", "CHOICES", "auto_note", "check_choice", "default_choice", "describe",
           "for_compiled", "for_run", "kept_text", "name_of", "reference_of", "run_targets", "select"]
