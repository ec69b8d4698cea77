"""The fixed-step solvers' whole step loop as compiled code (numba), for small and mid-size systems.

When a model runs on the ``numba`` backend (:mod:`phc.codegen.numba_backend`) and has at
most :data:`MAX_UNKNOWNS` unknowns, `midpoint`, `discrete_gradient` and `midpoint4` run
their steps in one compiled function that calls the model's compiled residual, Jacobian,
invariants, H and powers directly (numba first-class functions: no Python in between):

* the simplified Newton iteration of :class:`~phc.simulation.midpoint.StageSolver` — the same
  code, :func:`phc.simulation.step_logic.newton`, jitted: the same stopping rules, the same refresh
  of the Newton matrix on poor contraction, step-size change, a moved evaluation point or age,
  the GGL position constraints imposed at the step ends — with the Newton matrix as a dense
  LU (LAPACK ``dgetrf``) turned into
  its inverse (``dgetri``) once per factorization, so that each of the many corrections
  with one matrix is a matrix–vector product (BLAS ``dgemv``: half the time of the two
  triangular solves ``dtrsv`` it replaced at 83 unknowns; all through
  ``scipy.linalg.cython_lapack``/``cython_blas``), one factorization per distinct substep
  size as in Python;
* from :data:`MIXED_PRECISION_MIN` unknowns on, the corrections in mixed precision: the
  product with a single-precision copy of the inverse (``sgemv``, about 0.6× the time of
  ``dgemv``), equilibrated by powers of two so that any units stay in range, while the
  residual, the iterate and the convergence test stay in double. A simplified Newton
  iteration converges to the solution of F = 0 with any approximate inverse that contracts:
  the copy's round-off (about 6e-8 times the equilibrated matrix's condition number) only
  adds to the contraction rate θ, which the iteration measures anyway (C. T. Kelley,
  "Newton's method in mixed precision", SIAM Review 64, 2022). Where a matrix factorized in
  this solve contracts worse than :data:`~phc.simulation.midpoint.REFACTOR_RATE`, the
  correction is redone in double; if double then contracts, that is a strike, and after
  :data:`LOW_PRECISION_STRIKES` strikes (a near-singular configuration) the run keeps double
  precision. ``PHC_MIXED_PRECISION=0`` switches it off;
* the discrete-gradient step's secant iteration on the mean-value point
  (:mod:`phc.simulation.discrete_gradient`) and midpoint4's composition with its
  predictor and passivity guard (:mod:`phc.simulation.midpoint4`), again the code the Python
  loop runs (:mod:`phc.simulation.step_logic`);
* the routine part of the driver of :func:`~phc.simulation.midpoint.integrate_fixed_step`, again
  its code (:mod:`phc.simulation.step_logic`: ``next_step``, ``predict``, ``looks``, ``accept``):
  the output grid and its equal substeps, the predictor of the step midpoints (the polynomial of
  degree :data:`~phc.simulation.midpoint.PREDICTOR_ORDER` through the last ones), the singularity
  monitor's routine look every :data:`~phc.simulation.midpoint.MONITOR_EVERY` steps (the equilibrated
  iteration matrix's singular values by LAPACK ``dgesdd``, unless the condition estimate
  ``dgecon`` puts it far from singular: :data:`~phc.codegen.numba_steps_kernel._RCOND_MARGIN`),
  ``max_steps``.

The compiled function runs chunks of steps (about :data:`CHUNK_SECONDS` each) and returns
to Python between them: progress is reported and Ctrl-C is seen there. Whatever is not
routine goes back to the Python code, which then does exactly what the Python loop does: a
step whose Newton iteration fails from the predictor (the retry from the constant
predictor, the split, the failure message naming the row or expression that could not be
evaluated), a step Newton found ill-conditioned (the monitor's look with the looser
threshold), a routine look that finds the matrix nearly singular (the message), and in a run
with switching conditions (:mod:`phc.simulation.events`) the step at whose end a watched
switching function has fallen through zero: the chunk evaluates them after each step (the
model's ``events``, which the numba back end leaves as NumPy text, compiled here per model:
:func:`_events_function`; the run's modes as :func:`watch_map`), and the Python loop's
:func:`~phc.simulation.midpoint._locate` finds the event, which the run returns as the Python
loop does. Runs with contacts (impacts, whose watched functions are Python's) keep the Python
loop. The trajectory is the Python loop's up to the Newton tolerance (a dense inverse instead of
SuperLU: the corrections differ by round-off), and so are the events' times, each located to
:data:`~phc.simulation.midpoint.EVENT_TOL`.

The compiled loop is model-independent (the model's functions are arguments), compiled once
and kept in phc's signed cache of compiled code (``<phc cache>/numba/``, see
:mod:`phc.codegen.numba_backend`); :func:`enabled` says whether a run uses it, and
``PHC_COMPILED_LOOP=0`` switches it off.

On the C back end (:mod:`phc.codegen.c_backend`), :func:`integrate` runs the chunks of all three
methods in C instead (``phc/codegen/c_runtime/steps.c``, built and bound by
:mod:`phc.codegen.c_steps`): a port of the same step logic on the same state arrays, so that
everything between chunks — progress, Ctrl-C, the steps handed back — is this driver's, shared.

Where what lives: this module is the Python side — whether a run uses the loop
(:func:`enabled`), building it once per process and keeping it in the cache (:func:`_build`,
:func:`_compile`, :func:`_attach_cache`), the model's functions handed to it
(:func:`_functions`) and the driver between chunks (:func:`integrate`). The code numba
compiles, the chunk of steps and everything it calls, with the layout of the state arrays
both sides share, is :mod:`phc.codegen.numba_steps_kernel`; its names are importable
from here as well (module ``__getattr__``). The cache stamp covers the text of both files.
"""

