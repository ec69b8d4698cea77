"""SUNDIALS IDA backend (variable-order BDF) through scikit-sundae.

Index-2 systems (GGL-stabilized position constraints, velocity constraints through port
couplings) are integrated with all algebraic variables excluded from the local error
test — the effect of IDA's ``IDASetSuppressAlg``, which scikit-sundae does not expose;
we get it with a very large absolute tolerance on algebraic components. Accuracy is
controlled on the differential (energy) states, which determine the algebraic ones.

IDA integrates in its normal mode, in C, from one output time to the next (its own
interpolation gives the outputs); Python runs only the residual and Jacobian callbacks
and, between chunks, the bookkeeping. A chunk ends at the next output time or after at
most :data:`CHUNK_STEPS` (or the singularity monitor's cadence) internal steps — IDA's
per-call step limit, set before each call through SUNDIALS' C API
(:class:`_IdaCounters`) — so that the monitor looks at the states every few steps,
progress is reported, Ctrl-C is answered (between chunks: the callbacks are Python
functions, where a pending KeyboardInterrupt is raised), `max_steps` is honoured exactly
and a failure keeps the outputs computed before it.
"""

from __future__ import annotations

import ctypes
import glob
import math
import os
import time
import warnings
from typing import Optional

import numpy as np
import scipy.sparse as sps

from phc.errors import SimulationSetupError
from phc.simulation.guard import CATCH, GuardedModule, ModelEvaluationError
from phc.simulation.monitor import SingularityMonitor, check_scales, diagnose_failure

LOCAL_TOLERANCE = 0.005
"""IDA runs at ``rtol · LOCAL_TOLERANCE`` and ``atol · LOCAL_TOLERANCE`` (but see
:data:`TIGHTEST_LOCAL`): its error test bounds the error made in one step, and what a user
reads is the error of the outputs, which accumulates over the run — most of all as a phase
error in undamped oscillations (a pendulum over 8 periods, the high modes of a beam). At a
tenth, ``rtol = 1e-6`` gave 2.7e-4 on the shipped pendulum and 3.4e-4 on the Timoshenko
beam. The global error of both grows like the local tolerance to the power ~0.6, and runs
that differ only in rounding (the NumPy and the numba backend) differ by ±30 %: at a
hundredth the beam was at 8.2e-5 on one backend and 1.1e-4 on the other; at 1/200 every
shipped and test model is within 1e-4 on both (at most 7.2e-5). What it gives on the
shipped models, in steps and in errors: ``benchmarks/bench_accuracy.py``
(``benchmarks/results/accuracy.md``, docs/tolerances.md)."""

TIGHTEST_LOCAL = 1e-13
"""IDA's local relative tolerance is not set below this (the factor :func:`local_fraction`
gives then rises above :data:`LOCAL_TOLERANCE`): a step's residual is evaluated to a few ε
times its largest terms, BDF's error estimate is a difference of predicted and corrected
values, and over the 10⁴–10⁵ steps of such a run the round-off that accumulates is of
order 1e-14; a local tolerance below ~1e-13 buys steps, not accuracy."""


def local_fraction(rtol: float) -> float:
    """The factor between the tolerances asked for and those IDA's error test applies:
    :data:`LOCAL_TOLERANCE`, raised so that ``rtol`` times it is no tighter than
    :data:`TIGHTEST_LOCAL` (and never above 1)."""
    rtol = float(rtol)
    if not rtol > 0:
        return LOCAL_TOLERANCE
    return min(1.0, max(LOCAL_TOLERANCE, TIGHTEST_LOCAL / rtol))


ALGEBRAIC_ATOL = 1e8
"""Absolute tolerance on algebraic variables: effectively removes them from the error test."""

DENSE_LIMIT = 120
"""Systems up to this size use the dense linear solver; larger ones the sparse one
(SuperLU_MT, one thread). Measured by ``benchmarks/bench_ida_linsolver.py`` (the flexible
slider–crank at 27–275 unknowns, CPU time per step, ``benchmarks/results/ida_linsolver.md``):
SUNDIALS' dense LU as fast or faster up to 115 unknowns, the sparse solver faster from 131 on."""

DENSE_SOLVER = "dense"
"""scikit-sundae's name of the dense solver: SUNDIALS' own LU (``dense``) or LAPACK's."""

MAX_ORDER = 5
"""Maximum BDF order (5 is IDA's default; 2 is A-stable for undamped stiff oscillations)."""

CHUNK_STEPS = 50
"""Most internal steps IDA takes in C before control returns to Python (progress, Ctrl-C,
the failure bookkeeping) when the singularity monitor does not ask for a shorter cadence."""

IDA_ROOT_RETURN, IDA_TOO_MUCH_WORK, IDA_NORMAL = 2, -1, 1

_STATUS_HINTS = {
    -1: "the solver took too many steps; raise `max_steps` or shorten the time span",
    -2: "the tolerances are too tight for double precision; loosen `rtol`/`atol`",
}
"""Hints for failures whose cause the status says; error-test (-3) and Newton (-4) failures
are diagnosed at the failure point (:func:`phc.simulation.monitor.diagnose_failure`)."""


def _import_ida():
    """scikit-SUNDAE's IDA class, loaded without ``scipy.optimize`` and NumPy's unused
    submodules (:func:`phc.simulation._lean.import_ida`)."""
    from phc.simulation._lean import import_ida

    try:
        return import_ida()
    except ImportError as err:  # pragma: no cover - dependency is required
        raise SimulationSetupError("the IDA backend needs scikit-sundae: pip install scikit-sundae") from err


# ---------------------------------------------------------------------------------------
# IDA's counters through SUNDIALS' C API

_LIBRARY: list = []   # [ctypes.CDLL or None], found once per process


def _mapped(fragment: str) -> list[str]:
    """Paths of the shared libraries loaded in this process whose name contains `fragment`
    (Linux's ``/proc/self/maps``; empty elsewhere)."""
    try:
        with open("/proc/self/maps") as fh:
            return sorted({line.split()[-1] for line in fh if fragment in line})
    except OSError:
        return []


def _first_library(paths, symbol: str):
    """(``ctypes.CDLL``, path) of the first of `paths` that loads and has `symbol`, or (None, None)."""
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
            getattr(lib, symbol)
            return lib, path
        except (OSError, AttributeError):
            continue
    return None, None


def _ida_library():
    """The SUNDIALS IDA shared library scikit-sundae's extension runs (already loaded in
    this process: ``dlopen`` of its path returns the same copy), or None."""
    if _LIBRARY:
        return _LIBRARY[0]
    lib = None
    try:
        import sksundae

        paths = _mapped("libsundials_ida")
        if not paths:
            root = os.path.dirname(os.path.dirname(sksundae.__file__))
            for pattern in ("scikit_sundae.libs/libsundials_ida*", "sksundae/.dylibs/libsundials_ida*",
                            "sksundae.libs/*sundials_ida*"):
                paths += glob.glob(os.path.join(root, pattern))
        lib, path = _first_library(paths, "IDAGetNumSteps")
        if lib is not None:
            _declare_solve(lib, path)
            lib.IDAGetNumSteps.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_long)]
            lib.IDAGetLastStep.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_double)]
            lib.IDAGetNumResEvals.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_long)]
            lib.IDAGetNumJacEvals.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_long)]
            lib.IDASetMaxNumSteps.argtypes = [ctypes.c_void_p, ctypes.c_long]
            lib.IDASetStopTime.argtypes = [ctypes.c_void_p, ctypes.c_double]
            lib.SUNContext_ClearErrHandlers.argtypes = [ctypes.c_void_p]
            try:
                lib.IDASetJacFn.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
                lib.IDASetJacFn.restype = ctypes.c_int
            except AttributeError:  # the compiled callbacks are then not used
                pass
            for name in ("IDAGetNumSteps", "IDAGetLastStep", "IDAGetNumResEvals", "IDAGetNumJacEvals",
                         "IDASetMaxNumSteps", "IDASetStopTime", "SUNContext_ClearErrHandlers"):
                getattr(lib, name).restype = ctypes.c_int
    except Exception:  # noqa: BLE001 - the counters are an optimization with a fallback
        lib = None
    _LIBRARY.append(lib)
    return lib


