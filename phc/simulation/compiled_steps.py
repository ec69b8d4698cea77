"""The fixed-step solvers' whole step loop as compiled code (numba), for small and mid-size systems.

When a model runs on the ``numba`` backend (:mod:`phc.codegen.numba_backend`) and has at
most :data:`MAX_UNKNOWNS` unknowns, `midpoint`, `discrete_gradient` and `midpoint4` run
their steps in one compiled function that calls the model's compiled residual, Jacobian,
invariants, H and powers directly (numba first-class functions: no Python in between):

* the simplified Newton iteration of :class:`~phc.simulation.midpoint.StageSolver`, step for
  step — the same stopping rules, the same refresh of the Newton matrix on poor contraction,
  step-size change, a moved evaluation point or age, the GGL position constraints imposed
  at the step ends — with the Newton matrix as a dense LU (LAPACK ``dgetrf``) turned into
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
  predictor and passivity guard (:mod:`phc.simulation.midpoint4`);
* the driver of :func:`~phc.simulation.midpoint.integrate_fixed_step`: the output grid and
  its equal substeps, the predictor of the step midpoints (the polynomial of degree
  :data:`~phc.simulation.midpoint.PREDICTOR_ORDER` through the last ones), the singularity
  monitor's routine look every :data:`~phc.simulation.midpoint.MONITOR_EVERY` steps (the equilibrated
  iteration matrix's singular values by LAPACK ``dgesdd``, unless the condition estimate
  ``dgecon`` puts it far from singular: :data:`_RCOND_MARGIN`), ``max_steps``.

The compiled function runs chunks of steps (about :data:`CHUNK_SECONDS` each) and returns
to Python between them: progress is reported and Ctrl-C is seen there. Whatever is not
routine goes back to the Python code, which then does exactly what the Python loop does: a
step whose Newton iteration fails from the predictor (the retry from the constant
predictor, the split, the failure message naming the row or expression that could not be
evaluated), a step Newton found ill-conditioned (the monitor's look with the looser
threshold), a routine look that finds the matrix nearly singular (the message). The
trajectory is the Python loop's up to the Newton tolerance (a dense inverse instead of
SuperLU: the corrections differ by round-off).

The compiled loop is model-independent (the model's functions are arguments), compiled once
and kept in phc's signed cache of compiled code (``<phc cache>/numba/``, see
:mod:`phc.codegen.numba_backend`); :func:`enabled` says whether a run uses it, and
``PHC_COMPILED_LOOP=0`` switches it off.
"""

from __future__ import annotations

import hashlib
import math
import os
import time
import warnings
import weakref
from pathlib import Path
from typing import Optional

import numpy as np

MAX_UNKNOWNS = 400
"""Largest system whose step loop is compiled (dense LU); larger ones keep the sparse Python loop."""
CHUNK_SECONDS = 0.05
"""Wall time of one compiled chunk of steps (progress and Ctrl-C are handled between chunks)."""

METHODS = {"midpoint": 0, "discrete_gradient": 1, "midpoint4": 2}

# status of a chunk
_BUDGET, _DONE, _HARD, _LOOK, _MAXSTEPS = 0, 1, 2, 3, 4
# outcome of a stage solve / a step
_OK, _FAIL, _SINGULAR, _EVAL = 0, 1, 2, 3
# integer state
(_K, _J, _SUBSTEPS, _STEPS, _LAST_LOOK, _HAS_MID, _MAX_STEPS, _STATUS, _NFEV, _NFACT, _HIST, _MONITOR, _METHOD,
 _CODE, _ILL, _E, _NEND, _NMID, _LOWP, _STRIKES) = range(20)
_NI = 20
# float state
_T, _H, _H_PREV, _STEP = range(4)
_NF = 4
# constants
(_TOL, _RATE, _FLOOR, _MAX_AGE, _MAX_NEWTON, _BAL_TOL, _MAX_SECANT, _S_MIN, _S_MAX, _THRESHOLD, _EVERY,
 _G1, _G2, _M0, _M1, _M2, _ORDER, _ZONE, _STAGNATION, _ONE, _ZERO, _ORDER_ALG, _STRIKES_C) = range(23)
_NC = 23

MIXED_PRECISION_MIN = 32
"""Smallest system whose Newton corrections use a single-precision copy of the inverse Newton
matrix (:func:`_lowprec`); ``PHC_MIXED_PRECISION=0`` keeps double precision throughout. Below
this size a double-precision product costs no more (``dgemv`` against ``sgemv``, measured on
2-core x86-64: equal at 16 unknowns, 0.45–0.66× from 32 to 400)."""
LOW_PRECISION_STRIKES = 3
"""Corrections redone in double precision (a freshly factorized matrix whose single-precision
copy contracted worse than ``REFACTOR_RATE``) after which a run keeps double precision."""

_RCOND_MARGIN = 1e3
"""The routine look of the singularity monitor computes singular values only when LAPACK's
1-norm condition estimate is within this factor (times N) of the monitor's threshold."""

_READY = None
"""(kernel, dummy invariants) once built; () when the compiled loop cannot be built here."""
_WHY = ""


def _kernel_source() -> str:
    return Path(__file__).read_text(encoding="utf-8")