from __future__ import annotations

import hashlib
import os
import time
import warnings
import weakref
from pathlib import Path
from typing import Optional

import numpy as np

from phc.codegen import numba_steps_kernel as _kernel
from phc.simulation import step_logic as _step_logic
from phc.simulation.backend import BackendRun
from phc.codegen.numba_steps_kernel import (  # the layout of the state arrays the kernel shares
    _BUDGET, _CODE, _DONE, _E, _EVENT, _H, _H_PREV, _HARD, _HIST, _ILL, _K, _LAST_LOOK, _LOOK, _LOWP, _MAX_STEPS,
    _MAXSTEPS, _METHOD, _MONITOR, _NEND, _NF, _NFACT, _NFEV, _NI, _OK, _ONE, _STATUS, _STEP,
    _RUN_ENERGY, _STEPS, _STRIKES, _STRIKES_C, _T, _THRESHOLD, _ZERO)

MAX_UNKNOWNS = 400
"""Largest system whose step loop is compiled (dense LU); larger ones keep the sparse Python loop."""
CHUNK_SECONDS = 0.05
"""Wall time of one compiled chunk of steps (progress and Ctrl-C are handled between chunks)."""

METHODS = {"midpoint": 0, "discrete_gradient": 1, "midpoint4": 2}

MIXED_PRECISION_MIN = 32
"""Smallest system whose Newton corrections use a single-precision copy of the inverse Newton
matrix (:func:`~phc.codegen.numba_steps_kernel._lowprec`); ``PHC_MIXED_PRECISION=0``
keeps double precision throughout. Below this size a double-precision product costs no more
(``dgemv`` against ``sgemv``, measured on 2-core x86-64: equal at 16 unknowns, 0.45–0.66×
from 32 to 400)."""
LOW_PRECISION_STRIKES = 3
"""Corrections redone in double precision (a freshly factorized matrix whose single-precision
copy contracted worse than ``REFACTOR_RATE``) after which a run keeps double precision."""

_READY = None
"""(kernel, dummy invariants) once built; () when the compiled loop cannot be built here."""
_WHY = ""


_SOURCE_FILES = (Path(_kernel.__file__), Path(_step_logic.__file__), Path(__file__))
"""The files the compiled loop's code comes from: the kernel's functions, the step logic it
shares with the Python loop (:mod:`phc.simulation.step_logic`), and this module (the signatures,
the LAPACK/BLAS symbols and the namespace they are compiled with). The stamp of the loop in
phc's cache (:func:`_attach_cache`) covers their text."""


def _kernel_source() -> str:
    return "\0".join(path.read_text(encoding="utf-8") for path in _SOURCE_FILES)


def enabled(mod) -> bool:
    """Whether a fixed-step run of `mod` (a generated module, guarded or not) uses the
    compiled loop: the numba backend, at most :data:`MAX_UNKNOWNS` unknowns, the functions the
    loop calls compiled with the signatures it expects, and ``PHC_COMPILED_LOOP`` not 0."""
    if os.environ.get("PHC_COMPILED_LOOP", "1").strip().lower() in ("0", "no", "false", "off"):
        return False
    raw = getattr(mod, "module", mod)
    if getattr(raw, "BACKEND", "numpy") != "numba" or raw.N > MAX_UNKNOWNS:
        return False
    if _functions(raw) is not None:
        return True
    if _WHY and not _SAID:  # numba is there but the loop did not compile: said once per process
        from phc.errors import CompiledLoopWarning, caller_stacklevel

        _SAID.append(_WHY)
        warnings.warn(f"the compiled step loop could not be built ({_WHY}); the Python step loop runs fixed-step "
                      "simulations in this process (the same steps, more time per step)", CompiledLoopWarning,
                      stacklevel=caller_stacklevel())
    return False