def _declare_solve(lib, path) -> None:
    """``lib.solve``: ``IDASolve`` called with the GIL held (``ctypes.PyDLL``: the residual
    and Jacobian callbacks are Python functions, and an exception they leave set is raised
    when the call returns), and ``lib.array``: ``N_VGetArrayPointer`` from SUNDIALS' core
    library, or None where either cannot be had (the solver is then driven through
    scikit-SUNDAE's ``step``)."""
    lib.solve = lib.array = None
    try:
        solve = ctypes.PyDLL(path).IDASolve
        solve.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.POINTER(ctypes.c_double),
                          ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
        solve.restype = ctypes.c_int
        # SUNDIALS' core library, or reachable through IDA's own
        core, _ = _first_library(_mapped("libsundials_core") or [path], "N_VGetArrayPointer")
        if core is None:
            return
        core.N_VGetArrayPointer.argtypes = [ctypes.c_void_p]
        core.N_VGetArrayPointer.restype = ctypes.c_void_p
        core.N_VGetLength.argtypes = [ctypes.c_void_p]
        core.N_VGetLength.restype = ctypes.c_int64
        lib.solve, lib.array = solve, core
    except Exception:  # noqa: BLE001 - an optimization with a fallback
        lib.solve = lib.array = None


class _IdaCounters:
    """Number of steps, last step size and the per-call step limit of a scikit-sundae IDA
    solver, read and set through SUNDIALS' C API (``IDAGetNumSteps``, ``IDAGetLastStep``,
    ``IDASetMaxNumSteps``), which scikit-sundae does not expose.

    The solver's IDA memory pointer is the first field of scikit-sundae's ``_cy_ida.IDA``
    extension object; :meth:`attach` uses it only after checking the object's layout (its
    size, the system size and its ``AuxData`` object in their fields, the memory's context
    and unit round-off, and the number of residual evaluations against scikit-sundae's),
    and returns None otherwise: the integrator then counts steps itself."""

    _SIZE = 144  # sizeof(_cy_ida.IDA): head, vtable, mem, ctx, 7 pointers, NEQ, 5 objects
    _MEM, _CTX, _YY, _YP, _NEQ, _AUX = 24, 32, 64, 72, 96, 104

    def __init__(self, lib, mem):
        self.lib, self.mem = lib, ctypes.c_void_p(mem)
        self._long, self._double = ctypes.c_long(), ctypes.c_double()
        self._tret = ctypes.c_double()
        self.y = self.yp = None
        """Views of the solver's own output vectors (``yy``, ``yp``), when :meth:`advance`
        may be used."""
        self._vectors = (None, None)
        self._aux = None
        self._base = 0          # scikit-SUNDAE's solver object (its address)
        self.native = None      # the compiled callbacks in use (phc.simulation.ida_native.Native)
        self._native = None     # (residual function and fields they replaced)
        self._guarded = None    # (guarded module, p): the located error of a compiled callback's failure
        self._residual = None   # (ctypes callback, the function it replaced, its fields, [its calls])
        self._unverified = False
        self.pending: list = []
        """An exception the installed residual callback caught (raised by :meth:`advance`)."""
        self.failures: list = [0, None, 0.0, False]
        """The callback's recoverable failures (model errors at a trial point): how many so
        far, the last one's error and time, and whether the latest evaluation was one (IDA
        retries shorter; :meth:`advance` raises the error when IDA then gives up)."""

    @classmethod
    def attach(cls, solver, n: int, nfev: int) -> Optional["_IdaCounters"]:
        try:
            from sksundae import _cy_ida

            obj = getattr(solver, "_IDA__IDA", None)
            if obj is None or type(obj) is not _cy_ida.IDA or type(obj).__basicsize__ != cls._SIZE:
                return None
            lib = _ida_library()
            if lib is None:
                return None
            base = id(obj)
            word = ctypes.c_void_p.from_address
            if ctypes.c_int64.from_address(base + cls._NEQ).value != n:
                return None
            aux = word(base + cls._AUX).value
            if not aux or word(aux + 8).value != id(_cy_ida.AuxData):  # ob_type of the AuxData object
                return None
            mem, ctx = word(base + cls._MEM).value, word(base + cls._CTX).value
            if not mem or not ctx or word(mem).value != ctx:  # IDAMemRec: SUNContext, then uround
                return None
            if ctypes.c_double.from_address(mem + 8).value != np.finfo(float).eps:
                return None
            counters = cls(lib, mem)
            if counters._get(lib.IDAGetNumResEvals, counters._long) != nfev:
                return None
            # SUNDIALS prints every error it returns on stderr, among them the step limit that ends
            # each chunk; phc reports a failure itself (diagnosed), so this solver's context prints none
            if lib.SUNContext_ClearErrHandlers(ctypes.c_void_p(ctx)) != 0:
                return None
            counters._attach_vectors(word(base + cls._YY).value, word(base + cls._YP).value, n)
            counters._aux, counters._base = aux, base
            return counters
        except Exception:  # noqa: BLE001 - an optimization with a fallback
            return None

    def _get(self, fn, box):
        if fn(self.mem, ctypes.byref(box)) < 0:
            raise RuntimeError(f"{fn.__name__} failed")
        return box.value

    def steps(self) -> int:
        return int(self._get(self.lib.IDAGetNumSteps, self._long))

    def last_step(self) -> float:
        return float(self._get(self.lib.IDAGetLastStep, self._double))

    def set_max_steps(self, k: int) -> None:
        self.lib.IDASetMaxNumSteps(self.mem, int(k))

    def jacobian_evaluations(self) -> int:
        return int(self._get(self.lib.IDAGetNumJacEvals, self._long))

    def residual_evaluations(self) -> int:
        return int(self._get(self.lib.IDAGetNumResEvals, self._long))

    def _attach_vectors(self, yy: int, yp: int, n: int) -> None:
        """Views of scikit-SUNDAE's ``yy``/``yp`` N_Vectors, for :meth:`advance`: used only
        when both are serial vectors of length `n` holding the state `init_step` left."""
        lib, core = self.lib, getattr(self.lib, "array", None)
        if getattr(lib, "solve", None) is None or core is None or not yy or not yp:
            return
        views = []
        for vec in (yy, yp):
            if core.N_VGetLength(ctypes.c_void_p(vec)) != n:
                return
            data = core.N_VGetArrayPointer(ctypes.c_void_p(vec))
            if not data:
                return
            views.append(np.ctypeslib.as_array((ctypes.c_double * n).from_address(data)))
        self._vectors = (ctypes.c_void_p(yy), ctypes.c_void_p(yp))
        self.y, self.yp = views

    @property
    def can_advance(self) -> bool:
        return self.y is not None

    def set_stop_time(self, t: float) -> None:
        if self.lib.IDASetStopTime(self.mem, float(t)) < 0:
            raise RuntimeError("IDASetStopTime failed")

    def advance(self, t: float) -> tuple[int, float]:
        """``IDASolve`` in normal mode to `t` (status, time reached); the state is then in
        :attr:`y`/:attr:`yp`. What scikit-SUNDAE's ``step`` does without building a result
        object and copying the state each call (about 25 µs an output time). An exception a
        callback raised is raised here."""
        before = self.residual_evaluations() if self._unverified else None
        status = self.lib.solve(self.mem, t, ctypes.byref(self._tret), self._vectors[0], self._vectors[1],
                                IDA_NORMAL)
        if before is not None:
            self._verify_residual(before)
        if self.pending:
            err = self.pending[0]
            self.pending.clear()
            raise err
        if self.failures[3]:
            self.failures[3] = False
            if status < 0 and status != IDA_TOO_MUCH_WORK:  # IDA gave up where the model cannot be evaluated
                raise self.failures[1]
        if self.native is not None and self.native.failed_last:
            self.native.clear_last()
            if status < 0 and status != IDA_TOO_MUCH_WORK:
                raise self.native.error(*self._guarded)
        return int(status), float(self._tret.value)

    def failure_count(self) -> int:
        """Recoverable failures of the callbacks so far (Python's and the compiled ones')."""
        return self.failures[0] + (self.native.count if self.native is not None else 0)

    def last_failure_time(self) -> float:
        """The time of the latest recoverable failure."""
        if self.native is not None and self.native.count:
            return self.native.time
        return self.failures[2]

    def last_failure_error(self):
        """The located error of the latest recoverable failure."""
        if self.native is not None and self.native.count:
            return self.native.error(*self._guarded)
        return self.failures[1]

    def last_cj(self, python_cj: float) -> float:
        """α/h of the step IDA last formed its matrix for."""
        return self.native.cj if self.native is not None and self.native.cj > 0 else python_cj

    def install_native(self, native, guarded, p) -> bool:
        """Let IDA call the compiled callbacks of `native` (:mod:`phc.simulation.ida_native`)
        for its residual and Jacobian, with its context array as the user data; the
        residual's two fields are found as by :meth:`install_residual` (whose Python
        callback, if installed, is removed first), the Jacobian is set through SUNDIALS'
        ``IDASetJacFn``. Returns whether it was installed (False: nothing changed)."""
        if self._native is not None:
            return False
        self.restore_residual()
        found = self._residual_fields()
        set_jac = getattr(self.lib, "IDASetJacFn", None)
        if found is None or set_jac is None:
            return False
        original, fields = found
        word = ctypes.c_void_p.from_address
        mem = self.mem.value
        word(mem + self._USER).value = native.context.ctypes.data
        if set_jac(self.mem, ctypes.c_void_p(native.jacobian.address)) != 0:
            word(mem + self._USER).value = self._aux
            return False
        for off in fields:
            word(mem + off).value = native.residual.address
        self._native, self.native, self._guarded = (original, fields), native, (guarded, p)
        return True

    def restore_native(self) -> None:
        """scikit-SUNDAE's residual wrapper and user data back; the Jacobian becomes IDA's
        difference quotients (scikit-SUNDAE's wrapper cannot be set again from here): the
        solver object stays usable."""
        if self._native is None:
            return
        original, fields = self._native
        word = ctypes.c_void_p.from_address
        mem = self.mem.value
        for off in fields:
            word(mem + off).value = original
        word(mem + self._USER).value = self._aux
        self.lib.IDASetJacFn(self.mem, None)
        self._native = None

    # IDA's memory (SUNDIALS' ``IDAMemRec``) begins with its context, the unit round-off, the
    # residual function and its user data (checked by :meth:`attach` and :meth:`install_residual`);
    # further on, after the nonlinear solver object and its ownership flag, the copy of the
    # residual function the nonlinear solver calls (``nls_res``)
    _RES, _USER, _SCAN = 16, 24, 1536

    def install_residual(self, resfn, n: int) -> bool:
        """Let IDA call `resfn(t, y, ẏ, r)` through a ctypes callback of phc's instead of
        scikit-SUNDAE's wrapper, which makes three NumPy arrays of the N_Vectors every call
        (about 4 µs, more than the pendulum's whole residual): IDA evaluates its residual on
        a handful of vectors it allocates once (``IDAInit``), so each gets one NumPy view, kept
        by its address. A model that cannot be evaluated at a trial point (a
        :class:`ModelEvaluationError` from `resfn`: outside its domain, an overflow) is a
        recoverable failure for IDA (the callback returns 1): IDA retries the step shorter,
        as Newton's method does after a failed iteration, and only when it gives up there
        does :meth:`advance` raise the error, located. (scikit-SUNDAE's wrapper can only
        report every exception as unrecoverable: a long trial step that overflowed ended the
        run at its start.) Any other exception (Ctrl-C) is kept in :attr:`pending`, the
        callback returns −1 (IDA stops) and :meth:`advance` raises it.

        SUNDIALS has no call that replaces the residual after ``IDAInit``; its memory holds
        the function twice, as ``ida_res`` (right before the user data, here scikit-SUNDAE's
        ``AuxData`` object) and as ``nls_res``, the copy the nonlinear solver calls, two
        words after the nonlinear solver object (whose context is the memory's). Both fields
        are found and checked that way; where either check fails nothing is changed and
        False is returned (the run then goes through scikit-SUNDAE's wrapper, as before).
        :meth:`advance` checks on its first call that the callback is the one IDA calls,
        and :meth:`restore_residual` puts the wrapper back."""
        core = getattr(self.lib, "array", None)
        if self.y is None or core is None or self._residual is not None or self._native is not None:
            return False
        found = self._residual_fields()
        if found is None:
            return False
        original, fields = found
        mem = self.mem.value
        word = ctypes.c_void_p.from_address
        pending, failures, views, seen = self.pending, self.failures, {}, [0]
        as_array, vector = np.ctypeslib.as_array, ctypes.c_double * n
        get_data, get_length = core.N_VGetArrayPointer, core.N_VGetLength

        def view(ptr):
            data = get_data(ptr) if ptr else None
            if not data or get_length(ptr) != n:
                raise SimulationSetupError("IDA passed the residual a vector phc cannot read; "
                                           "this scikit-SUNDAE build is not supported by phc's direct callback")
            views[ptr] = arr = as_array(vector.from_address(data))
            return arr

        def callback(t, yy, yp, rr, _data):
            try:
                seen[0] += 1
                try:
                    resfn(t, views[yy], views[yp], views[rr])
                except KeyError:  # a vector seen for the first time
                    resfn(t, views[yy] if yy in views else view(yy), views[yp] if yp in views else view(yp),
                          views[rr] if rr in views else view(rr))
                if failures[3]:
                    failures[3] = False
                return 0
            except ModelEvaluationError as err:  # a trial point outside the model's domain
                failures[0] += 1
                failures[1], failures[2], failures[3] = err, t, True
                return 1
            except BaseException as err:  # noqa: BLE001 - raised again by advance()
                pending.append(err)
                return -1

        c_callback = _RESIDUAL_FN(callback)
        address = ctypes.cast(c_callback, ctypes.c_void_p).value
        for off in fields:
            word(mem + off).value = address
        self._residual = (c_callback, original, fields, seen)
        self._unverified = True
        return True

    def _residual_fields(self):
        """(the residual function, the offsets of ``ida_res`` and ``nls_res`` in IDA's
        memory), or None where the layout is not the one described in :meth:`install_residual`."""
        if self._aux is None:
            return None
        mem = self.mem.value
        word = ctypes.c_void_p.from_address
        original, ctx = word(mem + self._RES).value, word(mem).value
        if word(mem + self._USER).value != self._aux or not original or not ctx:
            return None
        for off in range(self._USER + 8, self._SCAN, 8):  # the first other copy: nls_res
            if word(mem + off).value == original:
                nls = word(mem + off - 16).value
                # SUNNonlinearSolver: content, ops, context (SUNDIALS ≥ 7.4: content, a pointer
                # of its Python interface, ops, context)
                if not nls or ctx not in (word(nls + 16).value, word(nls + 24).value):
                    return None
                return original, [self._RES, off]
        return None

    def _verify_residual(self, evaluations_before: int) -> None:
        """After the first :meth:`advance` with the callback installed: the callback must
        have been called at least as often as IDA counts residual evaluations (its nonlinear
        solver's; difference quotients of the Jacobian, which phc does not use, would add
        calls); else the fields were not the ones IDA calls, and scikit-SUNDAE's wrapper is
        put back."""
        self._unverified = False
        if self._residual is not None and self._residual[3][0] < self.residual_evaluations() - evaluations_before:
            self.restore_residual()

    def restore_residual(self) -> None:
        """Give IDA scikit-SUNDAE's residual wrapper back (the solver object may outlive the run)."""
        if self._residual is not None:
            for off in self._residual[2]:
                ctypes.c_void_p.from_address(self.mem.value + off).value = self._residual[1]
            self._residual = None

    @property
    def direct_residual(self) -> bool:
        """Whether IDA calls the residual through :meth:`install_residual`'s callback."""
        return self._residual is not None