def enabled(mod) -> bool:
    """Whether a fixed-step run of `mod` (a generated module, guarded or not) uses the
    compiled loop: the numba backend, at most :data:`MAX_UNKNOWNS` unknowns, the functions the
    loop calls compiled with the signatures it expects, and ``PHC_COMPILED_LOOP`` not 0."""
    if os.environ.get("PHC_COMPILED_LOOP", "1").strip().lower() in ("0", "no", "false", "off"):
        return False
    raw = getattr(mod, "module", mod)
    if getattr(raw, "BACKEND", "numpy") != "numba" or raw.N > MAX_UNKNOWNS:
        return False
    return _functions(raw) is not None


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
    chunk), this object hands it over. It keeps `func` alive, and with it the machine code."""
    from numba.core import types
    from numba.experimental.function_type import _get_wrapper_address

    class _Compiled(types.WrapperAddressProtocol):
        __slots__ = ("func", "_sig", "_addr")

        def __init__(self):
            self.func, self._sig, self._addr = func, sig, _get_wrapper_address(func, sig)

        def __wrapper_address__(self):
            return self._addr

        def signature(self):
            return self._sig

    return _Compiled()


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
            "powers": types.UniTuple(f64, 2)(f64, given, given, given)}


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
    for name in ("_copy", "_factor", "_invert", "_solve", "_lowprec", "_solve32", "_fill", "_stage_residual", "_refactor", "_all_finite",
                 "_stage", "_midpoint4", "_dg", "_advance", "_monitor_ratio", "_weights", "_predict"):
        namespace[name] = jit(namespace[name])
    chunk = numba.njit(error_model="numpy")(namespace["_chunk"])
    C1 = types.Array(types.float64, 1, "C")
    C2 = types.Array(types.float64, 2, "C")
    C3 = types.Array(types.float64, 3, "C")
    I1 = types.Array(types.int64, 1, "C")
    I2 = types.Array(types.int32, 2, "C")
    B1 = types.Array(types.int8, 1, "C")
    LP = types.Tuple((types.Array(types.float32, 3, "C"), C3, types.Array(types.float32, 1, "C")))
    signature = types.void(fn["residual"], fn["jacobian"], fn["invariants"], fn["hamiltonian"], fn["energy_scale"],
                           fn["powers"], C1, C1, C2, C2, C1, C1, C1, C1, C1, I1, C1, C3, LP, I2, C2, I1, I1, I1,
                           B1, C1, B1, C2, C3, C1, C1, C1, C2, C1, C1, C2, types.int64)
    _attach_cache(chunk, namespace["_chunk"])
    dummy = numba.njit(error_model="numpy")(_no_invariants)
    _attach_cache(dummy, _no_invariants)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba's NumbaExperimentalFeatureWarning on first-class functions
        chunk.compile(signature)
        dummy.compile(sigs["invariants"].args)
    chunk.disable_compile()
    dummy.disable_compile()
    return chunk, dummy, sigs


def _no_invariants(t, y, p):
    return np.zeros(0)


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
    """The kernel's functions (plain Python here, jitted by :func:`_compile`) with the LAPACK/BLAS
    entry points they call bound as globals."""
    ns = globals()
    for name, ext in externals.items():
        ns[f"_{name}"] = ext
    return ns


# ---------------------------------------------------------------------------------------------------
# the kernel (numba nopython code; plain Python until _compile jits it)

def _copy(a, b):
    """b ← a (a loop: a slice assignment compiles numba's shape-mismatch message, seconds of compile time)."""
    for i in range(a.shape[0]):
        b[i] = a[i]


def _all_finite(v):
    for i in range(v.shape[0]):
        if not np.isfinite(v[i]):
            return False
    return True


def _factor(A, ipiv, ints):
    """LU of the column-major matrix in A (C array holding Aᵀ row by row); the LAPACK info."""
    _dgetrf(ints[0:].ctypes, ints[0:].ctypes, A.ctypes, ints[0:].ctypes, ipiv.ctypes, ints[2:].ctypes)
    return ints[2]


def _invert(A, ipiv, ints):
    """A ← A⁻¹ from the LU of :func:`_factor` (LAPACK ``dgetri``); the LAPACK info. A simplified
    Newton iteration solves with one matrix many times: a product with the inverse (``dgemv``)
    costs half the two triangular solves (``dtrsv`` runs its n² operations in sequence)."""
    n = A.shape[0]
    lwork = np.empty(1, np.int32)
    lwork[0] = 64 * n
    work = np.empty(64 * n)
    _dgetri(ints[0:].ctypes, A.ctypes, ints[0:].ctypes, ipiv.ctypes, work.ctypes, lwork.ctypes, ints[2:].ctypes)
    return ints[2]


def _solve(A, ints, chars, c, x, tmp):
    """x ← A⁻¹x with the inverse of :func:`_invert` in A (column-major); `tmp` is scratch."""
    # ints: n, 1 (incx), info, -; chars: 'L', 'N', 'U'; c[_ONE], c[_ZERO]: 1.0, 0.0
    for i in range(x.shape[0]):
        tmp[i] = x[i]
    _dgemv(chars[1:].ctypes, ints[0:].ctypes, ints[0:].ctypes, c[_ONE:].ctypes, A.ctypes, ints[0:].ctypes,
           tmp.ctypes, ints[1:].ctypes, c[_ZERO:].ctypes, x.ctypes, ints[1:].ctypes)


def _lowprec(Am, lp, m):
    """The single-precision copy of the inverse Newton matrix in Am (column-major) into lp:
    equilibrated by powers of two (M = R·M̃·C with the row scales R and then the column scales
    C: every column of M̃ has its largest entry in [1, 2), no entry is larger), so that no entry
    that matters is out of single precision's range whatever the units; the scales are exact
    and kept in double (lp[1][m]: R, C, 1/R)."""
    A32, eq = lp[0], lp[1]
    n = Am.shape[0]
    for i in range(n):
        eq[m, 0, i] = 0.0
    for j in range(n):  # Am[j, :] is column j of M: the rows' largest entries, in one pass
        for i in range(n):
            a = abs(Am[j, i])
            if a > eq[m, 0, i]:
                eq[m, 0, i] = a
    for i in range(n):
        big = eq[m, 0, i]
        eq[m, 0, i] = math.ldexp(1.0, math.frexp(big)[1] - 1) if big > 0.0 else 1.0
        eq[m, 2, i] = 1.0 / eq[m, 0, i]  # exact: a power of two
    for j in range(n):
        big = 0.0
        for i in range(n):
            big = max(big, abs(Am[j, i]) * eq[m, 2, i])
        cj = math.ldexp(1.0, math.frexp(big)[1] - 1) if big > 0.0 else 1.0
        eq[m, 1, j] = cj
        cinv = 1.0 / cj
        for i in range(n):
            A32[m, j, i] = Am[j, i] * eq[m, 2, i] * cinv


def _solve32(lp, m, ints, chars, x):
    """x ← M x with the single-precision copy of :func:`_lowprec` (``sgemv``): the vector C x is
    brought to a largest entry of 1 by a power of two before it is rounded to single precision,
    the product scaled back by R in double. The iteration converges to the solution of F = 0 all
    the same (the residual is in double): only its rate can suffer, which :func:`_stage` watches."""
    A32, eq, v = lp[0], lp[1], lp[2]
    n = x.shape[0]
    big = 0.0
    for j in range(n):
        big = max(big, abs(eq[m, 1, j] * x[j]))
    if big == 0.0:
        return
    k = math.ldexp(1.0, math.frexp(big)[1])
    kinv = 1.0 / k  # exact: a power of two
    for j in range(n):
        v[j] = (eq[m, 1, j] * x[j]) * kinv
    # v[n:2n] the product; v[2n], v[2n + 1]: 1.0, 0.0
    _sgemv(chars[1:].ctypes, ints[0:].ctypes, ints[0:].ctypes, v[2 * n:].ctypes, A32[m].ctypes, ints[0:].ctypes,
           v.ctypes, ints[1:].ctypes, v[2 * n + 1:].ctypes, v[n:].ctypes, ints[1:].ctypes)
    for i in range(n):
        x[i] = eq[m, 0, i] * (k * np.float64(v[n + i]))


def _fill(A, jbuf, ebuf, jrows, jcols, emask, s, nend):
    """The Newton matrix s·(F_y + c_j F_ẏ) with the end-constraint rows from `ebuf`, column-major in A."""
    A[:, :] = 0.0
    for k in range(jrows.shape[0]):
        v = ebuf[k] if (nend > 0 and emask[k] != 0) else s * jbuf[k]
        A[jcols[k], jrows[k]] += v


def _stage_residual(res, inv, t, h, y, y1, s, p, out, end_rows, nend, xs, d):
    for i in range(y.shape[0]):
        d[i] = (y1[i] - y[i]) / h
        xs[i] = y[i] + s * (y1[i] - y[i])
    res(t + s * h, xs, d, p, out)
    if nend > 0:
        g = inv(t + h, y1, p)
        for i in range(nend):
            out[end_rows[i]] = g[i]
    return _all_finite(out)


def _refactor(jac, t, h, y, y1, s, p, A, lp, ipiv, matf, m, jrows, jcols, emask, nend, jbuf, ebuf, xs, d, ints, ist):
    """Factorize the Newton matrix m for the iterate y1; the outcome (_OK, _SINGULAR, _EVAL)."""
    ist[_NFACT] += 1
    n = y.shape[0]
    for i in range(n):
        d[i] = y1[i] - y[i]
        xs[i] = y[i] + s * d[i]
        d[i] = d[i] / h
    cj = 1.0 / (s * h)
    jac(t + s * h, xs, d, p, cj, jbuf)
    if nend > 0:
        jac(t + h, y1, d, p, cj, ebuf)
    matf[m, 2] = 0.0
    if not _all_finite(jbuf) or (nend > 0 and not _all_finite(ebuf)):
        return _EVAL
    _fill(A[m], jbuf, ebuf, jrows, jcols, emask, s, nend)
    info = _factor(A[m], ipiv[m], ints)
    if info != 0:
        return _SINGULAR
    if _invert(A[m], ipiv[m], ints) != 0:
        return _SINGULAR
    if ist[_LOWP] != 0:
        _lowprec(A[m], lp, m)
    matf[m, 0] = h
    matf[m, 1] = s
    matf[m, 2] = 1.0
    ist[_AGE0 + m] = 0
    return _OK


_AGE0 = _NI  # the ages of the two Newton matrices follow the integer state


def _stage(res, jac, inv, t, h, y, y1in, s, p, m, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend, weights,
           algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags):
    """StageSolver.solve: y1 with F(t + s h, y + s(y1 − y), (y1 − y)/h) = 0 (end rows: g(t + h, y1) = 0)
    into `out`; returns _OK, _FAIL, _SINGULAR or _EVAL; flags[0] ← ill-conditioned."""
    n = y.shape[0]
    flags[0] = 0
    refreshed = False
    if ist[_LOWP] < 0:  # double precision was for the last solve only
        ist[_LOWP] = 1
    for i in range(n):
        out[i] = y1in[i]
    ist[_AGE0 + m] += 1
    since = 1
    tol = c[_TOL]
    if (matf[m, 2] == 0.0 or abs(h - matf[m, 0]) > 1e-3 * abs(h) or abs(s - matf[m, 1]) > 0.2
            or ist[_AGE0 + m] >= c[_MAX_AGE]):
        refreshed = True
        code = _refactor(jac, t, h, y, out, s, p, A, lp, ipiv, matf, m, jrows, jcols, emask, nend, jbuf, ebuf, xs, d,
                         ints, ist)
        if code != _OK:
            return code
        since = 0
    last = -1.0
    rate = np.inf  # the smallest θ of this solve with this matrix
    suspect = 0.0  # > 0: the rate of the single-precision copy, being compared with double precision
    weighted = weights.shape[0] == n
    for _ in range(int(c[_MAX_NEWTON])):
        ist[_NFEV] += 1
        if not _stage_residual(res, inv, t, h, y, out, s, p, r, end_rows, nend, xs, d):
            return _EVAL
        for i in range(n):
            r[i] = -r[i]
        lowp = ist[_LOWP] > 0
        if lowp:
            _solve32(lp, m, ints, chars, r)
        else:
            _solve(A[m], ints, chars, c, r, xs)
        size = 0.0
        scale = 1.0
        alg = 0.0
        finite = True
        for i in range(n):
            a = abs(r[i])
            if not np.isfinite(a):
                finite = False
            if abs(out[i]) + 1.0 > scale:
                scale = abs(out[i]) + 1.0
            if weighted:
                if algmask[i] == 1 and a > alg:
                    alg = a
                # a state is measured against its scale or its size, whichever is larger
                a = a * (weights[i] / (1.0 + abs(out[i]) * weights[i]))
            if a > size:
                size = a
        states = size  # the states' part alone (ROUNDOFF_FLOOR, midpoint.StageSolver)
        if weighted:
            # algebraic variables (weight 0) as without scales, relative to |y| + 1; not the GGL multipliers
            size = max(size, alg / scale)
            scale = 1.0
        if not finite:
            if since == 0:
                return _FAIL
            for i in range(n):
                out[i] = y1in[i]
            refreshed = True
            code = _refactor(jac, t, h, y, out, s, p, A, lp, ipiv, matf, m, jrows, jcols, emask, nend, jbuf, ebuf, xs,
                             d, ints, ist)
            if code != _OK:
                return code
            since = 0
            last = -1.0
            rate = np.inf
            suspect = 0.0
            continue
        has_theta = last > 0.0
        theta = size / last if has_theta else 0.0
        if lowp and refreshed and has_theta and theta > c[_RATE]:
            # a matrix factorized in this solve contracts poorly: its single-precision copy may be
            # to blame (conditioning), or the iteration is far from linear. Redo the correction in
            # double and compare the rates
            ist[_LOWP] = -1
            suspect = theta
            last = -1.0
            rate = np.inf
            continue
        if suspect > 0.0 and has_theta:
            # double precision with the same matrix: a strike if it contracts where single did not;
            # after LOW_PRECISION_STRIKES strikes the run keeps double precision
            if theta <= c[_RATE] and since > 0:
                ist[_STRIKES] += 1
                if ist[_STRIKES] >= c[_STRIKES_C]:
                    ist[_LOWP] = 0
            suspect = 0.0
        if has_theta and (theta >= 0.5 or theta >= c[_STAGNATION] * rate) and size <= c[_ZONE] * tol * scale:
            for i in range(n):
                out[i] += r[i]
            return _OK
        if refreshed and has_theta and theta >= 0.5 and states <= c[_FLOOR] * scale:
            flags[0] = 1
            for i in range(n):
                out[i] += r[i]
            return _OK
        if has_theta and theta >= 1.0 and since > 0 and size > 1e3 * tol * scale:
            refreshed = True
            code = _refactor(jac, t, h, y, out, s, p, A, lp, ipiv, matf, m, jrows, jcols, emask, nend, jbuf, ebuf, xs,
                             d, ints, ist)
            if code != _OK:
                return code
            since = 0
            last = -1.0
            rate = np.inf
            suspect = 0.0
            continue
        for i in range(n):
            out[i] += r[i]
        since += 1
        if size <= 1e-2 * tol * scale:
            return _OK
        if has_theta:
            if theta < 1.0 and theta / (1.0 - theta) * size <= tol * scale:
                return _OK
            rate = min(rate, theta)
            if theta > c[_RATE]:
                refreshed = True
                code = _refactor(jac, t, h, y, out, s, p, A, lp, ipiv, matf, m, jrows, jcols, emask, nend, jbuf, ebuf,
                                 xs, d, ints, ist)
                if code != _OK:
                    return code
                since = 0
                size = -1.0
                rate = np.inf
                suspect = 0.0
        last = size
    return _FAIL


def _dg(res, jac, inv, ham, escale, t, h, y, guess, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend, weights,
        algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags):
    """DiscreteGradientStep: the stage equations at y(s) and the energy balance r(s) = 0."""
    n = y.shape[0]
    e = ist[_E]
    code = _stage(res, jac, inv, t, h, y, guess, 0.5, p, 0, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend,
                  weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags)
    if code != _OK:
        return code
    H0 = ham(t, y, p)
    bal = ham(t + h, out, p) - H0 + out[e] - y[e]
    scale = max(abs(escale(t, y, p)), abs(escale(t + h, out, p)), abs(y[e]), abs(out[e]), 1e-200)
    if not (np.isfinite(bal) and np.isfinite(scale)):
        return _EVAL
    tol = c[_BAL_TOL] * scale
    if abs(bal) <= tol:
        return _OK
    for i in range(n):
        xs[i] = y[i] + 0.5 * (out[i] - y[i])
    curv = 4.0 * (H0 - 2.0 * ham(t + 0.5 * h, xs.copy(), p) + ham(t + h, out, p))
    if not np.isfinite(curv):
        return _EVAL
    s_prev = 0.5
    r_prev = bal
    y_prev = out.copy()
    slope = -curv if curv != 0.0 else -abs(bal) * 10.0
    best = abs(bal)
    y_best = out.copy()
    for _ in range(int(c[_MAX_SECANT])):
        if slope != 0.0:
            s_new = min(max(s_prev - r_prev / slope, c[_S_MIN]), c[_S_MAX])
        else:
            s_new = 0.5
        if s_new == s_prev:
            break
        code = _stage(res, jac, inv, t, h, y, y_prev, s_new, p, 0, A, lp, ipiv, matf, jrows, jcols, emask, end_rows,
                      nend, weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags)
        if code != _OK:
            break
        r_new = ham(t + h, out, p) - H0 + out[e] - y[e]
        if not np.isfinite(r_new):
            return _EVAL
        if abs(r_new) < best:
            best = abs(r_new)
            _copy(out, y_best)
        if abs(r_new) <= tol:
            return _OK
        if r_new != r_prev:
            slope = (r_new - r_prev) / (s_new - s_prev)
        s_prev = s_new
        r_prev = r_new
        _copy(out, y_prev)
    _copy(y_best, out)
    if best <= 1e3 * tol:
        return _OK
    # no point balances the energy: the step is split in Python, and where even the shortest
    # split step cannot balance it, its midpoint step is taken (phc.simulation.discrete_gradient)
    return _FAIL


def _midpoint4(res, jac, inv, escale, powers, t, h, y, guess, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend,
               weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags, hist_t, hist_v):
    """Midpoint4Step: three midpoint substeps γ₁h, γ₂h, γ₁h, the predictor from the substep
    midpoints of the last two steps, the passivity guard."""
    n = y.shape[0]
    fr = (c[_G1], c[_G2], c[_G1])
    mt = (c[_M0], c[_M1], c[_M2])
    mids = np.empty((3, n))
    if ist[_HIST] == 2:
        for i in range(3):
            ti = t + mt[i] * h
            for j in range(n):
                mids[i, j] = hist_v[1, i, j] + (ti - hist_t[1, i]) * (hist_v[1, i, j] - hist_v[0, i, j]) / (
                    hist_t[1, i] - hist_t[0, i])
    else:
        for i in range(3):
            for j in range(n):
                mids[i, j] = y[j] + mt[i] * h * ((guess[j] - y[j]) / h)
    ill = 0
    start = y.copy()
    tau = t
    dissipated = 0.0
    scale = 0.0
    values = np.empty((3, n))
    g = np.empty(n)
    for i in range(3):
        m = 0 if i != 1 else 1
        hs = fr[i] * h
        for j in range(n):
            g[j] = 2.0 * mids[i, j] - start[j]
        code = _stage(res, jac, inv, tau, hs, start, g, 0.5, p, m, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend,
                      weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags)
        ill = ill | flags[0]
        if code != _OK:
            flags[0] = ill
            ist[_HIST] = 0
            return code
        for j in range(n):
            values[i, j] = 0.5 * (start[j] + out[j])
            d[j] = (out[j] - start[j]) / hs
        pw = powers(tau + 0.5 * hs, values[i], d, p)
        diss = hs * pw[1]
        if not np.isfinite(diss):
            flags[0] = ill
            ist[_HIST] = 0
            return _EVAL
        dissipated += diss
        scale += abs(diss)
        _copy(out, start)
        tau = tau + hs
    flags[0] = ill
    floor = 1e-13 * abs(escale(t, y, p)) + 1e-300
    if dissipated < -1e-9 * scale - floor:
        ist[_HIST] = 0
        return _FAIL
    if ist[_HIST] == 2:
        for i in range(3):
            hist_t[0, i] = hist_t[1, i]
            for j in range(n):
                hist_v[0, i, j] = hist_v[1, i, j]
        k = 1
    else:
        k = ist[_HIST]
        ist[_HIST] += 1
    for i in range(3):
        hist_t[k, i] = t + mt[i] * h
    for i in range(3):
        for j in range(n):
            hist_v[k, i, j] = values[i, j]
    return _OK


def _advance(res, jac, inv, ham, escale, powers, t, h, y, guess, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows,
             nend, weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags, hist_t, hist_v):
    method = ist[_METHOD]
    if method == 0:
        return _stage(res, jac, inv, t, h, y, guess, 0.5, p, 0, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend,
                      weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags)
    if method == 1:
        return _dg(res, jac, inv, ham, escale, t, h, y, guess, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows, nend,
                   weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags)
    return _midpoint4(res, jac, inv, escale, powers, t, h, y, guess, p, A, lp, ipiv, matf, jrows, jcols, emask, end_rows,
                      nend, weights, algmask, c, jbuf, ebuf, xs, d, r, out, ints, chars, ist, flags, hist_t, hist_v)


def _monitor_ratio(jac, t, y, yp, h, p, jrows, jcols, jbuf, M, colscale, threshold):
    """σ_min/σ_max of the equilibrated iteration matrix (SingularityMonitor.ratio); -1 when it
    cannot be computed here (the Python monitor then looks itself)."""
    n = y.shape[0]
    jac(t, y, yp, p, 1.0 / max(h, 1e-300), jbuf)
    if not _all_finite(jbuf):
        return -1.0
    M[:, :] = 0.0
    for k in range(jrows.shape[0]):
        M[jcols[k], jrows[k]] = jbuf[k]  # column-major: M[col, row]
    if colscale.shape[0] == n:  # scaled variables y/s: columns times s
        for j in range(n):
            for i in range(n):
                M[j, i] *= colscale[j]
    rowmax = np.empty(n)
    for _ in range(2):
        # rows of J (M[j, i] is J[i, j]: the loops run along M's rows, contiguous)
        for i in range(n):
            rowmax[i] = 0.0
        for j in range(n):
            for i in range(n):
                rowmax[i] = max(rowmax[i], abs(M[j, i]))
        for j in range(n):
            for i in range(n):
                if rowmax[i] > 0.0:
                    M[j, i] /= rowmax[i]
        for j in range(n):  # columns of J
            big = 0.0
            for i in range(n):
                big = max(big, abs(M[j, i]))
            if big > 0.0:
                for i in range(n):
                    M[j, i] /= big
    ints = np.zeros(4, np.int32)
    ints[0] = n
    # a cheap look first: the 1-norm condition estimate of LAPACK (dgecon, on an LU) bounds
    # σ_max/σ_min ≤ n·κ₁; an estimate (a lower bound of κ₁, within a small factor in practice)
    # RCOND_MARGIN·n times above the threshold leaves the SVD out
    lu = M.copy()
    anorm = np.zeros(1)
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(M[j, i])
        anorm[0] = max(anorm[0], col)
    ipiv = np.zeros(n, np.int32)
    _dgetrf(ints[0:].ctypes, ints[0:].ctypes, lu.ctypes, ints[0:].ctypes, ipiv.ctypes, ints[2:].ctypes)
    if ints[2] == 0:
        one_norm = np.zeros(1, np.uint8)
        one_norm[0] = 49  # '1'
        rcond = np.zeros(1)
        cwork = np.zeros(4 * n)
        ciwork = np.zeros(n, np.int32)
        _dgecon(one_norm.ctypes, ints[0:].ctypes, lu.ctypes, ints[0:].ctypes, anorm.ctypes, rcond.ctypes,
                cwork.ctypes, ciwork.ctypes, ints[2:].ctypes)
        if ints[2] == 0 and np.isfinite(rcond[0]) and rcond[0] >= threshold * n * _RCOND_MARGIN:
            return rcond[0] / n  # about a lower bound of σ_min/σ_max, far above the threshold
    ints[1] = -1
    ints[2] = 0
    chars = np.zeros(1, np.uint8)
    chars[0] = 78  # 'N'
    s = np.zeros(n)
    dummy = np.zeros(1)
    iwork = np.zeros(8 * n, np.int32)
    query = np.zeros(1)
    one = np.ones(1, np.int32)
    _dgesdd(chars.ctypes, ints[0:].ctypes, ints[0:].ctypes, M.ctypes, ints[0:].ctypes, s.ctypes, dummy.ctypes,
            one.ctypes, dummy.ctypes, one.ctypes, query.ctypes, ints[1:].ctypes, iwork.ctypes, ints[2:].ctypes)
    lwork = max(int(query[0]), 1)
    work = np.zeros(lwork)
    ints[1] = lwork
    _dgesdd(chars.ctypes, ints[0:].ctypes, ints[0:].ctypes, M.ctypes, ints[0:].ctypes, s.ctypes, dummy.ctypes,
            one.ctypes, dummy.ctypes, one.ctypes, work.ctypes, ints[1:].ctypes, iwork.ctypes, ints[2:].ctypes)
    if ints[2] != 0 or not _all_finite(s):
        return -1.0
    return s[n - 1] / s[0] if s[0] > 0 else 0.0


def _weights(pt, k, tn, w):
    """Lagrange weights at tn of the nodes pt[0:k] (midpoint.predict_midpoint's arithmetic)."""
    for a in range(k):
        wa = 1.0
        for b in range(k):
            if b != a:
                wa *= (tn - pt[b]) / (pt[a] - pt[b])
        w[a] = wa


def _predict(y, mid, mid_slope, pt, pm, ist, c, t, h, h_prev, algmask, guess):
    """The start of Newton, ``2 m − y`` with the predicted midpoint m: y + h/2·ẏ₀ at the start,
    else per variable (differential ones: degree ``c[_ORDER]``, algebraic ones ``c[_ORDER_ALG]``)
    the last midpoint (degree 0), the linear extrapolation of the last two (degree 1, or while
    fewer midpoints are known), or the Lagrange polynomial through the last ones
    (midpoint.predict_midpoint, the same arithmetic)."""
    n = y.shape[0]
    if ist[_HAS_MID] == 0:
        for i in range(n):
            guess[i] = 2.0 * (y[i] + 0.5 * h * mid_slope[i]) - y[i]
        return
    tn = t + 0.5 * h
    nmid = ist[_NMID]
    od = int(c[_ORDER])
    oa = int(c[_ORDER_ALG])
    kd = min(od + 1, nmid)
    ka = min(oa + 1, nmid)
    wd = np.empty(pm.shape[0])
    wa = np.empty(pm.shape[0])
    _weights(pt, kd, tn, wd)
    _weights(pt, ka, tn, wa)
    for i in range(n):
        o = oa if algmask[i] != 0 else od
        k = ka if algmask[i] != 0 else kd
        if o == 0:
            mg = mid[i]
        elif k < 3:
            mg = mid[i] + 0.5 * (h + h_prev) * mid_slope[i]
        else:
            w = wa if algmask[i] != 0 else wd
            mg = w[0] * pm[0, i]
            for a in range(1, k):
                mg = mg + w[a] * pm[a, i]
        guess[i] = 2.0 * mg - y[i]


def _chunk(res, jac, inv, ham, escale, powers, p, t_out, ys, yps, y, mid, mid_slope, y_prev, fst, ist, c, A, lp,
           ipiv, matf, jrows, jcols, end_rows, emask, weights, algmask, hist_t, hist_v, y_new, jbuf, ebuf, M, colscale, pt,
           pm, budget):
    """Steps of integrate_fixed_step until `budget` steps are done, the run ends, or a step needs
    the Python code (see the module docstring); the state is in the arrays, the status in ist."""
    n = y.shape[0]
    nend = ist[_NEND]
    ints = np.zeros(4, np.int32)
    ints[0] = n
    ints[1] = 1
    chars = np.zeros(3, np.uint8)
    chars[0] = 76  # 'L'
    chars[1] = 78  # 'N'
    chars[2] = 85  # 'U'
    xs = np.empty(n)
    d = np.empty(n)
    r = np.empty(n)
    guess = np.empty(n)
    yp = np.empty(n)
    flags = np.zeros(1, np.int64)
    every = int(c[_EVERY])
    nout = t_out.shape[0]
    done = 0
    while True:
        k = ist[_K]
        if k >= nout:
            ist[_STATUS] = _DONE
            return
        if done >= budget:
            ist[_STATUS] = _BUDGET
            return
        if ist[_J] == 0:
            interval = t_out[k] - t_out[k - 1]
            step = fst[_STEP]
            if step > 0.0:
                sub = max(1, int(math.ceil(interval / step - 1e-9)))
            else:
                sub = 1
            ist[_SUBSTEPS] = sub
            fst[_H] = interval / sub
            fst[_T] = t_out[k - 1]
        t = fst[_T]
        h = fst[_H]
        h_prev = fst[_H_PREV]
        _predict(y, mid, mid_slope, pt, pm, ist, c, t, h, h_prev, algmask, guess)
        code = _advance(res, jac, inv, ham, escale, powers, t, h, y, guess, p, A, lp, ipiv, matf, jrows, jcols, emask,
                        end_rows, nend, weights, algmask, c, jbuf, ebuf, xs, d, r, y_new, ints, chars, ist, flags,
                        hist_t, hist_v)
        steps = ist[_STEPS]
        ist[_CODE] = code
        ist[_ILL] = flags[0]
        if code != _OK or (ist[_MONITOR] != 0 and flags[0] != 0 and steps - ist[_LAST_LOOK] >= 10):
            ist[_STATUS] = _HARD
            return
        if ist[_MONITOR] != 0 and steps % every == 0:
            ist[_LAST_LOOK] = steps
            for i in range(n):
                yp[i] = (y_new[i] - y[i]) / h
            ratio = _monitor_ratio(jac, t, y, yp, 0.5 * h, p, jrows, jcols, jbuf, M, colscale, c[_THRESHOLD])
            if ratio < c[_THRESHOLD]:
                ist[_STATUS] = _LOOK
                return
        # accept the step
        kp = pm.shape[0]
        for j in range(kp - 1, 0, -1):
            pt[j] = pt[j - 1]
        pt[0] = t + 0.5 * h
        for i in range(n):
            nm = 0.5 * (y[i] + y_new[i])
            if ist[_HAS_MID] != 0:
                mid_slope[i] = (nm - mid[i]) / (0.5 * (h + h_prev))
            mid[i] = nm
            for j in range(kp - 1, 0, -1):
                pm[j, i] = pm[j - 1, i]
            pm[0, i] = nm
            y_prev[i] = y[i]
            y[i] = y_new[i]
        ist[_HAS_MID] = 1
        ist[_NMID] = min(ist[_NMID] + 1, kp)
        fst[_H_PREV] = h
        fst[_T] = t + h
        ist[_STEPS] = steps + 1
        done += 1
        if steps + 1 >= ist[_MAX_STEPS]:
            ist[_STATUS] = _MAXSTEPS
            return
        ist[_J] += 1
        if ist[_J] >= ist[_SUBSTEPS]:
            for i in range(n):
                ys[k, i] = y[i]
                yps[k, i] = (y[i] - y_prev[i]) / h
            ist[_K] = k + 1
            ist[_J] = 0


# ---------------------------------------------------------------------------------------------------
# the Python driver

def integrate(method: str, mod, p, t_out, y0, yp0, *, max_steps, progress, step, name, names=None,
              python_advance=None, weights=None, scales=None) -> Optional[dict]:
    """Run a fixed-step solver with the compiled loop; None when it does not apply (the caller
    runs its Python loop). Returns what :func:`~phc.simulation.midpoint.integrate_fixed_step`
    returns, plus ``nfev``/``njev``. `python_advance()` makes the Python step object used for
    steps the compiled loop hands back; `weights` (optional, shape (N,)) are Newton weights:
    converged when max |Δⱼ|·wⱼ ≤ NEWTON_TOL (default: max |Δ| ≤ NEWTON_TOL·(1 + max |y|));
    `scales` are the nominal scales the singularity monitor scales the columns by
    (:mod:`phc.simulation.scaling`)."""
    from phc.simulation import midpoint as mp
    from phc.simulation.monitor import SingularityMonitor

    raw = getattr(mod, "module", mod)
    if not enabled(raw) or mp.make_projector(raw, p, np.asarray(y0, dtype=float), float(t_out[0])) is not None:
        return None
    funcs = _functions(raw)
    chunk = _READY[0]
    from phc.simulation import discrete_gradient as dg
    from phc.simulation import midpoint4 as m4
    from phc.simulation.monitor import THRESHOLD

    n = raw.N
    t_out = np.ascontiguousarray(t_out, dtype=float)
    nout = len(t_out)
    ys, yps = np.zeros((nout, n)), np.zeros((nout, n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    y = np.array(y0, dtype=float)
    mid, mid_slope, y_prev = np.zeros(n), np.array(yp0, dtype=float), np.zeros(n)
    monitor = SingularityMonitor(mod, p, names=names, **({} if scales is None else {"scales": scales}))
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
    c = np.zeros(_NC)
    c[_TOL], c[_RATE], c[_FLOOR], c[_MAX_AGE] = mp.NEWTON_TOL, mp.REFACTOR_RATE, mp.ROUNDOFF_FLOOR, mp.MAX_AGE
    c[_MAX_NEWTON], c[_BAL_TOL], c[_MAX_SECANT] = mp.MAX_NEWTON, dg.BALANCE_TOL, dg.MAX_SECANT
    c[_S_MIN], c[_S_MAX], c[_THRESHOLD], c[_EVERY] = dg.S_MIN, dg.S_MAX, THRESHOLD, mp.MONITOR_EVERY
    c[_G1], c[_G2] = m4.GAMMA1, m4.GAMMA2
    c[_M0], c[_M1], c[_M2] = m4.MID_TIMES
    c[_ZONE], c[_STAGNATION] = mp.ROUNDOFF_ZONE, mp.STAGNATION_JUMP
    c[_ONE], c[_ZERO] = 1.0, 0.0
    c[_ORDER] = min(max(int(mp.PREDICTOR_ORDER), 0), mp.MAX_PREDICTOR_ORDER)
    c[_ORDER_ALG] = min(max(int(mp.PREDICTOR_ORDER_ALGEBRAIC), 0), mp.MAX_PREDICTOR_ORDER)
    pt, pm = np.zeros(mp.MAX_PREDICTOR_ORDER + 1), np.zeros((mp.MAX_PREDICTOR_ORDER + 1, n))
    A = np.zeros((2, n, n))
    low = mixed_precision(n)
    # the single-precision copies of the two inverses, their scales, and the vectors of sgemv
    lp = ((np.zeros((2, n, n), np.float32), np.ones((2, 3, n)), np.array([0.0] * (2 * n) + [1.0, 0.0], np.float32))
          if low else (np.zeros((2, 1, 1), np.float32), np.ones((2, 3, 1)), np.zeros(2, np.float32)))
    ist[_LOWP] = int(low)
    c[_STRIKES_C] = LOW_PRECISION_STRIKES
    ipiv = np.zeros((2, n), dtype=np.int32)
    matf = np.zeros((2, 3))
    w = np.zeros(0) if weights is None else np.ascontiguousarray(weights, dtype=float)
    if w.shape != (0,) and w.shape != (n,):
        raise ValueError(f"Newton weights: expected shape ({n},), got {w.shape}")
    # with weights, the algebraic variables but the GGL multipliers are tested relative to |y| + 1
    # (StageSolver.algebraic)
    # algebraic variables: 1, tested relative to |y| + 1 with weights (StageSolver.algebraic); 2, the GGL
    # multipliers (not tested); 0, differential
    algmask = np.array([0 if d else (2 if str(v).startswith("ggl.") else 1)
                        for d, v in zip(raw.DIFFERENTIAL, raw.VARIABLES)], dtype=np.int8)
    colscale = np.zeros(0) if scales is None else np.ascontiguousarray(scales, dtype=float)
    if colscale.shape != (0,) and colscale.shape != (n,):
        raise ValueError(f"nominal scales: expected shape ({n},), got {colscale.shape}")
    hist_t, hist_v = np.zeros((2, 3)), np.zeros((2, 3, n))
    y_new = np.zeros(n)
    jbuf, ebuf = np.zeros(len(jrows)), np.zeros(len(jrows))
    M = np.zeros((n, n))
    pv = np.ascontiguousarray(p, dtype=float)
    split = 0
    ok, message, interrupted = True, "integration finished", False
    python = None
    python_nfev = python_njev = 0
    budget = 16
    reported = 1

    def step_in_python():
        """The rest of the Python loop's body for the step at (t, h, y) the chunk handed back."""
        nonlocal python, split, ok, message
        t, h = float(fst[_T]), float(fst[_H])
        steps = int(ist[_STEPS])
        converged = ist[_STATUS] == _LOOK or ist[_CODE] == _OK
        hard = not converged or bool(ist[_ILL] and steps - ist[_LAST_LOOK] >= 10)
        new = y_new.copy()
        if python is None:
            python = python_advance()
        stage = getattr(python, "stage", None)
        if hasattr(python, "history"):
            python.history = []
        reason = ""
        if not converged:
            new, converged, reason = mp._subdivide(python, t, h, y.copy(), mp.MAX_SPLIT)
            split += converged
        if monitor.enabled and (hard or steps % mp.MONITOR_EVERY == 0):
            ist[_LAST_LOOK] = steps
            limit = mp.HARD_STEP_THRESHOLD if hard else None
            warning = monitor.check(t, y, (new - y) / h if converged else mid_slope, 0.5 * h, limit)
            if warning is None and converged and hard:
                warning = monitor.check(t + h, new, (new - y) / h, 0.5 * h, limit)
            if warning:
                ok, message = False, f"{name}: {warning}"
                return
        if not converged:
            failed = getattr(stage, "evaluation_error", None)
            if failed is not None:
                ok, message = False, f"{name}: {failed}; results up to t = {t:.6g} are kept"
            else:
                ok, message = False, f"{name}: {reason} at t = {t:.6g}; results up to this time are kept"
            return
        new_mid = 0.5 * (y + new)
        if ist[_HAS_MID]:
            mid_slope[:] = (new_mid - mid) / (0.5 * (h + fst[_H_PREV]))
        mid[:] = new_mid
        pt[1:], pm[1:] = pt[:-1].copy(), pm[:-1].copy()
        pt[0], pm[0] = t + 0.5 * h, new_mid
        ist[_NMID] = min(int(ist[_NMID]) + 1, len(pt))
        y_prev[:] = y
        y[:] = new
        ist[_HAS_MID] = 1
        ist[_HIST] = 0
        fst[_H_PREV] = h
        fst[_T] = t + h
        ist[_STEPS] = steps + 1
        if steps + 1 >= max_steps:
            ok, message = False, (f"stopped after {steps + 1} steps at t = {t + h:.6g} (max_steps); raise "
                                  "`max_steps` or the step size")
            return
        ist[_J] += 1
        if ist[_J] >= ist[_SUBSTEPS]:
            k = int(ist[_K])
            ys[k], yps[k] = y, (y - y_prev) / h
            ist[_K] = k + 1
            ist[_J] = 0

    try:
        while True:
            t0 = time.perf_counter()
            before = int(ist[_STEPS])
            chunk(*funcs, pv, t_out, ys, yps, y, mid, mid_slope, y_prev, fst, ist, c, A, lp, ipiv, matf, jrows, jcols,
                  end_rows, emask, w, algmask, hist_t, hist_v, y_new, jbuf, ebuf, M, colscale, pt, pm, budget)
            took = time.perf_counter() - t0
            status = int(ist[_STATUS])
            if status == _BUDGET:
                taken = max(int(ist[_STEPS]) - before, 1)
                budget = int(min(max(CHUNK_SECONDS * taken / max(took, 1e-9), 1), 1_000_000))
            elif status in (_HARD, _LOOK):
                step_in_python()
                if python is not None:
                    python_nfev, python_njev = _counts(python)
            elif status == _MAXSTEPS:
                ok, message = False, (f"stopped after {int(ist[_STEPS])} steps at t = {fst[_T]:.6g} (max_steps); "
                                      "raise `max_steps` or the step size")
            if progress is not None and ist[_K] > reported:
                reported = int(ist[_K])
                progress(float(t_out[reported - 1]))
            if not ok or status == _DONE:
                break
    except mp.ModelEvaluationError as err:
        k = max(int(ist[_K]) - 1, 0)
        ok, message = False, f"{name}: {err}; results up to t = {t_out[k]:.6g} are kept"
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[max(int(ist[_K]) - 1, 0)]:.6g}"
    if ok and split:
        message += (f"; {split} step(s) needed a restart or a split to be solved (the step is long "
                    "for the dynamics)")
    last = int(ist[_K]) - 1 if not ok else nout - 1
    return dict(t=t_out[:last + 1], y=ys[:last + 1], yp=yps[:last + 1], steps=int(ist[_STEPS]), success=ok,
                message=message, cpu=time.process_time() - start, interrupted=interrupted,
                nfev=int(ist[_NFEV]) + python_nfev, njev=int(ist[_NFACT]) + python_njev, compiled_loop=True,
                mixed_precision=bool(low), low_precision_strikes=int(ist[_STRIKES]),
                unbalanced=int(getattr(python, "unbalanced", 0) or 0))


def _counts(python) -> tuple[int, int]:
    """(residual evaluations, factorizations) of the Python step object."""
    if hasattr(python, "stages"):
        return python.nfev, python.factorizations
    stage = python.stage
    return stage.nfev, stage.matrix.factorizations


__all__ = ["MAX_UNKNOWNS", "enabled", "integrate", "why_not"]