_SAID: list = []
"""Why the compiled loop could not be built, once said (:func:`enabled`)."""


_ADDRESSES = weakref.WeakKeyDictionary()
"""Per generated module: its functions as :func:`_address` objects (looked up once per process)."""


def _functions(raw):
    """The compiled functions the loop calls, in its argument order (each with its machine-code
    address looked up once: :func:`_address`), or None."""
    ready = _build()
    if not ready:
        return None
    try:
        cached = _ADDRESSES.get(raw)
    except TypeError:  # not weakly referable: look the functions up every time
        cached = None
    if cached is not None:
        return cached
    found = _lookup(raw, ready)
    if found is not None:
        found = tuple(_address(f, ready[2][name]) for f, name in zip(found, _FUNCTION_NAMES))
        try:
            _ADDRESSES[raw] = found
        except TypeError:
            pass
    return found


_FUNCTION_NAMES = ("residual", "jacobian", "invariants", "hamiltonian", "energy_scale", "powers")


def _address(func, sig):
    """`func` (a numba dispatcher compiled for `sig`) as an object of numba's wrapper-address
    protocol holding its address: numba looks the address of a dispatcher passed as a
    first-class function up on every call of the kernel (about 0.1 ms each, six functions a
    chunk), this object hands it over, and its numba type is made once (:func:`_compiled_class`).
    It keeps `func` alive, and with it the machine code."""
    return _compiled_class()(func, sig)


_COMPILED = []
"""The class of :func:`_address`'s objects, made once per process (:func:`_compiled_class`)."""


def _compiled_class():
    """The class of :func:`_address`'s objects, with numba's type of an argument (``typeof``)
    registered for it: each object's type, made once. numba's own rule for the protocol builds a
    new ``FunctionType`` of the signature at every call of the kernel, about 20 µs for each of the
    seven functions a chunk takes (a new chunk at every event of a run with switching
    conditions)."""
    if _COMPILED:
        return _COMPILED[0]
    from numba.core import types
    from numba.experimental.function_type import _get_wrapper_address
    from numba.extending import typeof_impl

    class _Compiled(types.WrapperAddressProtocol):
        __slots__ = ("func", "_sig", "_addr", "numba_type")

        def __init__(self, func, sig):
            self.func, self._sig, self._addr = func, sig, _get_wrapper_address(func, sig)
            self.numba_type = types.FunctionType(sig)

        def __wrapper_address__(self):
            return self._addr

        def signature(self):
            return self._sig

    @typeof_impl.register(_Compiled)
    def _typeof_compiled(val, c):
        return val.numba_type

    _COMPILED.append(_Compiled)
    return _Compiled


def _lookup(raw, ready):
    """The module's compiled functions in :data:`_FUNCTION_NAMES` (the dummy for absent invariants), or
    None when one is missing or compiled for another signature."""
    _, dummy, sigs = ready
    found = []
    for name in _FUNCTION_NAMES:
        func = getattr(raw, name, None)
        sigs_of = getattr(func, "nopython_signatures", None)
        if sigs_of is None:
            if name == "invariants" and not len(getattr(raw, "INVARIANTS", ())):
                found.append(dummy)
                continue
            return None
        if len(sigs_of) != 1 or sigs_of[0] != sigs[name]:
            return None
        found.append(func)
    return tuple(found)


_EVENTS = weakref.WeakKeyDictionary()
"""Per generated module: its switching functions compiled (:func:`_events_function`), or False."""


def _events_function(raw):
    """The model's switching functions ``events(t, y, yp, p, out)`` as the compiled loop calls them
    (an :func:`_address` object), or None when numba cannot compile them (the run keeps the Python
    loop). The numba back end compiles the functions of :data:`phc.codegen.numba_cache.FUNCTIONS`;
    ``events``, which only runs with switching conditions, is the NumPy module's text, compiled
    here once per module and process for the signature the loop expects (the same arithmetic
    as the Python loop's calls: the values agree to the last bit)."""
    try:
        found = _EVENTS.get(raw)
    except TypeError:
        found = None
    if found is not None:
        return found or None
    sig = _READY[2]["events"]
    func = getattr(raw, "events", None)
    try:
        if getattr(func, "nopython_signatures", None) is None:
            import numba

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                func = numba.njit(sig, error_model="numpy")(func)
        found = _address(func, sig)
    except Exception:  # noqa: BLE001 — the Python loop runs the model's events as written
        found = False
    try:
        _EVENTS[raw] = found
    except TypeError:
        pass
    return found or None