class _DeferredInterrupt:
    """Ctrl-C taken between IDA's chunks while IDA calls phc's ``ctypes`` residual callback.

    Python raises KeyboardInterrupt at the next instruction it runs, and while IDA steps that
    is in the callback; raised at the callback's first instruction, before its ``try``, the
    exception would leave the callback, which ctypes cannot pass on to IDA: it prints it
    ("Exception ignored on calling ctypes callback function"), IDA carries on with a
    residual never written, and the interrupt is lost. So, in the main thread and where
    SIGINT has Python's default handler, a handler that only notes the signal is installed
    for the run, and :meth:`check` (between chunks: at most ``CHUNK_STEPS`` steps apart)
    raises KeyboardInterrupt there; :meth:`close` puts the default handler back."""

    def __init__(self, active: bool):
        import signal
        import threading

        self.hit, self._previous = False, None
        if active and threading.current_thread() is threading.main_thread() \
                and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._previous = signal.signal(signal.SIGINT, self._note)

    def _note(self, signum, frame) -> None:
        self.hit = True

    def check(self) -> None:
        if self.hit:
            self.hit = False
            raise KeyboardInterrupt

    def close(self) -> None:
        if self._previous is not None:
            import signal

            signal.signal(signal.SIGINT, self._previous)
            self._previous = None


