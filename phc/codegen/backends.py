"""Choosing the backend that runs the generated functions.

Input: the NumPy module printed and loaded for a model (the reference backend) and the
:class:`~phc.codegen.lower.ResidualIR` it was printed from. Output: the module to run —
the reference itself (``numpy``), or the same functions compiled to machine code:
``numba`` (:mod:`phc.codegen.numba_backend`; needs the optional dependency,
``pip install "port-hamiltonian-compiler[fast]"``) or ``c`` (:mod:`phc.codegen.c_backend`:
C99 compiled by the system C compiler, loaded through ctypes; only when asked for).

``auto`` (the default, or ``$PHC_BACKEND``) picks ``numba`` when numba can be imported and
the model has at least :data:`AUTO_MIN_UNKNOWNS` unknowns, ``numpy`` otherwise; a compiled
module that disagrees with the reference at its check point is never used (a warning says
so and the reference runs). Asking for ``numba`` explicitly where it cannot be imported is
an error that says how to install it; asking for ``c`` where no C compiler is found, or for
a model using something the C back end does not print yet (an input table), is an error
that says so in one line. ``auto`` never picks ``c`` (yet).
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
"""``auto`` compiles models with at least this many unknowns. Below, the NumPy module is
as fast per call (a handful of float operations; calling compiled code from Python costs
about a microsecond itself) and needs neither numba's import nor a compilation."""


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
    if choice == "auto" and reference.N < AUTO_MIN_UNKNOWNS:
        return reference, auto_note(reference)
    from phc.codegen import numba_backend

    ok, why = numba_backend.available()
    if not ok:
        if choice == "numba":
            raise SimulationSetupError(f"the numba backend is not available: {why}; or use --backend numpy")
        return reference, f"numpy (compiled backend unavailable: {why})"
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
    return module, ""


def _select_c(ir, reference: ModuleType, source: str) -> tuple[ModuleType, str]:
    from phc.codegen import c_backend
    from phc.errors import BackendMismatch, BackendUnsupported, CompiledBackendWarning

    ok, why = c_backend.available()
    if not ok:
        raise SimulationSetupError(f"the C backend is not available: {why}")
    try:
        module, _ = c_backend.load_compiled(ir, reference, source)
    except BackendUnsupported as err:
        raise SimulationSetupError(f"{err}; run this model with --backend numpy (or numba)") from None
    except BackendMismatch as err:
        warnings.warn(f"{err}; running the NumPy module instead (please report this phc bug)",
                      CompiledBackendWarning, stacklevel=3)
        return reference, f"numpy ({err})"
    except Exception as err:  # the compiler refused the code: a phc bug, never a failed run
        first = (str(err).strip().splitlines() or [""])[0][:300]
        warnings.warn(f"the C backend could not build this model's functions ({type(err).__name__}: {first}); "
                      "running the NumPy module instead (please report this phc bug)", CompiledBackendWarning,
                      stacklevel=3)
        return reference, f"numpy (C compilation failed: {type(err).__name__})"
    return module, ""


def auto_note(module) -> str:
    """Why ``auto`` runs the NumPy module for a model this small."""
    return (f"auto: {module.N} unknowns, below {AUTO_MIN_UNKNOWNS}, where the NumPy module is as fast per call; "
            "--backend numba compiles it anyway")


def describe(module, requested: Optional[str] = None) -> str:
    """One line on what runs `module`'s functions and, for the NumPy module, why."""
    if name_of(module) == "c":
        return f"c: compiled functions ({module.C_REPORT.describe()})"
    report = getattr(module, "COMPILE_REPORT", None)
    if report is not None:
        return f"numba: compiled functions ({report.describe()})"
    if check_choice(requested) == "numpy":
        return "numpy"
    if check_choice(requested) == "c":
        return "numpy (the C backend could not build this model's functions: see the warning)"
    if getattr(module, "N", AUTO_MIN_UNKNOWNS) < AUTO_MIN_UNKNOWNS:
        return f"numpy ({auto_note(module)})"
    from phc.codegen.numba_cache import why_unavailable

    why = why_unavailable()
    return f"numpy (compiled backend unavailable: {why})" if why else "numpy"


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
        raise SimulationSetupError(f"backend `{backend}`: this model was loaded from its description (phc.fastpath), "
                                   f"which runs on `{current}` only; compile it (phc.compile_model) for another")
    from phc.codegen.lower import lower_residual

    start = time.perf_counter()
    module, _ = select(lower_residual(compiled.dae), reference, compiled.source, choice)
    timings = compiled.cache.timings  # phc.compiled.RunCache
    timings["backend"] = timings.get("backend", 0.0) + time.perf_counter() - start
    return module


__all__ = ["AUTO_MIN_UNKNOWNS", "CHOICES", "auto_note", "check_choice", "default_choice", "describe", "for_compiled",
           "name_of", "reference_of", "select"]