def watch_map(watch) -> np.ndarray:
    """The run's :class:`~phc.simulation.events.Watch` (its current modes) as the compiled loop
    evaluates it: rows a, b, k of ``w_i = a_i + b_i·v[k_i]``, ``v`` the model's ``events`` values —
    a watched switch ``mode·g`` (a = 0, b = mode), an unwatched one 1, a sticking sign's
    ``1 − s`` and ``1 + s`` (else 1), in the order of ``Watch.__call__`` (contacts are not mapped:
    a run with contacts keeps the Python loop). a + b·v is the Watch's value exactly (0 + x = x,
    1 + (−1)·s = 1 − s in IEEE arithmetic)."""
    n_sw, n_st = watch.n_sw, watch.n_st
    wmap = np.zeros((3, n_sw + 2 * n_st))
    wmap[0, :n_sw] = np.where(watch.mask, 0.0, 1.0)
    wmap[1, :n_sw] = np.where(watch.mask, watch.sign, 0.0)
    wmap[2, :n_sw] = np.arange(n_sw)
    for j in range(n_st):
        for col, b in ((n_sw + 2 * j, -1.0), (n_sw + 2 * j + 1, 1.0)):
            wmap[0, col] = 1.0
            wmap[1, col] = b if watch.stuck[j] else 0.0
            wmap[2, col] = n_sw + j
    return wmap


def mixed_precision(n: int) -> bool:
    """Whether the compiled loop's Newton corrections of a system of `n` unknowns start with the
    single-precision copy of the inverse: from :data:`MIXED_PRECISION_MIN` unknowns on;
    ``PHC_MIXED_PRECISION=0`` never, ``=always`` at every size (for testing)."""
    flag = os.environ.get("PHC_MIXED_PRECISION", "1").strip().lower()
    if flag in ("0", "no", "false", "off"):
        return False
    return flag == "always" or n >= MIXED_PRECISION_MIN


def _signatures():
    from numba.core import types

    f64 = types.float64
    given = types.Array(f64, 1, "A", readonly=True)
    out = types.Array(f64, 1, "A")
    vector = types.Array(f64, 1, "C")
    return {"residual": types.none(f64, given, given, given, out),
            "jacobian": types.none(f64, given, given, given, f64, out),
            "invariants": vector(f64, given, given),
            "hamiltonian": f64(f64, given, given),
            "energy_scale": f64(f64, given, given),
            "powers": types.UniTuple(f64, 2)(f64, given, given, given),
            "events": types.none(f64, given, given, given, out)}


def _build():
    """Compile (or load from the cache) the chunk function once per process."""
    global _READY, _WHY
    if _READY is not None:
        return _READY
    try:
        from phc.codegen.numba_cache import available

        ok, why = available()
        if not ok:
            _READY, _WHY = (), why
            return _READY
        _READY = _compile()
    except Exception as err:  # noqa: BLE001 — the Python loop runs instead, and says nothing is lost
        _READY, _WHY = (), f"{type(err).__name__}: {err}"
    return _READY


def why_not() -> str:
    """Why the compiled loop could not be built in this process ("" when it was, or was not tried)."""
    return _WHY


_SYMBOLS = {"dgetrf": ("cython_lapack", 6), "dgetri": ("cython_lapack", 7), "dgecon": ("cython_lapack", 9),
            "dgesdd": ("cython_lapack", 14), "dgemv": ("cython_blas", 11),
            "sgemv": ("cython_blas", 11)}