_RESIDUAL_FN = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p,
                                ctypes.c_void_p, ctypes.c_void_p)
"""SUNDIALS' ``IDAResFn``: ``int (sunrealtype t, N_Vector yy, N_Vector yp, N_Vector rr, void *user_data)``."""


# ---------------------------------------------------------------------------------------
# Callbacks

def _callbacks(mod, p, n: int, sparse: bool):
    """(resfn, jacfn, state) for scikit-sundae: the raw generated functions (compiled or
    NumPy) into preallocated buffers, checked for a finite result by one dot product; a
    failure is evaluated again through the guard (:mod:`phc.simulation.guard`), which
    raises the located :class:`ModelEvaluationError`. The dense Jacobian is scattered into
    scikit-sundae's own matrix through precomputed flat indices (its zeros are written once).
    `state` holds the last ``cj`` (α/h of the step IDA was trying)."""
    guarded = mod if isinstance(mod, GuardedModule) else None
    raw = mod.module if guarded is not None else mod
    residual, jacobian = raw.residual, raw.jacobian
    check_res = guarded.residual if guarded is not None else None
    check_jac = guarded.jacobian if guarded is not None else None
    rows, cols = np.asarray(mod.JAC_ROWS, dtype=np.intp), np.asarray(mod.JAC_COLS, dtype=np.intp)
    state = {"cj": 0.0}
    isfinite, dot = math.isfinite, np.dot

    if check_res is None:
        def resfn(t, y, yp, res):
            residual(t, y, yp, p, res)
    else:
        def resfn(t, y, yp, res):
            try:
                residual(t, y, yp, p, res)
            except CATCH:
                check_res(t, y, yp, p, res)  # raises the located error
                raise
            if not isfinite(res.dot(res)):  # (the method: a third of np.dot's call overhead)
                check_res(t, y, yp, p, res)  # raises if a value is not finite (else an overflow of the check)

    if sparse:
        def jacfn(t, y, yp, res, cj, JJ):
            state["cj"] = cj
            try:
                jacobian(t, y, yp, p, cj, JJ)
            except CATCH:
                if check_jac is None:
                    raise
                check_jac(t, y, yp, p, cj, JJ)
                raise
            if not isfinite(dot(JJ, JJ)) and check_jac is not None:
                check_jac(t, y, yp, p, cj, JJ)
    else:
        buf = np.zeros(len(rows))
        flat = rows * n + cols
        target = [None, None]  # scikit-sundae's matrix (the same array every call) and its flat view

        def jacfn(t, y, yp, res, cj, JJ):
            state["cj"] = cj
            try:
                jacobian(t, y, yp, p, cj, buf)
            except CATCH:
                if check_jac is None:
                    raise
                check_jac(t, y, yp, p, cj, buf)
                raise
            if not isfinite(dot(buf, buf)) and check_jac is not None:
                check_jac(t, y, yp, p, cj, buf)
            if target[0] is not JJ:
                JJ.fill(0.0)
                target[0], target[1] = JJ, JJ.reshape(-1)
            target[1][flat] = buf

    return resfn, jacfn, state


LOOK_STRETCH = 32
"""Most the singularity monitor's cadence is stretched where the conditioning is flat."""
FLAT_DECADES = 0.1
"""Change of the conditioning ratio between two looks (decades) below which it counts as flat."""
FAR_RATIO = 1e-6
"""Conditioning ratio above which the monitor may look less often (its threshold is 1e-11)."""


def _native_candidate(mod, python_callback: bool, n: int, sparse: bool):
    """The raw numba module whose compiled callbacks a long run may change to, or None."""
    from phc.simulation import ida_native

    raw = mod.module if isinstance(mod, GuardedModule) else mod
    if not python_callback or sparse or getattr(raw, "BACKEND", "numpy") != "numba" or not ida_native.enabled():
        return None
    return raw


def _switch_to_native(counters, raw, mod, p):
    """Build (once per model and process) and install the compiled callbacks; None
    afterwards either way (a failure to build them keeps the Python callback)."""
    from phc.simulation import ida_native

    at = ida_native.data_offset(counters.lib, counters._base, counters._vectors[0].value, int(raw.N))
    if at is None:
        return None
    try:
        native = ida_native.Native(raw, p, raw.JAC_ROWS, raw.JAC_COLS, at)
    except Exception:  # noqa: BLE001 - numba could not build them: the Python callback stays
        return None
    counters.install_native(native, mod if isinstance(mod, GuardedModule) else None, p)
    return None


SWITCH_EVALUATIONS = 100_000
"""Residual evaluations through the Python callback after which a run on the numba backend
changes to compiled callbacks (:mod:`phc.simulation.ida_native`): about 0.2 s of Python
calls, about what building the callbacks costs."""


EDGE_SHRINK = 1e-6
"""A model that cannot be evaluated at IDA's trial point is a recoverable failure: IDA
retries the step shorter (:meth:`_IdaCounters.install_residual`). After a long trial step's
overshoot the run passes the failed trial point within a few steps. Where the solution
itself runs into the edge of the model's domain it never does: the steps creep up to the
edge, shorter and shorter (10⁶ steps without reaching it, where the first failure ended
the run before). Once the steps have shrunk by this factor below the step size before the
first failure, without passing the failed trial point, the run stops with the last
failure's located error."""


CRAWL_CHECK_STEPS = 2000
"""Steps between two diagnoses of a crawling run (one whose step size cannot reach the end
of the run within ``max_steps``): each costs a few looks of the monitor."""


APPROACH_FALL = 10.0
"""A run whose conditioning fell by at least this factor over the monitor's last looks, and
further to the failure point, failed approaching a singular configuration."""


def _approaching_singularity(monitor, h, how: str = "Newton's iteration failed before reaching it") -> Optional[str]:
    """The singular configuration a run failed on its way to, or None.

    Close to a singular configuration the iteration matrix is conditioned like the distance
    to it, and IDA's Newton iteration fails (round-off outgrows the tolerances) before the
    conditioning reaches the monitor's threshold — the tighter the tolerances, the earlier:
    the folded slider–crank failed half a degree before its rod stood perpendicular to the guide.
    The conditioning at the monitor's last looks (``monitor.history``) is compared at one
    step size `h` (the ratio depends on it); when it fell steadily, by :data:`APPROACH_FALL`
    or more, to below :data:`FAR_RATIO`, the monitor's message is given for the last look
    (the dependent equations, their connections, the condition)."""
    if not monitor.enabled or h <= 0:
        return None
    h = max(h, monitor.h_floor)
    looks = []  # a tenth of a step apart (while IDA cut its step, its looks repeat the failure point)
    for look in monitor.history:
        if not looks or look[0] > looks[-1][0] + 0.1 * h:
            looks.append(look)
    if len(looks) < 3:
        return None
    picks = sorted({0, len(looks) // 3, 2 * len(looks) // 3, len(looks) - 1})
    try:
        ratios = [monitor.ratio(*looks[i][:3], h)[0] for i in picks]
    except (ModelEvaluationError, *CATCH, np.linalg.LinAlgError):
        return None
    if any(b >= a for a, b in zip(ratios, ratios[1:])) or ratios[0] < APPROACH_FALL * ratios[-1] \
            or ratios[-1] > FAR_RATIO:
        return None
    t_last, y_last, yp_last = looks[-1][:3]
    warning = monitor.check(t_last, y_last, yp_last, h, threshold=2.0 * ratios[-1])
    if warning is None:
        return None
    return (f"the conditioning of the iteration matrix fell from {ratios[0]:.1e} at t = {looks[0][0]:.6g} to "
            f"{ratios[-1]:.1e} at t = {t_last:.6g}: the run was approaching a singular configuration, and "
            f"{how}; {warning}")


def _status_text(res, status: int) -> str:
    """scikit-SUNDAE's text for an IDA return flag."""
    if res is not None:
        return str(res.message)
    try:
        from sksundae._cy_ida import IDAMESSAGES

        return str(IDAMESSAGES.get(status, f"IDA flag {status}"))
    except Exception:  # noqa: BLE001 - only the wording of a message
        return f"IDA flag {status}"


def _next_cadence(cadence: int, base: int, before: Optional[float], ratio: Optional[float]) -> int:
    """Steps until the monitor's next look: 1.5× longer (up to :data:`LOOK_STRETCH`× `base`)
    when the ratio moved less than :data:`FLAT_DECADES` since the last look and stays above
    :data:`FAR_RATIO`, else back to `base` at once."""
    if before is None or ratio is None or not (ratio > FAR_RATIO and before > FAR_RATIO):
        return base
    if abs(math.log10(ratio / before)) >= FLAT_DECADES:
        return base
    return min(LOOK_STRETCH * base, max(cadence + 1, int(1.5 * cadence)))


def determined_algebraic(mod, p, t, y, yp) -> np.ndarray:
    """Mask of the algebraic variables the algebraic rows determine from the states (index 1:
    a junction effort, a resistor's flow), as opposed to those only the derivative of a
    constraint determines (index 2: multipliers, the torque a flow source applies).

    The algebraic rows are those without ẏ (``F_ẏ`` row zero at (t, y, ẏ)); on their pattern
    in the algebraic variables, a maximum matching and the Dulmage–Mendelsohn
    decomposition: a variable an alternating path reaches from an unmatched variable is
    not determined (the rows leave a choice), every other matched variable is. Index-1
    variables go into IDA's Newton and error tests like the states; index-2 ones cannot
    (BDF then cuts its step without end) and are recomputed at the output times instead
    (:mod:`phc.simulation.polish`)."""
    from phc.analysis.matching import bipartite_matching

    n, m = mod.N, len(mod.EQUATIONS)
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    out = np.zeros(n, dtype=bool)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    if not len(rows) or m != n:
        return out
    # the entries that are nonzero here or at a nearby point: the modes of switches are
    # parameters (a sticking friction law replaces its row), a coefficient may vanish by chance
    rng = np.random.default_rng(0)
    size = np.abs(y) + np.abs(yp) + 1e-3
    nonzero_y = np.zeros(len(rows), dtype=bool)
    nonzero_yp = np.zeros(len(rows), dtype=bool)
    for y_, yp_ in ((y, yp), (y + 1e-3 * size * rng.uniform(0.5, 1.5, n), yp + 1e-3 * size * rng.uniform(0.5, 1.5, n))):
        a, b = np.zeros(len(rows)), np.zeros(len(rows))
        try:
            mod.jacobian(t, y_, yp_, p, 0.0, a)
            mod.jacobian(t, y_, yp_, p, 1.0, b)
        except (ModelEvaluationError, *CATCH):
            return out
        nonzero_y |= (a != 0) | ~np.isfinite(a)
        nonzero_yp |= (b - a != 0) | ~np.isfinite(b)
    dynamic = np.zeros(m, dtype=bool)
    dynamic[rows[nonzero_yp]] = True
    alg_rows = np.flatnonzero(~dynamic)
    alg_cols = np.flatnonzero(~diff & np.array([not str(v).startswith("ggl.") for v in mod.VARIABLES]))
    if not len(alg_rows) or not len(alg_cols):
        return out
    rpos = np.full(m, -1)
    rpos[alg_rows] = np.arange(len(alg_rows))
    cpos = np.full(n, -1)
    cpos[alg_cols] = np.arange(len(alg_cols))
    sel = (rpos[rows] >= 0) & (cpos[cols] >= 0) & nonzero_y
    pattern = sps.csr_matrix((np.ones(int(sel.sum())), (rpos[rows[sel]], cpos[cols[sel]])),
                             shape=(len(alg_rows), len(alg_cols)))
    match = bipartite_matching(pattern)
    row_of = np.full(len(alg_cols), -1)
    matched = np.flatnonzero(match >= 0)
    row_of[match[matched]] = matched
    by_col = pattern.tocsc()
    seen = np.zeros(len(alg_cols), dtype=bool)
    stack = list(np.flatnonzero(row_of < 0))
    seen[stack] = True
    while stack:  # alternating paths: unmatched column → its rows → their matched columns
        c = stack.pop()
        for r in by_col.indices[by_col.indptr[c]:by_col.indptr[c + 1]]:
            c2 = match[r]
            if c2 >= 0 and not seen[c2]:
                seen[c2] = True
                stack.append(c2)
    out[alg_cols[~seen]] = True
    return out


SENSITIVITY_DENSE = 400
"""Up to this many unknowns the scales of the determined algebraic variables are raised to
what the states' tolerances allow them (:func:`determined_scales`); larger models keep theirs."""


CANCELLATION = 10.0
"""An index-1 variable below 1/CANCELLATION of the terms the states put into it is a
difference of those terms (:func:`determined_scales`)."""


def determined_scales(mod, p, t, y, yp, determined, scales, rtol: float = 1.0, atol: float = 1.0
                      ) -> Optional[np.ndarray]:
    """The nominal `scales` with each index-1 algebraic variable z_j (`determined`) that is a
    small difference of the terms the states put into it raised to ``(1 + rtol/atol) T_j``,
    ``T_j = Σ_k |∂z_j/∂x_k| s_k``: the error the states' own tolerances (``rtol·|x_k| +
    atol·s_k``, |x_k| up to s_k) put into it, over atol. A small difference is one of

    * over the run: ``Σ_k |∂z_j/∂x_k| n_k`` above ``CANCELLATION · n_j``, with ``n`` the sizes
      the variables take (:attr:`phc.simulation.scaling.Scales.sizes`, the scales before
      the round-off floor; a floor that raised z's scale says how finely z can be resolved,
      not how large it is);
    * at the start of this piece (`y`, in the modes of `p`): the error the states'
      tolerances put into z, ``Σ_k |∂z_j/∂x_k| (rtol·|x_k| + atol·s_k)``, above
      ``CANCELLATION`` times z's own ``rtol·|z_j| + atol·s_j``. A switched law makes z
      small in one mode only — a diode's voltage is Ron·i, 0.1 V out of the source's and
      the capacitor's 7 V, while it conducts, and 13 V while it blocks — and a piece that
      begins at an event begins with z on the boundary.

    Other index-1 variables keep their scales (one that is a state times a factor, a
    friction element's flow p/m, is tested as tightly as the state determines it).

    The algebraic rows determine z from the states x (and t); to first order
    ``∂z/∂x = −(F_z)⁺ F_x`` on those rows. IDA tests z like a state, at
    ``rtol·|z| + atol·s_z``; where z is the small difference of large terms driven by the
    states — an inductor's voltage ``V(t) − R φ/L`` behind a resistor, 0.04 V out of 10 V,
    with ``∂z/∂φ = −R/L = −25 000`` — an error of the states within their own tolerance
    moves z by far more than z's, and IDA cuts its step to resolve the states far beyond
    what was asked: 556 000 steps for 0.1 s of an RL circuit driven at 100 rad/s, where
    raising the scale of that voltage to the size of the terms it is the difference of
    takes a few hundred: IDA at order 5 fell into runs of error-test and Newton failures,
    every step, while the same model with the voltage left out of the test, or at order 3,
    ran smoothly. At order 1 it does not get out again: z's error estimate is then the
    change of the states' truncation error times ∂z/∂x — ``(h² − h_old²)/2 · v_C''/Ron`` for
    a diode's current behind a capacitor — so a step that doubles fails the test and the
    retry passes at the old size; with a failure every other step BDF never raises its
    order. The rectifier of tests/simulation/test_events.py crawled that way, with steps of
    2.5e-9 s, to 10⁶ steps: its diode's voltage and current had local tolerances of
    1.5e-12 V and 2.1e-12 A while the capacitor's (3.6e-11 V at 7 V) put 3.6e-11 V and
    7e-11 A into them (the round-off floor had raised their scales to 180 V and 167 A,
    hiding the cancellation; the current takes 0.54 A, the voltage 13 V only while the
    diode blocks). Where it fell into the trap depended on round-off: the BLAS kernel
    (Zen, Haswell; SkylakeX passed) or the end time (t_end = 0.0623 s crawled on SkylakeX);
    now about 3 000 steps on each. The user's own scales are kept. Returns None where
    nothing changes (no determined variable, a model above :data:`SENSITIVITY_DENSE`
    unknowns, or a Jacobian that cannot be evaluated)."""
    n, m = mod.N, len(mod.EQUATIONS)
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    z_cols = np.flatnonzero(np.asarray(determined, dtype=bool) & ~diff)
    names = list(mod.VARIABLES)
    x_mask = diff.copy()
    if "energy.supplied" in names:  # it feeds nothing back
        x_mask[names.index("energy.supplied")] = False
    x_cols = np.flatnonzero(x_mask)
    if scales is None or not len(z_cols) or not len(x_cols) or n > SENSITIVITY_DENSE or m != n:
        return None
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    a, b = np.zeros(len(rows)), np.zeros(len(rows))
    try:
        mod.jacobian(t, y, yp, p, 0.0, a)
        mod.jacobian(t, y, yp, p, 1.0, b)
    except (ModelEvaluationError, *CATCH):
        return None
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return None
    Fy = np.zeros((m, n))
    Fyp = np.zeros((m, n))
    np.add.at(Fy, (rows, cols), a)
    np.add.at(Fyp, (rows, cols), b - a)
    alg_rows = np.flatnonzero(~np.any(Fyp != 0, axis=1))
    if not len(alg_rows):
        return None
    Fz = Fy[np.ix_(alg_rows, z_cols)]
    Fx = Fy[np.ix_(alg_rows, x_cols)]
    try:
        dz_dx = -np.linalg.lstsq(Fz, Fx, rcond=None)[0]
    except np.linalg.LinAlgError:
        return None
    s = np.asarray(scales, dtype=float)
    ratio = rtol / atol if atol > 0 and np.isfinite(rtol / atol) else 1.0
    terms = np.abs(dz_dx) @ s[x_cols]
    # where z is a small difference of the states' terms, its own rtol·|z| is far tighter than
    # the states' rtol·|x| puts into it: that part goes into the scale too. Judged on the sizes
    # the variables take, before the round-off floor (scaling.Scales.sizes: a floor that raised
    # z's scale above its size says how finely z can be resolved, not how large it is) ...
    size = getattr(scales, "sizes", None)
    size = s if size is None or np.shape(size) != s.shape else np.asarray(size, dtype=float)
    cancels = np.abs(dz_dx) @ size[x_cols] > CANCELLATION * size[z_cols]
    # ... and at the values of the start: in this piece's mode z may be a small difference where
    # its size over the run is not (a diode's voltage: Ron·i, 0.1 V out of the capacitor's 7 V,
    # while it conducts; 13 V blocking), and a piece that starts at an event starts with z on
    # the boundary. There the error the states' tolerances put into z is compared with z's own
    x = np.where(np.isfinite(y), np.abs(np.asarray(y, dtype=float)), 0.0)
    put = np.abs(dz_dx) @ (ratio * x[x_cols] + s[x_cols])
    cancels |= put > CANCELLATION * (ratio * x[z_cols] + s[z_cols])
    need = np.where(cancels, (1.0 + ratio) * terms, 0.0)
    out = s.copy()
    user = set(getattr(scales, "user", ()) or ())
    for j, v in zip(z_cols, need):
        if int(j) not in user and np.isfinite(v) and v > out[j]:
            out[j] = v
    return out if np.any(out != s) else None


def algebraic_rates(mod, p, t, y, yp, determined) -> np.ndarray:
    """ẏ with the rates of the `determined` (index-1) algebraic variables filled in: the
    time derivative of their algebraic rows, ``F_y[R, A] ż_A = −(F_y[R, states] ẏ + F_t[R])``
    (least squares). A consistent start leaves them 0, and IDA's first predictor then
    misses by ż·h: a diode voltage that follows V₀ sin(ωt) from 0 at 3 kV/s failed the error
    test at every step size down to 1e-13 s."""
    yp = np.array(yp, dtype=float)
    A = np.flatnonzero(determined)
    if not len(A):
        return yp
    n, m = mod.N, len(mod.EQUATIONS)
    rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
    a, b = np.zeros(len(rows)), np.zeros(len(rows))
    ft = np.zeros(m)
    try:
        mod.jacobian(t, y, yp, p, 0.0, a)
        mod.jacobian(t, y, yp, p, 1.0, b)
        mod.residual_t(t, y, yp, p, ft)
    except (ModelEvaluationError, *CATCH, AttributeError):
        return yp
    algebraic_row = np.ones(m, dtype=bool)
    algebraic_row[rows[b - a != 0]] = False
    R = np.flatnonzero(algebraic_row)
    Fy = sps.csr_matrix((a, (rows, cols)), shape=(m, n))[R]
    known = yp.copy()
    known[~np.asarray(mod.DIFFERENTIAL, dtype=bool)] = 0.0
    rhs = -(Fy @ known + ft[R])
    M = Fy[:, A]
    try:
        if M.shape[0] * M.shape[1] <= 250_000:
            import scipy.linalg as sla

            z = sla.lstsq(M.toarray(), rhs, lapack_driver="gelsy", cond=1e-13)[0]
        else:
            from scipy.sparse.linalg import lsqr

            z = lsqr(M, rhs, atol=1e-14, btol=1e-14)[0]
    except (ValueError, np.linalg.LinAlgError):
        return yp
    if np.all(np.isfinite(z)):
        yp[A] = z
    return yp


def solver_options(mod, p, *, rtol, atol, max_order=None, sparse: Optional[bool] = None, determined=None):
    """(options of scikit-sundae's ``IDA``, callback state) for `mod` at parameters `p`: the
    tolerances (algebraic variables out of the error test), analytic Jacobian, linear solver
    (dense up to :data:`DENSE_LIMIT` unknowns) and maximum order of a phc run."""
    n = mod.N
    diff = np.asarray(mod.DIFFERENTIAL, dtype=bool)
    sparse = n > DENSE_LIMIT if sparse is None else bool(sparse)
    resfn, jacfn, state = _callbacks(mod, p, n, sparse)
    # algebraic variables out of the error test, except those the algebraic rows determine
    # (`determined`, index 1): IDA's Newton test ignores what its weights ignore, and a
    # junction flow left out of it drifted from the momentum it equals by 20 %
    tested = diff if determined is None else diff | np.asarray(determined, dtype=bool)
    atol_vec = np.where(tested, atol, ALGEBRAIC_ATOL)
    options = dict(resfn=resfn, rtol=rtol, atol=atol_vec, jacfn=jacfn,
                   algebraic_idx=[int(j) for j in np.flatnonzero(~diff)],
                   max_num_steps=CHUNK_STEPS, max_order=int(max_order or MAX_ORDER))
    if sparse:
        rows, cols = np.asarray(mod.JAC_ROWS), np.asarray(mod.JAC_COLS)
        pattern = sps.csc_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        options.update(linsolver="sparse", sparsity=pattern)
    else:
        options.update(linsolver=DENSE_SOLVER)
    return options, state


def integrate_ida(mod, p, t_out, y0, yp0, *, rtol, atol, max_steps, progress=None, max_order=None, names=None,
                  events=None, nominal=None):
    """Integrate from ``t_out[0]`` and return a dict of arrays and statistics.

    `events` (a :class:`phc.simulation.events.Watch`, optional) are switching functions
    w(t, y, ẏ), positive while the modes hold: IDA's root finding (scikit-sundae's
    ``eventsfn``, direction −1, terminal) stops at the first that falls to zero; the run
    then returns with ``event`` = dict(t, y, yp, which) and the outputs before it."""
    IDA = _import_ida()
    n = mod.N
    max_order = int(max_order or MAX_ORDER)
    # `nominal`: the variables' nominal scales (phc.simulation.scaling); atol is relative to them.
    # IDA's local tolerances are 1/200 of what the outputs should meet (local_fraction).
    determined = determined_algebraic(mod, p, float(t_out[0]), np.asarray(y0, dtype=float),
                                      np.asarray(yp0, dtype=float))
    # an index-1 variable is tested no tighter than its states' tolerances determine it
    tested_scales = determined_scales(mod, p, float(t_out[0]), np.asarray(y0, dtype=float),
                                      np.asarray(yp0, dtype=float), determined, nominal, rtol, atol)
    if tested_scales is None:
        tested_scales = nominal
    local = local_fraction(rtol)
    atol_j = (atol if tested_scales is None else atol * np.asarray(tested_scales, dtype=float)) * local
    yp0 = algebraic_rates(mod, p, float(t_out[0]), np.asarray(y0, dtype=float), yp0, determined)
    options, calls = solver_options(mod, p, rtol=rtol * local, atol=atol_j, max_order=max_order,
                                    determined=determined)
    resfn = options.pop("resfn")
    with warnings.catch_warnings():
        # scikit-sundae warns that its own sparse approximation is unused: we pass jacfn.
        warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
        if events is not None and events.n:
            def eventsfn(t, y, yp, out):
                out[:] = events(t, y, yp)

            eventsfn.direction = [-1] * events.n   # w falls through 0: the mode no longer holds
            eventsfn.terminal = [True] * events.n
            options.update(eventsfn=eventsfn, num_events=events.n)
        solver = IDA(resfn, **options)
    t_out = np.asarray(t_out, dtype=float)

    def scales(failed, upto=1):  # the states of the run so far (a system at rest at t0 may move later)
        return check_scales(mod, ys[:upto], yps[:upto], float(t_out[-1] - t_out[0]), rtol, atol, failed,
                            scales=nominal)

    ys = np.empty((len(t_out), n))
    yps = np.empty((len(t_out), n))
    ys[0], yps[0] = y0, yp0
    start = time.process_time()
    init = solver.init_step(t_out[0], y0, yp0)
    if not init.success:
        return dict(t=t_out[:1], y=ys[:1], yp=yps[:1], steps=0, nfev=0, njev=0, success=False,
                    message=f"IDA could not start: {init.message}" + (f"; {scales(True)}" if scales(True) else ""),
                    cpu=time.process_time() - start)
    counters = _IdaCounters.attach(solver, n, int(getattr(init, "nfev", 0) or 0))
    # IDASolve called directly (no result object a call): not with switching functions, whose
    # roots scikit-SUNDAE collects after its own call
    direct = (counters is not None and counters.can_advance and not (events is not None and events.n)
              and np.array_equal(counters.y, init.y) and np.array_equal(counters.yp, init.yp))
    if direct:
        counters.set_stop_time(float(t_out[-1]))
        counters.install_residual(resfn, n)
    monitor = SingularityMonitor(mod, p, names=names, scales=nominal)
    monitor.h_floor = 1e-6 * float(t_out[-1] - t_out[0])
    # the monitor looks every `cadence` steps: `base`, stretched up to LOOK_STRETCH-fold while the
    # conditioning stays flat and far above the threshold (a look is a dense SVD, ~30 µs at 19
    # unknowns, about what one IDA step of such a system costs: every 5 steps, as before, it
    # was a third of the run; a minimum of the conditioning between looks is still located by
    # the monitor's golden-section search)
    base = 10 if n <= 60 else 20
    cadence = base if monitor.enabled else CHUNK_STEPS
    last_ratio = None
    k, steps, ok, message = 1, 0, True, "integration finished"
    since_look = 0
    next_crawl_check = 0
    event = None
    nfev = njev = 0
    t_end = float(t_out[-1])
    t_last, h_last = float(t_out[0]), 0.0
    # A failure is diagnosed at the last state reached with a normal step (h > h_ref/10, h_ref
    # the recent largest step, decaying 0.1 % a step): the steps collapse before IDA gives up.
    h_ref = 0.0
    normal = (float(t_out[0]), np.asarray(y0, dtype=float), np.asarray(yp0, dtype=float))
    interrupted = False
    interrupt = _DeferredInterrupt(direct and counters.direct_residual)
    # recoverable model errors seen; (the earliest failed trial time not passed yet, the step size before it)
    failures_seen, edge = 0, None
    native = _native_candidate(mod, direct and counters.direct_residual, n, n > DENSE_LIMIT)
    try:  # a model function outside its domain, or Ctrl-C: keep the outputs filled so far
        while k < len(t_out):
            interrupt.check()
            if counters is not None:  # IDA returns after this many steps at most (status -1)
                counters.set_max_steps(max(1, min(cadence - since_look, CHUNK_STEPS, max_steps - steps)))
            if direct:
                status, t_now = counters.advance(float(t_out[k]))
                res = None
            else:
                res = solver.step(float(t_out[k]), method="normal", tstop=t_end)
                status, t_now = int(res.status), float(res.t)
                nfev, njev = getattr(res, "nfev", nfev), getattr(res, "njev", njev)
            # without IDA's counters, residual evaluations stand in for steps (an upper bound)
            taken = (counters.steps() if counters is not None else int(res.nfev)) - steps
            steps += taken
            since_look += taken
            if taken:
                if counters is not None:
                    h_last = counters.last_step()
                else:
                    h_last = (t_now - t_last) / taken if t_now > t_last else h_last
                h_ref = max(h_last, 0.999 ** taken * h_ref)
            t_last = max(t_last, t_now)
            if direct and counters.failure_count() != failures_seen:  # a trial point the model could not be evaluated at
                failures_seen = counters.failure_count()
                t_fail = counters.last_failure_time()
                if edge is None or t_fail < edge[0]:
                    edge = (t_fail, h_ref)
            if edge is not None:
                if t_now > edge[0]:
                    edge = None  # passed: it was a trial step's overshoot
                elif taken and h_last < EDGE_SHRINK * edge[1]:
                    raise counters.last_failure_error()  # creeping up to the edge of the model's domain
            if native is not None and counters.native is None and counters.direct_residual \
                    and counters._residual[3][0] >= SWITCH_EVALUATIONS and status >= IDA_TOO_MUCH_WORK:
                native = _switch_to_native(counters, native, mod, p)
            chunk_end = status == IDA_TOO_MUCH_WORK  # the step limit of the call: a chunk ends
            if status < 0 and not chunk_end:
                ok = False
                hint = _STATUS_HINTS.get(status)
                approach = _approaching_singularity(monitor, h_ref) if hint is None else None
                if approach is not None:
                    hint = approach
                elif hint is None:  # diagnose before blaming: is the iteration matrix singular there?
                    cj = counters.last_cj(calls["cj"]) if counters is not None else calls["cj"]
                    hint = diagnose_failure(mod, p, *normal, status=status, h_typical=h_ref,
                                            h_fail=(1.0 / cj) if cj > 0 else h_last,
                                            max_order=max_order, rtol=rtol, atol=atol, names=names,
                                            scales=nominal, local=local)
                message = f"IDA failed at t = {t_now:.6g} (status {status}: {_status_text(res, status)}); {hint}"
                break
            y_now, yp_now = (counters.y.copy(), counters.yp.copy()) if direct else (res.y, res.yp)
            if status == IDA_ROOT_RETURN and res.i_events is not None:  # a switching function hit 0
                event = dict(t=t_now, y=np.array(y_now), yp=np.array(yp_now),
                             which=np.flatnonzero(np.asarray(res.i_events)[-1]).tolist())
            elif not chunk_end:  # reached the output time
                ys[k], yps[k] = y_now, yp_now
                k += 1
            if h_last > 0.1 * h_ref:
                normal = (t_now, y_now, yp_now)
            if since_look >= cadence and not monitor.enabled:
                since_look = 0  # a chunk of CHUNK_STEPS ended
            elif since_look >= cadence:
                since_look = 0
                warning = monitor.watch(t_now, y_now, yp_now, h_last)
                if warning is None and taken and steps >= next_crawl_check \
                        and h_last * (max_steps - steps) < t_end - t_now:
                    # crawling: at this step size the run cannot reach its end within max_steps.
                    # Close to a singular configuration IDA may crawl instead of failing (which
                    # of the two depends on round-off: the BLAS kernels of the CPU); ask the
                    # same question as after a failure, at most every CRAWL_CHECK_STEPS steps
                    next_crawl_check = steps + CRAWL_CHECK_STEPS
                    approach = _approaching_singularity(
                        monitor, h_ref, f"IDA's steps shrank to {h_last:.1e} s before reaching it")
                    if approach is not None:
                        warning = approach
                        monitor.stop_time = t_now
                if warning:
                    ok, message = False, warning
                    # the configuration may lie before outputs already filled in: keep none past it
                    k = max(1, min(k, int(np.searchsorted(t_out, monitor.stop_time, side="right"))))
                    break
                ratio = monitor._looks[-1][-1] if monitor._looks else None
                cadence = _next_cadence(cadence, base, last_ratio, ratio)
                last_ratio = ratio
            if progress is not None:
                progress(t_now)
            if event is not None:
                break
            if steps >= max_steps and k < len(t_out):
                ok = False
                message = (f"stopped after {steps} steps at t = {t_now:.6g} (max_steps); raise `max_steps` or "
                           "loosen the tolerances")
                break
        interrupt.check()
    except ModelEvaluationError as err:
        ok, message = False, f"IDA: {err}; results up to t = {t_out[k - 1]:.6g} are kept"
    except KeyboardInterrupt:
        ok, interrupted = False, True
        message = f"interrupted at t = {t_out[k - 1]:.6g}"
    finally:
        interrupt.close()
        if direct:
            counters.restore_residual()
            counters.restore_native()
    if direct:
        nfev, njev = counters.residual_evaluations(), counters.jacobian_evaluations()
    note = scales(not ok, k) if not message.startswith(("stopped at", "interrupted")) else None
    if note:
        message = f"{message}; {note}"
    extra = {"event": event} if event is not None else {}
    return dict(t=t_out[:k], y=ys[:k], yp=yps[:k], steps=steps, nfev=nfev, njev=njev, success=ok, **extra,
                message=message, cpu=time.process_time() - start, conditioning=monitor.worst, interrupted=interrupted)