def _compile():
    import llvmlite.binding as llvm
    import numba
    from numba.core import types
    from numba.extending import get_cython_function_address

    for name, (where, nargs) in _SYMBOLS.items():
        llvm.add_symbol(f"phc_{name}", get_cython_function_address(f"scipy.linalg.{where}", name))
    externals = {name: types.ExternalFunction(f"phc_{name}", types.void(*([types.voidptr] * nargs)))
                 for name, (_, nargs) in _SYMBOLS.items()}
    sigs = _signatures()
    fn = {name: types.FunctionType(sig) for name, sig in sigs.items()}
    namespace = _kernel_namespace(externals)
    jit = numba.njit(error_model="numpy")
    for name in ("_copy", "_factor", "_invert", "_solve", "_lowprec", "_solve32", "_fill", "_stage_residual",
                 "_refactor_matrix", "_all_finite", "_begin", "_refactor", "_correct", "_add", "_precision",
                 "_consistent", "_newton", "_stage", "_discrete_gradient", "passivity_floor", "_midpoint4_step",
                 "_advance", "_monitor_ratio", "_far_from_singular", "_watch", "lagrange_weights", "predictor_nodes",
                 "substeps", "next_step",
                 "polynomial", "extrapolate", "predict", "looks", "accept", "chunk"):
        namespace[name] = jit(namespace[name])
    chunk = numba.njit(error_model="numpy")(namespace["_chunk"])
    C1 = types.Array(types.float64, 1, "C")
    C2 = types.Array(types.float64, 2, "C")
    C3 = types.Array(types.float64, 3, "C")
    I1 = types.Array(types.int64, 1, "C")
    I2 = types.Array(types.int32, 2, "C")
    events = types.FunctionType(sigs["events"])
    B1 = types.Array(types.int8, 1, "C")
    LP = types.Tuple((types.Array(types.float32, 3, "C"), C3, types.Array(types.float32, 1, "C")))
    signature = types.void(fn["residual"], fn["jacobian"], fn["invariants"], fn["hamiltonian"], fn["energy_scale"],
                           fn["powers"], events, C1, C1, C2, C2, C1, C1, C1, C1, C1, I1, C1, C3, LP, I2, C2, I1, I1,
                           I1, B1, C1, B1, C2, C3, C1, C1, C1, C2, C1, C1, C2, C2, C1, C1, C1, types.int64)
    _attach_cache(chunk, namespace["_chunk"])
    dummy = numba.njit(error_model="numpy")(namespace["_no_invariants"])
    _attach_cache(dummy, namespace["_no_invariants"])
    no_events = numba.njit(error_model="numpy")(namespace["_no_events"])
    _attach_cache(no_events, namespace["_no_events"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba's NumbaExperimentalFeatureWarning on first-class functions
        chunk.compile(signature)
        dummy.compile(sigs["invariants"].args)
        no_events.compile(sigs["events"].args)
    chunk.disable_compile()
    dummy.disable_compile()
    no_events.disable_compile()
    sigs["no_events"] = _address(no_events, sigs["events"])
    return chunk, dummy, sigs


def _attach_cache(dispatcher, py_func) -> None:
    """Keep the compiled loop in phc's signed cache of compiled code (if it can be used)."""
    if os.environ.get("PHC_COMPILED_CACHE", "1").strip().lower() in ("0", "no", "false", "off"):
        return
    try:
        import numba
        import sys

        from phc import __version__
        from phc.codegen import numba_cache as nb

        classes = nb._cache_classes()
        folder = nb.compiled_cache_dir()
        if classes is None or nb._private_dir(folder):
            return
        key, _ = nb.cache_key()
        if key is None:
            return
        stamp = hashlib.sha256("\0".join((_kernel_source(), __version__, numba.__version__, sys.version,
                                           "compiled-steps-1")).encode()).hexdigest()[:24]
        nb._REGISTRY[py_func.__code__.co_filename] = (str(folder), stamp)
        dispatcher._cache = classes[0](py_func, key)
    except Exception:  # noqa: BLE001 — compiled in memory instead
        pass


def _kernel_namespace(externals) -> dict:
    """The kernel's functions (plain Python in :mod:`phc.codegen.numba_steps_kernel`, jitted
    by :func:`_compile`) with the LAPACK/BLAS entry points they call bound as globals: the
    kernel module's own namespace, the one numba resolves the kernel's global names in."""
    ns = vars(_kernel)
    for name, ext in externals.items():
        ns[f"_{name}"] = ext
    return ns


# ---------------------------------------------------------------------------------------------------
# the Python driver

def step_constants(method: Optional[str] = None) -> np.ndarray:
    """The constants vector of the step logic (:mod:`phc.simulation.step_logic`: the methods'
    tolerances, limits, the predictor's orders, the monitor's threshold and period), as the
    Python loop uses them: what the compiled loops and an exported FMU (:mod:`phc.export.fmu`)
    are handed. With `method` ``"midpoint"``: without the secant iteration's and the composition's
    numbers (left 0), which its steps never read — the nominal-scales probe's midpoint steps
    (:func:`phc.codegen.c_steps.midpoint_steps`) then need not import
    :mod:`~phc.simulation.discrete_gradient` and :mod:`~phc.simulation.midpoint4` (about 1 ms of a
    process's first IDA run)."""
    from phc.simulation import midpoint as mp
    from phc.simulation.monitor import THRESHOLD

    if method not in (None, "midpoint"):
        raise ValueError(f"step_constants: method {method!r} is not None or 'midpoint'")
    c = mp.newton_constants()
    if method is None:
        from phc.simulation import discrete_gradient as dg
        from phc.simulation import midpoint4 as m4

        c = m4.composition_constants(dg.secant_constants(c))
    c = mp.driver_constants(c)
    c[_THRESHOLD] = THRESHOLD
    c[_ONE], c[_ZERO] = 1.0, 0.0
    c[_STRIKES_C] = LOW_PRECISION_STRIKES
    return c


def algebraic_mask(raw) -> np.ndarray:
    """Per variable: 0 differential; 1 algebraic, tested relative to |y| + 1 with Newton weights
    (StageSolver.algebraic); 2 a GGL multiplier (not tested)."""
    return np.array([0 if d else (2 if str(v).startswith("ggl.") else 1)
                     for d, v in zip(raw.DIFFERENTIAL, raw.VARIABLES)], dtype=np.int8)


def integrate(method: str, mod, p, t_out, y0, yp0, *, max_steps, progress, step, name, names=None,
              python_advance=None, weights=None, scales=None, events=None) -> Optional[dict]:
    """Run a fixed-step solver with the compiled loop; None when it does not apply (the caller
    runs its Python loop). Returns what :func:`~phc.simulation.midpoint.integrate_fixed_step`
    returns, plus ``nfev``/``njev``. `python_advance()` makes the Python step object used for
    steps the compiled loop hands back; `weights` (optional, shape (N,)) are Newton weights:
    converged when max |Δⱼ|·wⱼ ≤ NEWTON_TOL (default: max |Δ| ≤ NEWTON_TOL·(1 + max |y|));
    `scales` are the nominal scales the singularity monitor scales the columns by
    (:mod:`phc.simulation.scaling`).

    `events` (a :class:`phc.simulation.events.Watch`, optional) are the run's switching functions:
    the chunk evaluates them after each step (the operation ``_watch``) and hands back the first
    step at whose end one has fallen to zero or below; that step is located here by the Python
    loop's code (:func:`phc.simulation.midpoint._locate`) and the run returns with ``event`` as
    :func:`~phc.simulation.midpoint.integrate_fixed_step` does; the C loop calls the model
    library's ``phc_events`` (:func:`phc.codegen.c_steps.bind`). A run with contacts (impacts)
    keeps the Python loop (None)."""
    from phc.simulation import midpoint as mp
    from phc.simulation.monitor import SingularityMonitor

    raw = getattr(mod, "module", mod)
    on_c = getattr(raw, "BACKEND", "numpy") == "c"  # the C back end's loop (phc.codegen.c_steps)
    if events is not None and events.n_ct:  # contacts' watched functions are Python's
        return None
    if method == "discrete_gradient":
        from phc.simulation.discrete_gradient import velocity_rows

        if len(velocity_rows(raw)[0]):
            # the energy at the step's ends needs the velocities made consistent (rows M(q) v = p):
            # the Python loop does it (phc.simulation.discrete_gradient), the compiled loops do not
            if on_c:
                from phc.codegen import c_steps

                c_steps.say_unused("the discrete gradient's energy at the step ends needs the velocities of "
                                   "M(q) v = p solved there, which only the Python loop does")
            return None
    if on_c:
        from phc.codegen import c_steps

        use, why = c_steps.usable(method, raw)
        if use and events is not None and not c_steps.watches(raw):
            use, why = False, "the model's C library has no switching functions (phc_events): compile it again"
        if not use:
            c_steps.say_unused(why)
            return None
    elif not enabled(raw):
        return None
    if mp.make_projector(raw, p, np.asarray(y0, dtype=float), float(t_out[0])) is not None:
        if on_c:
            c_steps.say_unused("the model's invariants are not rows of its equations (the Python loop projects them "
                               "at the step ends)")
        return None
    if not on_c:
        funcs = _functions(raw)
        chunk = _READY[0]
        evf = _READY[2]["no_events"] if events is None else _events_function(raw)
        if evf is None:
            return None

    n = raw.N
    t_out = np.ascontiguousarray(t_out, dtype=float)
    nout = len(t_out)
    ys, yps = np.zeros((nout, n)), np.zeros((nout, n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    y = np.array(y0, dtype=float)
    mid, mid_slope, y_prev = np.zeros(n), np.array(yp0, dtype=float), np.zeros(n)
    monitor = SingularityMonitor(mod, p, names=names, **({} if scales is None else {"scales": scales}))
    monitor.start = (float(t_out[0]), np.array(y0, dtype=float), np.array(yp0, dtype=float))
    end_rows = np.ascontiguousarray(mp.constraint_rows(raw), dtype=np.int64)
    jrows = np.ascontiguousarray(raw.JAC_ROWS, dtype=np.int64)
    jcols = np.ascontiguousarray(raw.JAC_COLS, dtype=np.int64)
    emask = np.isin(jrows, end_rows).astype(np.int8)
    ist = np.zeros(_NI + 2, dtype=np.int64)
    ist[_K], ist[_LAST_LOOK], ist[_MAX_STEPS] = 1, -mp.MONITOR_EVERY, max_steps
    ist[_MONITOR], ist[_METHOD], ist[_NEND] = int(monitor.enabled), METHODS[method], len(end_rows)
    ist[_E] = list(raw.VARIABLES).index("energy.supplied")
    fst = np.zeros(_NF)
    fst[_STEP] = float(step) if step else 0.0
    fst[_H_PREV] = 1.0
    c = step_constants()
    from phc.simulation.scaling import run_energy

    c[_RUN_ENERGY] = run_energy(raw, scales)  # the energy checks' round-off floor (scaling.run_energy)
    pt, pm = np.zeros(mp.MAX_PREDICTOR_ORDER + 1), np.zeros((mp.MAX_PREDICTOR_ORDER + 1, n))
    A = np.zeros((2, n, n) if not on_c else (2, 1, 1))  # the numba loop's matrices (the C loop has its own)
    low = mixed_precision(n) and not on_c  # the C loop corrects in double precision only
    # the single-precision copies of the two inverses, their scales, and the vectors of sgemv
    lp = ((np.zeros((2, n, n), np.float32), np.ones((2, 3, n)), np.array([0.0] * (2 * n) + [1.0, 0.0], np.float32))
          if low else (np.zeros((2, 1, 1), np.float32), np.ones((2, 3, 1)), np.zeros(2, np.float32)))
    ist[_LOWP] = int(low)
    ipiv = np.zeros((2, n), dtype=np.int32)
    matf = np.zeros((2, 3))
    w = np.zeros(0) if weights is None else np.ascontiguousarray(weights, dtype=float)
    if w.shape != (0,) and w.shape != (n,):
        raise ValueError(f"Newton weights: expected shape ({n},), got {w.shape}")
    algmask = algebraic_mask(raw)
    colscale = np.zeros(0) if scales is None else np.ascontiguousarray(scales, dtype=float)
    if colscale.shape != (0,) and colscale.shape != (n,):
        raise ValueError(f"nominal scales: expected shape ({n},), got {colscale.shape}")
    hist_t, hist_v = np.zeros((2, 3)), np.zeros((2, 3, n))
    y_new = np.zeros(n)
    jbuf, ebuf = np.zeros(len(jrows)), np.zeros(len(jrows))
    M = np.zeros((n, n) if not on_c else (1, 1))
    pv = np.ascontiguousarray(p, dtype=float)
    # the watched switching functions (a run with events): their map, values at the step's start
    # and end, the model's events values (phc.codegen.numba_steps_kernel._watch)
    wmap = np.zeros((3, 0)) if events is None else watch_map(events)
    wprev = np.ascontiguousarray(events(float(t_out[0]), y, np.asarray(yp0, dtype=float)) if events is not None
                                 else np.zeros(0), dtype=float)
    wnew = np.zeros(wprev.shape[0])
    vbuf = np.zeros(0 if events is None else events.n_sw + events.n_st)
    event = None
    split = 0
    ok, message, interrupted = True, "integration finished", False
    python = None
    python_nfev = python_njev = 0
    rank_drops = []  # [first, last] time of the looks at each rank drop passed (midpoint.passed_rank_drop)
    budget = 16
    reported = 1
    if on_c:
        run_c = c_steps.bind(raw, pv, t_out, ys, yps, y, mid, mid_slope, y_prev, y_new, pt, pm, fst, ist, c, jrows,
                             jcols, end_rows, emask, w, algmask, colscale, hist_t, hist_v,
                             *((wmap, wprev, wnew, vbuf) if events is not None else ()))

    def python_step():
        nonlocal python
        if python is None:
            python = python_advance()
        if hasattr(python, "nhist"):  # midpoint4's predictor: the history is the kernel's
            python.nhist = 0
        return python

    def located(t, h, new, w_new, crossed):
        """The event the Python loop locates in the step (t, h, y) → `new` (mp._locate)."""
        found = mp._locate(python_step(), events, None, t, h, y.copy(), new, wprev.copy(), w_new, crossed)
        ist[_STEPS] += 1
        return found

    def event_in_python():
        """The step the chunk handed back with a switching function at or below zero at its end
        (or not finite: the Watch says which, as in the Python loop): the event, located as the
        Python loop locates it, or None (then the step is taken, as the Python loop takes it)."""
        nonlocal ok, message
        t, h = float(fst[_T]), float(fst[_H])
        new = y_new.copy()
        w_new = events(t + h, new, (new - y) / h)
        crossed = (wprev > 0) & (w_new <= 0)
        if crossed.any():
            return located(t, h, new, w_new, crossed)
        wprev[:] = w_new
        if _step_logic.accept(t, h, y, new, new, y_prev, mid, mid_slope, pt, pm, ys, yps, fst, ist):
            ok, message = False, _max_steps_message(ist, fst)
        return None

    def step_in_python():
        """The rest of the Python loop's body for the step at (t, h, y) the chunk handed back:
        None, or the event it found (a run with `events`)."""
        nonlocal split, ok, message
        t, h = float(fst[_T]), float(fst[_H])
        steps = int(ist[_STEPS])
        converged = ist[_STATUS] == _LOOK or ist[_CODE] == _OK
        hard, look = _step_logic.looks(ist, c, converged, bool(ist[_ILL]))
        new = y_new.copy()
        python_step()
        if not converged and events is not None and mp._crossed(events, t, h, y, new, wprev):
            # a failed step across a switching surface: the crossing is before (integrate_fixed_step)
            return located(t, h, new, events(t + h, new, (new - y) / h), None)
        if look:
            ist[_LAST_LOOK] = steps
        # the Python loop's own handling of the step (mp.finish_step), on copies of the kernel's arrays
        new, retried, failure, passed = mp.finish_step(python, monitor, raw, name, t, h, y.copy(), new,
                                                       bool(converged), "", hard, look, mid_slope, rank_drops)
        split += retried
        if passed:
            ist[_LAST_LOOK] = steps - mp.LOOK_GAP  # the passage's next hard step is handed back too
        if failure:
            ok, message = False, failure
            return None
        if events is not None:
            w_new = events(t + h, new, (new - y) / h)
            crossed = (wprev > 0) & (w_new <= 0)
            if crossed.any():
                return located(t, h, new, w_new, crossed)
            wprev[:] = w_new
        ist[_HIST] = 0  # midpoint4's predictor starts again: the Python step kept its own history
        # the Python loop's acceptance (plain NumPy: it is the step the chunk hands back)
        if _step_logic.accept(t, h, y, new, new, y_prev, mid, mid_slope, pt, pm, ys, yps, fst, ist):
            ok, message = False, _max_steps_message(ist, fst)
        return None

    try:
        while True:
            t0 = time.perf_counter()
            before = int(ist[_STEPS])
            if on_c:
                run_c(budget)
            else:
                chunk(*funcs, evf, pv, t_out, ys, yps, y, mid, mid_slope, y_prev, fst, ist, c, A, lp, ipiv, matf,
                      jrows, jcols, end_rows, emask, w, algmask, hist_t, hist_v, y_new, jbuf, ebuf, M, colscale, pt, pm,
                      wmap, wprev, wnew, vbuf, budget)
            took = time.perf_counter() - t0
            status = int(ist[_STATUS])
            if status == _BUDGET:
                taken = max(int(ist[_STEPS]) - before, 1)
                budget = int(min(max(CHUNK_SECONDS * taken / max(took, 1e-9), 1), 1_000_000))
            elif status in (_HARD, _LOOK, _EVENT):
                event = step_in_python() if status != _EVENT else event_in_python()
                if python is not None:
                    python_nfev, python_njev = _counts(python)
            elif status == _MAXSTEPS:
                ok, message = False, _max_steps_message(ist, fst)
            if progress is not None and ist[_K] > reported:
                reported = int(ist[_K])
                progress(float(t_out[reported - 1]))
            if not ok or status == _DONE or event is not None:
                break
    except mp.ModelEvaluationError as err:
        k = max(int(ist[_K]) - 1, 0)
        ok, message = False, f"{name}: {err}; results up to t = {t_out[k]:.6g} are kept"
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[max(int(ist[_K]) - 1, 0)]:.6g}"
    message = mp.closing_message(message, ok, split, rank_drops)
    last = int(ist[_K]) - 1 if not ok or event is not None else nout - 1
    return BackendRun.from_mapping(dict(
        t=t_out[:last + 1], y=ys[:last + 1], yp=yps[:last + 1], steps=int(ist[_STEPS]), success=ok, message=message,
        cpu=time.process_time() - start, interrupted=interrupted, nfev=int(ist[_NFEV]) + python_nfev,
        njev=int(ist[_NFACT]) + python_njev, compiled_loop=True, step_loop="c" if on_c else "numba",
        mixed_precision=bool(low),
        low_precision_strikes=int(ist[_STRIKES]), unbalanced=int(getattr(python, "unbalanced", 0) or 0),
        rank_drops=[a for a, _ in rank_drops], event=event))


def _max_steps_message(ist, fst) -> str:
    return (f"stopped after {int(ist[_STEPS])} steps at t = {fst[_T]:.6g} (max_steps); raise `max_steps` or the "
            "step size")


def _counts(python) -> tuple[int, int]:
    """(residual evaluations, factorizations) of the Python step object."""
    if hasattr(python, "stages"):
        return python.nfev, python.factorizations
    stage = python.stage
    return stage.nfev, stage.matrix.factorizations


def __getattr__(name: str):
    """The kernel's functions and constants under this module's name as well (they lived here
    before the kernel moved to :mod:`phc.codegen.numba_steps_kernel`), looked up at each
    access so that, once :func:`_build` has run, they are the jitted functions."""
    try:
        return getattr(_kernel, name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


__all__ = ["MAX_UNKNOWNS", "algebraic_mask", "enabled", "integrate", "step_constants", "watch_map", "why_not"]
